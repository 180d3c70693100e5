"""The paper's published numbers (Table 2), so reports can print them beside ours.

Transcribed from ``../shared/paper/isa-category-level-6d-pose.tex``, table ``tab:result``:

* left, :data:`POSE_RECALL`: 6D pose recall (%) on the synthetic ModelNet10 test renders with the
  SSC average-distance metric (paper Eq. 14-15; ``isa.evaluation.pose_metrics``): ISA with the quality
  functions Q1, Q1&Q2, Q1&Q3, Q1&Q2&Q3, and Linemod run with the templates of each training
  instance (min / max / mean recall over those instances);
* right, :data:`DETECTION_AP`: 3D detection average precision (%) on the RMRC 2014 (NYU Depth v2)
  real depth frames with the Sliding Shapes metric (3D IoU >= 0.25; ``isa.evaluation.boxes3d``), all methods
  on depth only: Sliding Shapes [Song & Xiao, ECCV 2014], Gupta et al. [CVPR 2015] on instance
  segmentation and on the estimated model, Deep Sliding Shapes [Song & Xiao, CVPR 2016], ISA.

Each row maps category -> value in the paper's category order; :data:`PRINTED_MEANS` holds the
"average"/"mean" column as printed (the Linemod rows are rounded to integers there).
"""

from __future__ import annotations

from typing import Mapping

from isa.categories import CATEGORIES

__all__ = ["POSE_RECALL", "DETECTION_AP", "PRINTED_MEANS", "mean", "table_rows"]

#: Table 2 (left): 6D pose recall in percent on synthetic test renders of unseen instances.
POSE_RECALL: dict[str, dict[str, float]] = {
    "ISA (Q1)": {"bed": 39, "chair": 40, "table": 50, "toilet": 80},
    "ISA (Q1 & Q2)": {"bed": 41, "chair": 37, "table": 53, "toilet": 89},
    "ISA (Q1 & Q3)": {"bed": 39, "chair": 46, "table": 53, "toilet": 82},
    "ISA (Q1 & Q2 & Q3)": {"bed": 46, "chair": 42, "table": 52, "toilet": 87},
    "Linemod (min)": {"bed": 58, "chair": 5, "table": 9, "toilet": 27},
    "Linemod (max)": {"bed": 62, "chair": 51, "table": 69, "toilet": 83},
    "Linemod (all)": {"bed": 60, "chair": 32, "table": 37, "toilet": 58},
}

# The two tables are alike in form as the paper's are (a row of four category values per method).
#: Table 2 (right): 3D detection AP in percent on RMRC / NYU Depth v2 frames (IoU >= 0.25).
DETECTION_AP: dict[str, dict[str, float]] = {
    "Sliding Shapes": {"bed": 33.5, "chair": 29.0, "table": 34.5, "toilet": 67.3},
    "Gupta et al. on instance seg.": {"bed": 71.0, "chair": 18.2, "table": 30.4, "toilet": 63.4},
    "Gupta et al. on estimated model": {"bed": 72.7, "chair": 47.5, "table": 40.6, "toilet": 72.7},
    "Deep Sliding Shapes": {"bed": 83.0, "chair": 58.8, "table": 68.6, "toilet": 79.2},
    "ISA (Q1 & Q2 & Q3)": {"bed": 52.0, "chair": 36.0, "table": 46.5, "toilet": 67.7},
}

#: The mean column exactly as printed in the paper, per (table, method).
PRINTED_MEANS: dict[tuple[str, str], float] = {
    ("left", "ISA (Q1)"): 52.25,
    ("left", "ISA (Q1 & Q2)"): 55.0,
    ("left", "ISA (Q1 & Q3)"): 55.0,
    ("left", "ISA (Q1 & Q2 & Q3)"): 56.75,
    ("left", "Linemod (min)"): 25,
    ("left", "Linemod (max)"): 66,
    ("left", "Linemod (all)"): 47,
    ("right", "Sliding Shapes"): 41.075,
    ("right", "Gupta et al. on instance seg."): 45.75,
    ("right", "Gupta et al. on estimated model"): 58.375,
    ("right", "Deep Sliding Shapes"): 72.40,
    ("right", "ISA (Q1 & Q2 & Q3)"): 50.55,
}


def mean(row: Mapping[str, float]) -> float:
    """Mean over the paper's four categories."""
    return sum(row[c] for c in CATEGORIES) / len(CATEGORIES)


def table_rows(table: Mapping[str, Mapping[str, float]]) -> list[list]:
    """Rows ``[method, bed, chair, table, toilet, mean]`` for a Markdown table."""
    return [[name, *(row[c] for c in CATEGORIES), round(mean(row), 3)] for name, row in table.items()]

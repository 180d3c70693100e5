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

import csv
from importlib import resources
from typing import Mapping

from isa.categories import CATEGORIES

__all__ = ["POSE_RECALL", "DETECTION_AP", "PRINTED_MEANS", "mean", "table_rows"]

#: Table 2 row by row as printed, from ``table2.csv`` beside this module (data, not code): (side,
#: method, bed, chair, table, toilet, mean column); the category columns are in the order of
#: :data:`isa.categories.CATEGORIES`, as in the paper.
def _read_table2() -> list[tuple]:
    with resources.files(__package__).joinpath("table2.csv").open(newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    assert header[2:6] == list(CATEGORIES), header  # the columns are the paper's category order
    # Integers as printed stay integers (the Linemod rows), so reports print them as the paper does.
    return [(side, method, *(int(v) if v.isdigit() else float(v) for v in values)) for side, method, *values in body]


_TABLE2 = _read_table2()


def _side(side: str) -> dict[str, dict[str, float]]:
    return {method: dict(zip(CATEGORIES, values)) for s, method, *values, _ in _TABLE2 if s == side}


#: Table 2 (left): 6D pose recall in percent on synthetic test renders of unseen instances.
POSE_RECALL: dict[str, dict[str, float]] = _side("left")

#: Table 2 (right): 3D detection AP in percent on RMRC / NYU Depth v2 frames (IoU >= 0.25).
DETECTION_AP: dict[str, dict[str, float]] = _side("right")

#: The mean column exactly as printed in the paper, per (table, method).
PRINTED_MEANS: dict[tuple[str, str], float] = {(side, method): m for side, method, *_, m in _TABLE2}


def mean(row: Mapping[str, float]) -> float:
    """Mean over the paper's four categories."""
    return sum(row[c] for c in CATEGORIES) / len(CATEGORIES)


def table_rows(table: Mapping[str, Mapping[str, float]]) -> list[list]:
    """Rows ``[method, bed, chair, table, toilet, mean]`` for a Markdown table."""
    return [[name, *(row[c] for c in CATEGORIES), round(mean(row), 3)] for name, row in table.items()]

"""Scene benchmark pictures: AP over the objects' visible fraction (matplotlib Agg, PNG).

Frames with boxes are drawn by :func:`isa.report.figures.scenes.scene_figure`; this module adds the
plot that only the scene scores have.
"""

from __future__ import annotations

import math
from pathlib import Path

from isa import atomic
from isa.scenes.scoring import METRICS, VISIB_BINS, Scores

__all__ = ["ap_by_visibility_figure"]

_TITLES = {"6d": "6D (Eq. 14)", "6d_sym": "6D, symmetries forgiven", "box_0.25": "box IoU 0.25", "box_0.5": "box IoU 0.5"}


def ap_by_visibility_figure(scores: Scores, path: str | Path, title: str = "", dpi: int = 110) -> Path:
    """One panel per metric: AP (%) in each visible-fraction bin, one line per category (bins
    without objects of a category are left out). Saves a PNG at ``path`` and returns it."""
    from matplotlib.figure import Figure

    metrics = [m for m in METRICS if any(scores.metrics[c][m] is not None for c in scores.categories)]
    fig = Figure(figsize=(3.2 * len(metrics), 3.0))
    axes = fig.subplots(1, len(metrics), squeeze=False)[0]
    names = [f"{lo:g}-{hi:g}" for lo, hi in VISIB_BINS]
    mids = [(lo + hi) / 2 for lo, hi in VISIB_BINS]
    for ax, m in zip(axes, metrics):
        for c in scores.categories:
            s = scores.metrics[c][m]
            if s is None:
                continue
            pts = [(x, 100 * s.ap_by_visib[n]) for x, n in zip(mids, names) if not math.isnan(s.ap_by_visib[n])]
            if pts:
                ax.plot(*zip(*pts), marker="o", label=c)
        ax.set_title(_TITLES.get(m, m), fontsize=9)
        ax.set_xticks(mids, names, fontsize=7)
        ax.set_xlim(0, 1)
        ax.set_ylim(-2, 102)
        ax.set_xlabel("visible fraction", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("AP (%)", fontsize=8)
    axes[-1].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, dpi=dpi), parents=True)
    return path

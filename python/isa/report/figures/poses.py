"""Pose pictures: hypotheses drawn over depth images (the paper's Fig. 6) and recall curves."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from isa import atomic
from isa.camera import Intrinsics

#: Colours as in the paper's Fig. 6: ground truth red, Q1+Q2+Q3 green, Q1 blue; others follow.
COLOURS = {"ground truth": "red", "Q1+Q2+Q3": "lime", "Q1": "deepskyblue", "Q1+Q2": "orange", "Q1+Q3": "magenta"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def box_edges(points: np.ndarray) -> np.ndarray:
    """The 12 edges (12, 2, 3) of the axis-aligned box of object-frame ``points``."""
    lo, hi = points.min(0), points.max(0)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pairs = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]
    return np.array([[c[a], c[b]] for a, b in pairs])


def _draw_pose(ax, edges: np.ndarray, R, t, K: Intrinsics, colour: str, label: str) -> None:
    pts = edges.reshape(-1, 3) @ np.asarray(R).T + np.asarray(t)
    if np.any(pts[:, 2] <= 0.05):
        return
    uv = K.project(pts).reshape(-1, 2, 2)
    for k, seg in enumerate(uv):
        ax.plot(seg[:, 0], seg[:, 1], color=colour, lw=1.2, label=label if k == 0 else None)
    o = K.project((np.asarray(t)).reshape(1, 3))[0]
    ax.plot(o[0], o[1], "o", color=colour, ms=3)


def hypotheses_sheet(
    frames: Sequence,
    model_points: Mapping[int, np.ndarray],
    estimates: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray] | None]],
    path: str | Path,
    correct: Mapping[str, Sequence[bool]] | None = None,
    columns: int = 4,
) -> Path:
    """Depth images with the ground-truth pose (red) and each method's top hypothesis drawn as the
    model's box wireframe (plus its SSC dot). ``frames`` have depth, intrinsics, R, t, obj_id;
    ``estimates[label][i]`` is (R, t) or None; ``correct[label][i]`` marks it in the title."""
    plt = _plt()
    n = len(frames)
    rows = max(1, int(np.ceil(n / columns)))
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 2.6 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for i, f in enumerate(frames):
        ax = axes.ravel()[i]
        d = np.where(f.depth > 0, f.depth, np.nan)
        ax.imshow(d, cmap="gray_r")
        edges = box_edges(model_points[f.obj_id])
        _draw_pose(ax, edges, f.R, f.t, f.intrinsics, COLOURS["ground truth"], "ground truth")
        marks = []
        for label, est in estimates.items():
            if est[i] is not None:
                _draw_pose(ax, edges, est[i][0], est[i][1], f.intrinsics, COLOURS.get(label, "yellow"), label)
            if correct is not None and label in correct:
                marks.append(f"{label}:{'ok' if correct[label][i] else 'x'}")
        ys, xs = np.nonzero(f.depth > 0)
        if len(xs):
            pad = 40
            ax.set_xlim(max(xs.min() - pad, 0), min(xs.max() + pad, f.depth.shape[1]))
            ax.set_ylim(min(ys.max() + pad, f.depth.shape[0]), max(ys.min() - pad, 0))
        ax.set_title(" ".join(marks), fontsize=7)
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, dpi=90))
    plt.close(fig)
    return path


def recall_curves(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: str | Path, title: str = "") -> Path:
    """Recall (%) over the threshold z of Eq. 15, one line per method."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.6))
    for label, (zs, rec) in curves.items():
        ax.plot(zs, 100 * np.asarray(rec), label=label, color=COLOURS.get(label))
    ax.axvline(0.1, color="gray", ls=":", lw=1)
    ax.set_xlabel("z (fraction of the model diameter)")
    ax.set_ylabel("recall (%)")
    ax.set_ylim(0, 100)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, dpi=100))
    plt.close(fig)
    return path

"""Real scenes: 3D boxes drawn over the depth image and in a top view (matplotlib Agg, PNG).

Ground truth is drawn in red and predictions in green (the paper's colours); predictions are
labelled with their score. Frames are :class:`isa.data.sunrgbd.SceneFrame`, boxes
:class:`isa.evaluation.boxes3d.Box3D` in the frame's upright coordinates.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from isa import atomic
from isa.evaluation.boxes3d import Box3D

__all__ = ["box_edges_image", "draw_depth_boxes", "draw_top_view", "scene_figure", "GT_COLOR", "PRED_COLOR"]

GT_COLOR = "red"
PRED_COLOR = "lime"

# Corner index pairs of the 12 edges for Box3D.corners(): bottom ring, top ring, verticals.
_EDGES = [(i, (i + 1) % 4) for i in range(4)] + [(4 + i, 4 + (i + 1) % 4) for i in range(4)] + [(i, i + 4) for i in range(4)]


def box_edges_image(frame, box: Box3D, near: float = 0.1) -> list[np.ndarray]:
    """The box's 12 edges as pixel segments, each (2, 2) ``[[u0, v0], [u1, v1]]``.

    Edges are cut at ``near`` metres in front of the camera, so boxes partly behind it still draw
    correctly; edges wholly behind it are left out.
    """
    # Solve rather than transpose: R_gravity read from rounded calib files is not exactly orthogonal.
    cam = np.linalg.solve(frame.R_gravity, box.corners().T).T
    segments = []
    for i, j in _EDGES:
        a, b = cam[i], cam[j]
        if a[2] < near and b[2] < near:
            continue
        if a[2] < near or b[2] < near:
            t = (near - a[2]) / (b[2] - a[2])
            cut = a + t * (b - a)
            a, b = (cut, b) if a[2] < near else (a, cut)
        segments.append(frame.intrinsics.project(np.stack([a, b])))
    return segments


def _label(box: Box3D, is_pred: bool) -> str:
    return f"{box.category} {box.score:.2f}" if is_pred else box.category


def draw_depth_boxes(ax, frame, ground_truth: Sequence[Box3D] = (), predictions: Sequence[Box3D] = ()) -> None:
    """Depth image (grey, near = light; missing pixels pale blue) with the boxes' wireframes."""
    import matplotlib

    d = frame.depth
    valid = d[d > 0]
    vmin, vmax = (float(np.percentile(valid, 1)), float(np.percentile(valid, 99))) if valid.size else (0.0, 1.0)
    cmap = matplotlib.colormaps["gray_r"].with_extremes(bad="#cfe3ff")
    # Start the scale below the nearest depth so near surfaces stay grey, not white like a hole.
    lo = vmin - 0.2 * (vmax - vmin)
    im = ax.imshow(np.ma.masked_where(d <= 0, d), cmap=cmap, vmin=lo, vmax=vmax + 1e-6, interpolation="nearest")
    h, w = d.shape
    for boxes, color, is_pred in ((ground_truth, GT_COLOR, False), (predictions, PRED_COLOR, True)):
        for b in boxes:
            segs = box_edges_image(frame, b)
            for s in segs:
                ax.plot(s[:, 0], s[:, 1], color=color, lw=1.2)
            # Label at the highest corner that is inside the image, if any.
            seen = [p for s in segs for p in s if 0 <= p[0] < w and 0 <= p[1] < h]
            if seen:
                top = min(seen, key=lambda p: p[1])
                ax.text(top[0], top[1] - 3, _label(b, is_pred), color=color, fontsize=6, ha="center", va="bottom")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    return im


def draw_top_view(ax, frame, ground_truth: Sequence[Box3D] = (), predictions: Sequence[Box3D] = (),
                  max_points: int = 30000, seed: int = 0) -> None:
    """Bird's-eye view of the upright frame: points coloured by height, box footprints with a
    tick on the heading side, the camera at the origin looking along +y."""
    pts = frame.points_upright()
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    ax.scatter(pts[:, 0], pts[:, 1], c=pts[:, 2], s=0.3, cmap="viridis", linewidths=0, rasterized=True)
    for boxes, color, is_pred in ((ground_truth, GT_COLOR, False), (predictions, PRED_COLOR, True)):
        for b in boxes:
            fp = b.footprint()
            ring = np.vstack([fp, fp[:1]])
            ax.plot(ring[:, 0], ring[:, 1], color=color, lw=1.2)
            front = 0.5 * (fp[0] + fp[3])  # the +length face
            ax.plot([b.centre[0], front[0]], [b.centre[1], front[1]], color=color, lw=0.8)
            ax.text(b.centre[0], b.centre[1], _label(b, is_pred), color=color, fontsize=6, ha="center", va="center")
    # The camera's horizontal field of view.
    k = frame.intrinsics
    reach = float(np.percentile(pts[:, 1], 99)) if len(pts) else 1.0
    for u in (-0.5, k.width - 0.5):
        ray = frame.R_gravity @ np.array([(u - k.cx) / k.fx, 0.0, 1.0])
        ray = ray / max(ray[1], 1e-6) * reach
        ax.plot([0, ray[0]], [0, ray[1]], color="0.5", lw=0.6, ls="--")
    ax.plot([0], [0], marker="^", color="k", ms=5)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y (forward) [m]")
    ax.tick_params(labelsize=7)


def scene_figure(frame, predictions: Sequence[Box3D] = (), path: str | Path | None = None,
                 title: str | None = None, categories: Sequence[str] | None = None, dpi: int = 120):
    """Depth image with boxes (left) and top view (right) of one frame.

    ``categories`` restricts the ground truth drawn (e.g. the paper's four); predictions are all
    drawn. Saves a PNG and returns ``path`` when given, else returns the matplotlib Figure.
    """
    from matplotlib.figure import Figure

    gt = [b for b in frame.boxes if categories is None or b.category in categories]
    h, w = frame.depth.shape
    fig = Figure(figsize=(11, 11 * h / w / 1.6 + 0.6))
    ax0, ax1 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1]})
    draw_depth_boxes(ax0, frame, gt, predictions)
    draw_top_view(ax1, frame, gt, predictions)
    fig.suptitle(title or f"{frame.name}: ground truth (red), predictions (green)", fontsize=9)
    fig.tight_layout()
    if path is None:
        return fig
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, dpi=dpi), parents=True)
    return path

"""Skeleton pictures (matplotlib, Agg backend, PNG).

- :func:`matched_grid`: instances with their template-matched nodes coloured by template index
  (the same colour = the same template node: a person checks the matching at a glance);
- :func:`com_vs_ssc`: the paper's COM vs SSC figure (top row centres of mass, bottom row SSCs);
- :func:`depth_with_skeleton`: depth renders with the projected skeleton drawn over them (the
  paper's Fig. 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from isa import atomic
from isa.exceptions import InvalidValueError


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return matplotlib, plt


def _surface_points(mesh, n: int = 2500, seed: int = 0) -> np.ndarray:
    import trimesh

    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts


def _colours(n: int) -> np.ndarray:
    matplotlib, _ = _plt()
    cmap = matplotlib.colormaps["tab20"]
    return np.array([cmap(i % 20) for i in range(n)])


def _axis3d(ax, points: np.ndarray, elev: float = 18, azim: float = -62) -> None:
    lo, hi = points.min(0), points.max(0)
    ax.set_box_aspect(np.maximum(hi - lo, 1e-3))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.view_init(elev, azim)
    ax.set_axis_off()


def _save(fig, path) -> Path:
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, bbox_inches="tight"), parents=True)
    _, plt = _plt()
    plt.close(fig)
    return path


def matched_grid(
    meshes: Sequence,
    matched: Sequence,
    path: str | Path,
    titles: Sequence[str] | None = None,
    columns: int = 7,
    dpi: int = 90,
) -> Path:
    """Grid of instances (grey surface samples), template links and matched nodes coloured by
    template index; unmatched nodes (completed from the template) are hollow. Returns ``path``."""
    if len(meshes) == 0 or len(meshes) != len(matched):
        raise InvalidValueError(f"meshes, matched: need equal, non-zero lengths, got {len(meshes)} and {len(matched)}")
    _, plt = _plt()
    n = len(meshes)
    cols = min(columns, n)
    rows = int(np.ceil(n / cols))
    fig = plt.figure(figsize=(2.6 * cols, 2.8 * rows + 0.6), dpi=dpi)
    col = _colours(len(matched[0].nodes))
    for i, (mesh, m) in enumerate(zip(meshes, matched)):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        p = _surface_points(mesh, 1500, i)
        ax.scatter(*p.T, s=0.2, c="0.75", depthshade=False)
        for a, b in m.links:
            ax.plot(*m.nodes[[a, b]].T, "-", c="0.2", lw=1.0)
        ok = np.asarray(m.meta.get("matched", [True] * len(m.nodes)), bool)
        ax.scatter(*m.nodes[ok].T, s=28, c=col[ok], edgecolors="k", linewidths=0.4, depthshade=False)
        if (~ok).any():
            ax.scatter(*m.nodes[~ok].T, s=28, facecolors="none", edgecolors=col[~ok], linewidths=1.2, depthshade=False)
        _axis3d(ax, np.vstack([p, m.nodes]))
        if titles is not None:
            ax.set_title(titles[i], fontsize=8)
    names = matched[0].names or [f"node {i}" for i in range(len(col))]
    handles = [plt.Line2D([], [], marker="o", ls="", c=col[i], markeredgecolor="k", label=nm) for i, nm in enumerate(names)]
    fig.legend(handles=handles, loc="lower center", ncol=min(6, len(names)), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return _save(fig, path)


def com_vs_ssc(
    meshes: Sequence,
    coms: Sequence,
    sscs: Sequence,
    path: str | Path,
    matched: Sequence | None = None,
    titles: Sequence[str] | None = None,
    dpi: int = 90,
) -> Path:
    """The paper's COM vs SSC figure: top row each instance with its centre of mass (red), bottom
    row with its SSC (blue), same view; with ``matched`` the skeleton is drawn faintly."""
    n = len(meshes)
    if n == 0 or len(coms) != n or len(sscs) != n:
        raise InvalidValueError(f"meshes, coms, sscs: need equal, non-zero lengths, got {n}, {len(coms)}, {len(sscs)}")
    _, plt = _plt()
    fig = plt.figure(figsize=(2.5 * n, 5.4), dpi=dpi)
    for i in range(n):
        p = _surface_points(meshes[i], 2000, i)
        for row, (pt, colour, label) in enumerate(((coms[i], "tab:red", "COM"), (sscs[i], "tab:blue", "SSC"))):
            ax = fig.add_subplot(2, n, row * n + i + 1, projection="3d")
            ax.scatter(*p.T, s=0.2, c="0.7", depthshade=False)
            if matched is not None:
                m = matched[i]
                for a, b in m.links:
                    ax.plot(*m.nodes[[a, b]].T, "-", c="0.45", lw=0.8)
            ax.scatter(*np.asarray(pt, float).reshape(3, 1), s=90, c=colour, marker="*", edgecolors="k", depthshade=False)
            _axis3d(ax, p)
            if i == 0:
                ax.text2D(-0.05, 0.5, label, transform=ax.transAxes, rotation=90, va="center", fontsize=10)
            if row == 0 and titles is not None:
                ax.set_title(titles[i], fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def depth_with_skeleton(
    depths: Sequence[np.ndarray],
    skeletons: Sequence,
    poses: Sequence,
    intrinsics,
    path: str | Path,
    columns: int = 4,
    crop: bool = True,
    dpi: int = 100,
) -> Path:
    """Depth renders (metres, 0 = none) with the skeleton projected over them: links white,
    nodes coloured by template index (the paper's Fig. 2). ``poses``: (R, t) per image."""
    from isa.privileged.annotate import project_skeleton

    n = len(depths)
    if n == 0 or len(skeletons) != n or len(poses) != n:
        raise InvalidValueError(f"depths, skeletons, poses: need equal, non-zero lengths, got {n}, {len(skeletons)}, {len(poses)}")
    matplotlib, plt = _plt()
    cols = min(columns, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows), dpi=dpi, squeeze=False)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="black")
    for ax in axes.ravel():
        ax.axis("off")
    for i, (d, sk, (R, t)) in enumerate(zip(depths, skeletons, poses)):
        ax = axes[i // cols, i % cols]
        uvz = project_skeleton(sk, R, t, intrinsics)
        ax.imshow(np.where(d > 0, d, np.nan), cmap=cmap)
        for a, b in sk.links:
            ax.plot(uvz[[a, b], 0], uvz[[a, b], 1], "-", c="white", lw=1.3)
        ax.scatter(uvz[:, 0], uvz[:, 1], s=16, c=_colours(len(uvz)), edgecolors="k", linewidths=0.4, zorder=3)
        if crop:
            fg = np.argwhere(d > 0)
            pts = np.vstack([fg[:, ::-1], uvz[:, :2]]) if len(fg) else uvz[:, :2]
            lo, hi = pts.min(0) - 12, pts.max(0) + 12
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(hi[1], lo[1])
    fig.tight_layout()
    return _save(fig, path)

"""Contact sheets of rendered depth images and their masks (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from isa import atomic
from isa.exceptions import InvalidValueError


def contact_sheet(
    depths: Sequence[np.ndarray],
    masks: Sequence[np.ndarray] | None,
    path: str | Path,
    titles: Sequence[str] | None = None,
    columns: int = 6,
    crop: bool = True,
    dpi: int = 110,
) -> Path:
    """Save a grid of depth images (metres, 0 = missing shown white) with each mask below its depth.

    ``crop`` zooms every tile onto the object (mask/depth bounding box plus a margin) so small,
    distant objects stay visible; a colour bar gives the depth scale. Returns ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(depths)
    if n == 0:
        raise InvalidValueError("contact_sheet: no images")
    if masks is not None and len(masks) != n:
        raise InvalidValueError(f"contact_sheet: {len(masks)} masks for {n} depth images")
    cols = min(columns, n)
    rows_per = 2 if masks is not None else 1
    rows = int(np.ceil(n / cols)) * rows_per
    valid = [d[d > 0] for d in depths]
    vals = np.concatenate(valid) if any(v.size for v in valid) else np.array([0.0, 1.0])
    vmin, vmax = float(np.percentile(vals, 1)), float(np.percentile(vals, 99)) + 1e-6
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 1.9 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    im = None
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="white")  # missing depth shows white
    for i, d in enumerate(depths):
        r, c = (i // cols) * rows_per, i % cols
        m = masks[i] if masks is not None else d > 0
        sl = _crop_slices(m if m.any() else d > 0, d.shape) if crop else (slice(None), slice(None))
        shown = np.ma.masked_where(d[sl] <= 0, d[sl])
        im = axes[r, c].imshow(shown, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        if titles is not None:
            axes[r, c].set_title(titles[i], fontsize=7)
        if masks is not None:
            axes[r + 1, c].imshow(np.asarray(masks[i])[sl], cmap="gray", interpolation="nearest")
    if im is not None:
        cb = fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.6, pad=0.01)
        cb.set_label("depth [m]")
    path = Path(path)
    atomic.write_with(path, lambda tmp: fig.savefig(tmp, dpi=dpi), parents=True)
    plt.close(fig)
    return path


def _crop_slices(mask: np.ndarray, shape: tuple[int, int], margin: float = 0.15) -> tuple[slice, slice]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return slice(None), slice(None)
    h, w = shape
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    size = max(y1 - y0, x1 - x0)
    pad = int(size * margin) + 2
    cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
    half = size // 2 + pad
    return slice(max(0, cy - half), min(h, cy + half)), slice(max(0, cx - half), min(w, cx + half))


def bop_contact_sheet(root: str | Path, split: str, path: str | Path, per_scene: int = 2, max_images: int = 24, **kw) -> Path:
    """Contact sheet of the first ``per_scene`` frames of each scene of a BOP dataset written by isa."""
    from isa.data import bop

    depths, masks, titles = [], [], []
    for sid in bop.list_scenes(root, split):
        for im in bop.list_frames(root, split, sid)[:per_scene]:
            f = bop.read_frame(root, split, sid, im)
            depths.append(f.depth)
            masks.append(f.mask)
            titles.append(f"obj {f.obj_id} view {im} ({np.linalg.norm(f.t):.1f} m)")
            if len(depths) >= max_images:
                return contact_sheet(depths, masks, path, titles, **kw)
    return contact_sheet(depths, masks, path, titles, **kw)

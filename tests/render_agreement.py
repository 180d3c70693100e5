"""How closely two renders of the same frame agree (the core rasteriser against pyrender or ray
casting): used by tests/test_render_core.py and benches/bench_render.py (one copy for both).

Disagreements are sorted by where they are: on a silhouette edge (a pixel within one pixel of a
mask boundary of either render, where the pixel centre lies within rounding of an edge and the two
renders may decide it differently) or not; depth differences likewise, on a depth edge (a
neighbour more than ``DEPTH_EDGE`` m away in either render, where the pixel may take the nearer or
the farther face) or on a smooth surface.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

#: A depth step between neighbours that makes a pixel a depth edge (metres).
DEPTH_EDGE = 0.01

_EIGHT = np.ones((3, 3), bool)


def mask_edges(mask: np.ndarray) -> np.ndarray:
    """Pixels within one pixel (8-neighbourhood) of a change of ``mask``."""
    return ndimage.binary_dilation(mask, _EIGHT) & ~ndimage.binary_erosion(mask, _EIGHT, border_value=1)


def depth_edges(depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Covered pixels whose covered 8-neighbours' depths span more than DEPTH_EDGE."""
    hi = ndimage.maximum_filter(np.where(mask, depth, -np.inf), footprint=_EIGHT)
    lo = ndimage.minimum_filter(np.where(mask, depth, np.inf), footprint=_EIGHT)
    return mask & (hi - lo > DEPTH_EDGE)


def smooth_pixels(da: np.ndarray, ma: np.ndarray, db: np.ndarray, mb: np.ndarray) -> np.ndarray:
    """Pixels both renders cover, on no silhouette edge and no depth edge of either."""
    edges = mask_edges(ma) | mask_edges(mb) | depth_edges(da, ma) | depth_edges(db, mb)
    return ma & mb & ~edges


@dataclass
class Agreement:
    """Pixels compared over one or more frames, and how they differ."""

    frames: int = 0
    union: int = 0  # pixels either render covers
    mask_differ: int = 0  # covered by one render only
    mask_differ_off_edge: int = 0  # ... and not on a silhouette edge of either
    both: int = 0  # covered by both
    smooth: int = 0  # covered by both, on no silhouette or depth edge
    diffs_smooth: list = field(default_factory=list)  # |depth a - depth b| on smooth pixels, per frame
    max_diff_all: float = 0.0  # over every pixel both cover
    over_1e4_off_edges: int = 0  # smooth pixels whose depths differ by more than 0.1 mm

    def add(self, da: np.ndarray, ma: np.ndarray, db: np.ndarray, mb: np.ndarray) -> None:
        edges = mask_edges(ma) | mask_edges(mb)
        differ = ma != mb
        self.frames += 1
        self.union += int((ma | mb).sum())
        self.mask_differ += int(differ.sum())
        self.mask_differ_off_edge += int((differ & ~edges).sum())
        both = ma & mb
        diff = np.abs(da.astype(np.float64) - db.astype(np.float64))
        smooth = smooth_pixels(da, ma, db, mb)
        self.both += int(both.sum())
        self.smooth += int(smooth.sum())
        self.diffs_smooth.append(diff[smooth])
        if both.any():
            self.max_diff_all = max(self.max_diff_all, float(diff[both].max()))
        self.over_1e4_off_edges += int((diff[smooth] > 1e-4).sum())

    def smooth_diffs(self) -> np.ndarray:
        return np.concatenate(self.diffs_smooth) if self.diffs_smooth else np.zeros(0)

    def summary(self) -> dict:
        d = self.smooth_diffs()
        q = (lambda p: float(np.quantile(d, p))) if len(d) else (lambda p: float("nan"))
        return {
            "frames": self.frames, "union_px": self.union, "mask_differ_px": self.mask_differ,
            "mask_agree_frac": 1 - self.mask_differ / max(1, self.union),
            "mask_differ_off_edge_px": self.mask_differ_off_edge,
            "both_px": self.both, "smooth_px": self.smooth,
            "depth_diff_median_m": q(0.5), "depth_diff_p999_m": q(0.999), "depth_diff_max_smooth_m": q(1.0),
            "depth_diff_max_all_m": self.max_diff_all, "smooth_px_over_1e-4_m": self.over_1e4_off_edges,
        }

"""Verification in numpy (the reference of ``isa._core.verify_pose``; the rules in
``isa.detection.verify``)."""

from __future__ import annotations

import math

import numpy as np

from isa.camera import Intrinsics
from isa.detection import verify
from isa.detection.verify import Verification, VerifyParams


class DepthEvidence(verify.DepthEvidence):
    """The package's frame (its checks on the planes mask), compared on a 5 x 5 grid of pixels
    spanning ``lateral`` metres around each shape cell's pixel."""

    GRID = 5

    def __init__(self, depth: np.ndarray, intrinsics: Intrinsics, planes: np.ndarray | None = None):
        super().__init__(depth, intrinsics, planes)
        g = np.arange(self.GRID) - self.GRID // 2
        self._offsets = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)  # (K, 2) unit steps

    def window(self, uv: np.ndarray, lateral: float, z: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Observed depth (M, K) on the grid around each pixel (M, 2) reaching ``lateral`` metres
        at depth ``z`` (0 where missing or outside the image), and whether each sample is a plane
        pixel (None without a planes mask)."""
        half = lateral * self.intrinsics.fx / max(z, 1e-3)
        step = half / (self.GRID // 2) if self.GRID > 1 else 0.0
        off = np.round(self._offsets * step).astype(np.int64)
        u = uv[:, :1] + off[None, :, 0]
        v = uv[:, 1:] + off[None, :, 1]
        h, w = self.depth.shape
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        vv, uu = np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)
        out = self.depth[vv, uu].astype(float)
        out[~inside] = 0.0
        return out, (None if self.planes is None else self.planes[vv, uu])


def _cell_px(spacing: float, z: float, intrinsics: Intrinsics, params: VerifyParams) -> int:
    return max(params.min_cell_px, int(round(params.cell_spacing * spacing * intrinsics.fx / max(z, 1e-3))))


def visible_points(points_cam: np.ndarray, intrinsics: Intrinsics, cell_px: int,
                   margin: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The front-most point per ``cell_px`` image cell of camera-frame points (N, 3): their
    indices (M,), pixels (M, 2) int (u, v) and whether each is inside the image (M,) bool.
    Points behind the camera are dropped, and so are those beyond ``margin`` times the image
    size outside it (kept within it: a hypothesis mostly out of view is scored on all of it)."""
    z = points_cam[:, 2]
    idx = np.flatnonzero(z > 0.05)
    zi = z[idx]
    u = np.floor(intrinsics.fx * points_cam[idx, 0] / zi + intrinsics.cx + 0.5).astype(np.int64)
    v = np.floor(intrinsics.fy * points_cam[idx, 1] / zi + intrinsics.cy + 0.5).astype(np.int64)
    mu, mv = int(margin * intrinsics.width), int(margin * intrinsics.height)
    keep = (u >= -mu) & (u < intrinsics.width + mu) & (v >= -mv) & (v < intrinsics.height + mv)
    idx, u, v, zi = idx[keep], u[keep], v[keep], zi[keep]
    if len(idx) == 0:
        return idx, np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=bool)
    cols = (intrinsics.width + 2 * mu + cell_px - 1) // cell_px
    cell = ((v + mv) // cell_px) * cols + (u + mu) // cell_px
    # By cell, then nearest first: one sort of cell + z / (z_max + 1), as a lexsort would order.
    order = np.argsort(cell + zi / (float(zi.max()) + 1.0), kind="stable")
    first = np.ones(len(order), dtype=bool)
    first[1:] = cell[order[1:]] != cell[order[:-1]]
    front = order[first]
    uv = np.column_stack([u[front], v[front]])
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < intrinsics.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intrinsics.height)
    return idx[front], uv, inside


def verify_pose(evidence: DepthEvidence, R: np.ndarray, t: np.ndarray, points: np.ndarray,
                spacing: float, params: VerifyParams = VerifyParams(), n_points: int | None = None) -> Verification:
    """Verify one shape (object-frame ``points`` (N, 3), mean ``spacing``) at pose ``(R, t)``
    against a frame's :class:`DepthEvidence`. ``n_points``: use only the first that many points
    (the samples are random, so any prefix is an even subsample; the cells grow to match), for a
    quick first look."""
    intrinsics = evidence.intrinsics
    R = np.asarray(R, dtype=float).reshape(3, 3)
    t = np.asarray(t, dtype=float).reshape(3)
    points = np.asarray(points, dtype=float)
    if n_points is not None and n_points < len(points):
        spacing = spacing * math.sqrt(len(points) / n_points)
        points = points[:n_points]
    pc = np.einsum("ij,nj->ni", R, points) + t  # einsum: see refine._apply
    idx, uv, inside = visible_points(pc, intrinsics, _cell_px(spacing, float(t[2]), intrinsics, params), 1.0)
    outside = int(np.count_nonzero(~inside))
    idx, uv = idx[inside], uv[inside]
    if len(idx) == 0:
        return Verification(0.0, 0, 0, 0, 0, outside)
    zm = pc[idx, 2]
    zo, plane = evidence.window(uv, params.lateral, float(t[2]))  # (M, K)
    base, k = params.tolerance
    tol = np.maximum(base, k * zm * zm)[:, None]
    valid = zo > 0
    d = zo - zm[:, None]
    near = np.abs(d) < tol
    thing = valid if plane is None else valid & ~plane
    agree_m = (thing & near).any(1)  # an object surface where the shape's is, nearby
    any_valid = valid.any(1)
    # No evidence either way: something (not a plane) in front hides the cell, or the shape
    # touches a plane there; anything else around is seen through (or is a wall in front).
    hidden = (thing & (d <= -tol)).any(1)
    if plane is not None:
        hidden |= (valid & plane & near).any(1)
    violate_m = ~agree_m & any_valid & ~hidden
    agree = int(np.count_nonzero(agree_m))
    violate = int(np.count_nonzero(violate_m))
    missing = int(np.count_nonzero(~any_valid))
    occluded = len(zm) - agree - violate - missing
    n = agree + violate + occluded + outside
    score = 0.0 if n - outside < params.min_cells else (agree - params.violation_weight * violate) / n
    return Verification(float(score), agree, violate, occluded, missing, outside)


def verify_shapes(evidence: DepthEvidence, R: np.ndarray, t: np.ndarray, library,
                  params: VerifyParams = VerifyParams()) -> list[Verification]:
    """:func:`verify_pose` of every shape of a :class:`ShapeLibrary` at one pose."""
    return [verify_pose(evidence, R, t, library.points[s], library.spacing[s], params)
            for s in range(len(library))]

"""Dominant planes of a depth frame in its upright frame: the floor (one height searched along
gravity) and large walls (gravity-constrained RANSAC), and their removal from the depth image."""

from __future__ import annotations

import numpy as np

from isa.camera import Intrinsics
from isa.detection.planes import Plane, PlaneParams, PlaneRemoval, checked_depth
from isa.exceptions import InvalidValueError


def _tolerance(depth: np.ndarray, params: PlaneParams) -> np.ndarray:
    base, k = params.tolerance
    return np.maximum(base, k * np.asarray(depth, dtype=float) ** 2)


def _find_floor(z: np.ndarray, tol: np.ndarray, params: PlaneParams, rng: np.random.Generator) -> float | None:
    """Height of the dominant horizontal layer at the bottom of the cloud, or None."""
    n = len(z)
    if n == 0:
        return None
    idx = rng.choice(n, params.samples, replace=False) if n > params.samples else np.arange(n)
    zs, ts = z[idx], tol[idx]
    lo = float(np.percentile(zs, 0.5))
    hs = np.arange(lo - 0.05, lo + params.floor_search, 0.01)
    hs = hs[hs <= -params.min_floor_drop]
    if hs.size == 0:
        return None
    support = (np.abs(zs[None, :] - hs[:, None]) < ts[None, :]).sum(1)
    best = int(np.argmax(support))
    if support[best] < params.min_floor_fraction * len(zs):
        return None
    on = np.abs(z - hs[best]) < tol
    return float(np.median(z[on]))


def _find_wall(p: np.ndarray, tol: np.ndarray, params: PlaneParams, rng: np.random.Generator,
               n_total: int) -> tuple[np.ndarray, float, np.ndarray] | None:
    """One wall by gravity-constrained RANSAC: ``(normal (3,), offset, inlier mask (N,))`` or None."""
    n = len(p)
    if n < 3:
        return None
    idx = rng.choice(n, params.samples, replace=False) if n > params.samples else np.arange(n)
    ps, ts = p[idx], tol[idx]
    i = rng.integers(0, len(ps), params.ransac_iterations)
    j = rng.integers(0, len(ps), params.ransac_iterations)
    dxy = ps[j, :2] - ps[i, :2]
    length = np.hypot(dxy[:, 0], dxy[:, 1])
    ok = length > 0.2  # two close points fix a direction badly
    if not ok.any():
        return None
    # Vertical plane through both points: its normal is horizontal and across their separation.
    nrm = np.column_stack([-dxy[ok, 1], dxy[ok, 0]]) / length[ok, None]
    off = -(nrm * ps[i[ok], :2]).sum(1)
    # Written out, not a (k, 2) @ (2, N) matmul: BLAS threading makes that slow on a busy machine.
    d = np.abs(nrm[:, :1] * ps[None, :, 0] + nrm[:, 1:] * ps[None, :, 1] + off[:, None])
    score = (d < ts[None, :]).sum(1)
    # A mid-size subsample screens candidates before the (costly) test on every point.
    ic = np.sort(rng.choice(n, params.check_samples, replace=False)) if n > params.check_samples else np.arange(n)
    tried: list[tuple[np.ndarray, float]] = []
    # The best-supported plane may be a furniture face (rejected below); try the next distinct ones.
    for best in np.argsort(-score, kind="stable"):
        if len(tried) >= params.wall_candidates or score[best] < params.min_wall_fraction * len(ps) * n_total / n:
            break
        if any(abs(nrm[best] @ nn) > 0.995 and abs(off[best] - oo * np.sign(nrm[best] @ nn)) < 0.15 for nn, oo in tried):
            continue
        tried.append((nrm[best], off[best]))
        wall = _check_wall(p, tol, ps, ts, (p[ic], tol[ic]), nrm[best], off[best], params, n_total)
        if wall is not None:
            return wall
    return None


def _check_wall(p, tol, ps, ts, check, normal, offset, params: PlaneParams, n_total: int):
    """Refine a vertical plane hypothesis on the samples ``ps`` and accept it if it is a wall,
    first on the points ``check`` (points, tolerances), then on all of ``p``: ``(normal (3,), offset, inlier mask)`` or
    None."""
    for _ in range(2):  # least-squares refinement on the inliers (2D line fit, normal stays horizontal)
        on = np.abs(ps[:, 0] * normal[0] + ps[:, 1] * normal[1] + offset) < ts
        if on.sum() < 3:
            return None
        xy = ps[on, :2]
        c = xy.mean(0)
        _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
        normal = vt[1]
        offset = -float(c @ normal)
    if not _wall_extent(ps[on], normal, params):  # cheap rejection on the samples first
        return None
    # Sparser points need fewer per cell to mark a patch.
    for q, tq, min_points in ((*check, 1), (p, tol, 3)):
        on = np.abs(q[:, 0] * normal[0] + q[:, 1] * normal[1] + offset) < tq
        on = _largest_patch(q[on, 0] * -normal[1] + q[on, 1] * normal[0], q[on, 2], on, min_points=min_points)
        if on.sum() < params.min_wall_fraction * n_total * len(q) / len(p) or not _wall_extent(q[on], normal, params):
            return None
    return np.array([normal[0], normal[1], 0.0]), offset, on


def _wall_extent(q: np.ndarray, normal: np.ndarray, params: PlaneParams) -> bool:
    """Whether the points ``q`` (on a vertical plane with this normal) span a wall's height and width."""
    if len(q) < 3:
        return False
    along = q[:, 0] * -normal[1] + q[:, 1] * normal[0]
    return bool(np.ptp(np.percentile(q[:, 2], [2, 98])) >= params.min_wall_height
                and np.ptp(np.percentile(along, [2, 98])) >= params.min_wall_width)


def _largest_patch(along: np.ndarray, z: np.ndarray, on: np.ndarray, cell: float = 0.1, min_points: int = 3) -> np.ndarray:
    """Keep only the inliers of the largest connected patch of the plane (``cell`` m grid in the
    plane's own coordinates): an infinite plane also grazes unrelated objects elsewhere, whose
    points would otherwise be removed and would make a low face look like a tall wall."""
    from scipy import ndimage

    if len(along) == 0:
        return on
    a = np.floor((along - along.min()) / cell).astype(np.int64)
    b = np.floor((z - z.min()) / cell).astype(np.int64)
    shape = (int(a.max()) + 1, int(b.max()) + 1)
    counts = np.bincount(a * shape[1] + b, minlength=shape[0] * shape[1]).reshape(shape)
    occupied = ndimage.binary_closing(counts >= min_points, iterations=1) | (counts >= min_points)
    lab, n = ndimage.label(occupied, structure=np.ones((3, 3)))
    if n == 0:
        out = on.copy()
        out[:] = False
        return out
    weight = ndimage.sum(counts, lab, index=np.arange(1, n + 1))
    keep = lab[a, b] == 1 + int(np.argmax(weight))
    out = np.zeros_like(on)
    out[np.flatnonzero(on)[keep]] = True
    return out


def find_planes(points: np.ndarray, depth: np.ndarray, params: PlaneParams = PlaneParams(),
                floor: bool = True, walls: bool = True) -> tuple[list[Plane], np.ndarray]:
    """The floor and walls of a cloud: ``points`` (N, 3) upright frame, ``depth`` (N,) each
    point's camera depth (for the tolerance). Returns the planes (floor first) and a label (N,)
    int per point: the index of the plane it lies on, -2 below the floor, -1 none."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    depth = np.asarray(depth, dtype=float).reshape(-1)
    if len(points) != len(depth):
        raise InvalidValueError(f"find_planes: {len(points)} points but {len(depth)} depths")
    rng = np.random.default_rng(params.seed)
    tol = _tolerance(depth, params)
    labels = np.full(len(points), -1, dtype=np.int64)
    planes: list[Plane] = []
    if floor:
        h = _find_floor(points[:, 2], tol, params, rng)
        if h is not None:
            dz = points[:, 2] - h
            on = np.abs(dz) < tol
            labels[on] = 0
            labels[dz <= -tol] = -2  # nothing real is under the floor: noise and reflections
            planes.append(Plane("floor", np.array([0.0, 0.0, 1.0]), -h, int(on.sum())))
    if walls:
        for _ in range(params.max_walls):
            free = np.flatnonzero(labels == -1)
            found = _find_wall(points[free], tol[free], params, rng, len(points))
            if found is None:
                break
            normal, offset, inliers = found
            on = free[inliers]
            labels[on] = len(planes)
            planes.append(Plane("wall", normal, offset, len(on)))
    return planes, labels


def remove_planes(depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray, params: PlaneParams = PlaneParams(),
                  floor: bool = True, walls: bool = True) -> PlaneRemoval:
    """The numpy version of :func:`isa.detection.planes.remove_planes` (its arguments and input
    checks)."""
    depth = checked_depth(depth, intrinsics, "remove_planes")
    Rg = np.asarray(R_gravity, dtype=float).reshape(3, 3)
    valid = depth > 0
    cam = intrinsics.backproject(depth)[valid]
    up = np.einsum("ij,nj->ni", Rg, cam)
    planes, labels = find_planes(up, cam[:, 2], params, floor, walls)
    removed = np.zeros(depth.shape, dtype=bool)
    removed[valid] = labels != -1
    out = depth.copy()
    out[removed] = 0.0
    return PlaneRemoval(out, planes, removed)

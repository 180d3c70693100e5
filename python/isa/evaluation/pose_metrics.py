"""The paper's evaluation metric on synthetic data: SSC-based average distance (Eq. 14-15).

    omega_i = mean_x || (R x + T) - (R~ x + T~) ||   over the point cloud X of the SSC-centred model
    correct  <=>  omega_i <= z * Phi_i               (Phi_i: the model's diameter)

``z`` sets how coarse a correct hypothesis may be; the paper's headline is z = 0.1, and the recall
over a range of z is reported too. For objects with symmetries (a rectangular table turned by
180 degrees looks the same) :func:`symmetric_average_distance` (ADD-S) is reported beside it.
Points are in the object frame (origin = the category's SSC), poses map them to the camera frame
as everywhere in isa: X_cam = R X + t.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from isa.exceptions import InvalidValueError

__all__ = ["average_distance", "symmetric_average_distance", "model_points", "model_diameter", "is_correct", "recall", "recall_curve"]


def _points(points) -> np.ndarray:
    X = np.asarray(points, float)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
        raise InvalidValueError(f"points: expected a non-empty (N, 3) array, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise InvalidValueError("points: contains non-finite values")
    return X


def _pose(R, t, name: str) -> tuple[np.ndarray, np.ndarray]:
    R = np.asarray(R, float)
    t = np.asarray(t, float)
    if R.shape[-2:] != (3, 3):
        raise InvalidValueError(f"{name}: rotation must be (..., 3, 3), got {R.shape}")
    if t.shape[-1:] != (3,):
        raise InvalidValueError(f"{name}: translation must be (..., 3), got {t.shape}")
    return R, t


def average_distance(points, R_gt, t_gt, R_est, t_est) -> np.ndarray | float:
    """Eq. 14: mean distance between the model points under the true and the estimated pose.

    Poses may be batched: ``R_*`` (..., 3, 3), ``t_*`` (..., 3) broadcast together; the result
    has the batch shape (a float for single poses). Computed as the mean of
    || (R - R~) x + (t - t~) ||, exact, in O(N) per pose.
    """
    X = _points(points)
    Rg, tg = _pose(R_gt, t_gt, "R_gt/t_gt")
    Re, te = _pose(R_est, t_est, "R_est/t_est")
    dR = Rg - Re
    dt = tg - te
    diff = np.einsum("...ij,nj->...ni", dR, X) + dt[..., None, :]
    om = np.linalg.norm(diff, axis=-1).mean(-1)
    return float(om) if np.ndim(om) == 0 else om


def symmetric_average_distance(points, R_gt, t_gt, R_est, t_est) -> float:
    """ADD-S (Hinterstoisser et al., ACCV 2012): mean over the truly posed model points of the
    distance to the *closest* point of the model under the estimated pose.

    Poses that a symmetry of the model makes indistinguishable score (near) zero, where Eq. 14
    scores them as far apart; never more than :func:`average_distance`. Single poses only.
    """
    X = _points(points)
    Rg, tg = _pose(R_gt, t_gt, "R_gt/t_gt")
    Re, te = _pose(R_est, t_est, "R_est/t_est")
    if Rg.shape != (3, 3) or Re.shape != (3, 3) or tg.shape != (3,) or te.shape != (3,):
        raise InvalidValueError("symmetric_average_distance: pass single poses (R (3, 3), t (3,))")
    d, _ = cKDTree(X @ Re.T + te).query(X @ Rg.T + tg)
    return float(d.mean())


def model_points(mesh, n: int = 4096, seed: int = 0) -> np.ndarray:
    """X of Eq. 14: ``n`` seeded surface samples of ``mesh`` plus its vertices, in ``mesh``'s frame.

    Pass the mesh in the object frame (origin at the category's SSC), as the poses are defined.
    """
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidValueError("mesh: expected a trimesh.Trimesh with triangles")
    if n < 1:
        raise InvalidValueError(f"n: need at least one sample, got {n}")
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.concatenate([pts, mesh.vertices[np.unique(mesh.faces)]])


def model_diameter(points) -> float:
    """Phi: the largest distance between two model points (exact, via the convex hull)."""
    X = _points(points)
    if len(X) > 4:
        try:
            X = X[ConvexHull(X).vertices]
        except Exception:  # flat or degenerate clouds: fall back to all points
            pass
    if len(X) > 4000:  # hull of a huge cloud: bound the O(n^2) step by chunks
        best = 0.0
        for i in range(0, len(X), 2000):
            d = np.linalg.norm(X[i : i + 2000, None] - X[None], axis=-1)
            best = max(best, float(d.max()))
        return best
    return float(np.linalg.norm(X[:, None] - X[None], axis=-1).max())


def is_correct(omega, diameter, z: float = 0.1) -> np.ndarray | bool:
    """Eq. 15: omega <= z * Phi (element-wise)."""
    if not z >= 0:
        raise InvalidValueError(f"z: must be >= 0, got {z}")
    diameter = np.asarray(diameter, float)
    if np.any(diameter <= 0):
        raise InvalidValueError("diameter: must be positive")
    out = np.asarray(omega, float) <= z * diameter
    return bool(out) if out.ndim == 0 else out


def recall(omegas, diameters, z: float = 0.1) -> float:
    """Fraction of hypotheses that are correct at ``z`` (a missing hypothesis: omega = inf)."""
    om = np.asarray(omegas, float).reshape(-1)
    di = np.broadcast_to(np.asarray(diameters, float), om.shape)
    if om.size == 0:
        raise InvalidValueError("omegas: need at least one hypothesis")
    return float(np.mean(is_correct(om, di, z)))


def recall_curve(omegas, diameters, zs=None) -> tuple[np.ndarray, np.ndarray]:
    """Recall over a range of ``z`` (default 0 to 0.5 in steps of 0.01); returns (zs, recalls)."""
    zs = np.linspace(0.0, 0.5, 51) if zs is None else np.asarray(zs, float).reshape(-1)
    om = np.asarray(omegas, float).reshape(-1)
    if om.size == 0:
        raise InvalidValueError("omegas: need at least one hypothesis")
    ratio = om / np.broadcast_to(np.asarray(diameters, float), om.shape)
    # Sorted ratios give every recall in one pass (monotone in z).
    r = np.sort(ratio)
    return zs, np.searchsorted(r, zs, side="right") / len(r)

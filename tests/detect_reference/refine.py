"""Refinement in numpy with a KD-tree (the reference of ``isa._core.refine_pose``; the
method in ``isa.detection.refine``)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from detect_reference.verify import visible_points
from isa.camera import Intrinsics
from isa.detection.refine import Refinement, RefineParams
from isa.evaluation.boxes3d import rot_z, yaw_from_rotation


def _apply(M: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points @ M.T`` for (N, 3) points; einsum, because a threaded BLAS matmul of a thin
    (N, 3) array is slow on a busy machine."""
    return np.einsum("ij,nj->ni", M, points)


def _in_box(points_up: np.ndarray, centre_up: np.ndarray, yaw: float, half: np.ndarray) -> np.ndarray:
    d = points_up - centre_up
    c, s = math.cos(yaw), math.sin(yaw)
    return (np.abs(d[:, 0] * c + d[:, 1] * s) <= half[0]) & (np.abs(d[:, 1] * c - d[:, 0] * s) <= half[1]) & (
        np.abs(d[:, 2]) <= half[2])


def _point_to_plane_step(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> tuple[float, np.ndarray]:
    """Linearised least squares of sum (n . (Rz(dyaw) q + shift - p))^2 over (dyaw, shift):
    Rz(d) q ~ q + d (e_z x q)."""
    ez_x_q = np.column_stack([-q[:, 1], q[:, 0], np.zeros(len(q))])
    J = np.column_stack([np.einsum("ij,ij->i", n, ez_x_q), n])  # (K, 4)
    r = np.einsum("ij,ij->i", n, p - q)
    # A small ridge keeps directions without constraint (a flat patch's in-plane shift) still.
    x = np.linalg.solve(J.T @ J + 1e-6 * len(q) * np.eye(4), J.T @ r)
    return float(x[0]), x[1:]


def refine_pose(points_up: np.ndarray, intrinsics: Intrinsics, R: np.ndarray, t: np.ndarray, shape_points: np.ndarray,
                bounds: np.ndarray, R_gravity: np.ndarray, params: RefineParams = RefineParams(),
                shape_normals: np.ndarray | None = None) -> Refinement:
    """numpy reference of :func:`isa.detection.refine.refine_pose` (same arguments and result)."""
    Rg = np.asarray(R_gravity, dtype=float).reshape(3, 3)
    R0 = np.asarray(R, dtype=float).reshape(3, 3)
    t0 = np.asarray(t, dtype=float).reshape(3)
    # Work in the upright frame: the object's rotation there is a yaw (after any snapping).
    A = Rg @ R0  # object -> upright
    b = Rg @ t0
    obs_up = np.asarray(points_up, dtype=float)
    lo, hi = np.asarray(bounds, dtype=float)
    centre_obj, half = (lo + hi) / 2, (hi - lo) / 2 + params.margin
    yaw0 = yaw_from_rotation(A)
    near = _in_box(obs_up, A @ centre_obj + b, yaw0, half)
    obs = obs_up[near]
    if len(obs) > params.max_points:
        obs = obs[np.linspace(0, len(obs) - 1, params.max_points).astype(np.int64)]
    rms, n_pairs, converged = float("inf"), 0, False
    if len(obs) < params.min_pairs:
        return Refinement(R0, t0, rms, len(obs), 0.0, 0.0, False)
    dists = np.geomspace(params.max_distance, params.min_distance, params.iterations)
    shape_points = np.asarray(shape_points, dtype=float)
    if shape_normals is not None:
        shape_normals = np.asarray(shape_normals, dtype=float)
    for it, dmax in enumerate(dists):
        model_up_all = _apply(A, shape_points) + b
        model_cam = _apply(Rg.T, model_up_all)  # upright -> camera: Rg^-1 = Rg.T
        idx, _, _ = visible_points(model_cam, intrinsics, params.cell_px)
        if len(idx) < params.min_pairs:
            break
        model_up = model_up_all[idx]
        dist, j = cKDTree(model_up).query(obs, distance_upper_bound=dmax)
        ok = np.isfinite(dist)
        n_pairs = int(ok.sum())
        if n_pairs < params.min_pairs:
            break
        p, q = obs[ok], model_up[j[ok]]
        rms = float(np.sqrt(np.mean(dist[ok] ** 2)))
        c = q.mean(0)  # rotate about the pairs' centroid: yaw and shift stay decoupled
        if shape_normals is not None:
            dyaw, shift = _point_to_plane_step(p - c, q - c, _apply(A, shape_normals[idx[j[ok]]]))
        else:
            # Closed-form yaw + translation taking q onto p (2D Procrustes on x, y; mean z shift).
            pc = p.mean(0)
            dp, dq = p[:, :2] - pc[:2], q[:, :2] - c[:2]
            dyaw = math.atan2(float(np.sum(dq[:, 0] * dp[:, 1] - dq[:, 1] * dp[:, 0])), float(np.sum(dq * dp)))
            shift = pc - c
        Rz = rot_z(dyaw)
        shift = shift + c - Rz @ c  # as a rotation about the upright origin followed by a shift
        if params.fix_height:
            shift[2] = 0.0
        A = Rz @ A
        b = Rz @ b + shift
        if abs(dyaw) < 1e-4 and np.linalg.norm(shift) < 1e-4 and it >= len(dists) // 2:
            converged = True
            break
    yaw_change = math.atan2(math.sin(yaw_from_rotation(A) - yaw0), math.cos(yaw_from_rotation(A) - yaw0))
    shift_total = float(np.linalg.norm((A @ centre_obj + b) - (Rg @ (R0 @ centre_obj + t0))))
    if abs(math.degrees(yaw_change)) > params.max_yaw_deg or shift_total > params.max_shift:
        return Refinement(R0, t0, rms, n_pairs, yaw_change, shift_total, False)
    R1 = np.linalg.solve(Rg, A)
    t1 = np.linalg.solve(Rg, b)
    return Refinement(R1, t1, rms, n_pairs, yaw_change, shift_total, converged)

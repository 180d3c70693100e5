"""Refinement: ICP of a category shape onto the observed points around a hypothesis, with the
object kept upright (yaw about gravity and a translation: 4 degrees of freedom).

Correspondences go from the observed points to the shape's surface the camera would see at the
current pose (z-buffered as in verification), nearest neighbours, trimmed at a distance that
shrinks over the iterations so clutter and neighbours beside the object stop pulling. Each step is the closed-form least-squares yaw
and translation in the upright frame (a 2D Procrustes problem plus the mean height change).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isa import _core
from isa.camera import Intrinsics
from isa.detection.stage_params import StageParams, core_params

__all__ = ["RefineParams", "Refinement", "upright_points", "refine_pose"]



# The fields are the core's section, one per parameter (stage_params.core_params).
@core_params("refine")
class RefineParams(StageParams):
    """``iterations`` of ICP; the trimming distance falls from ``max_distance`` to
    ``min_distance`` (metres) geometrically; ``margin`` (metres) around the shape's box that
    observed points are gathered from; ``max_yaw_deg`` / ``max_shift`` bound the total
    change (a hypothesis that wanders further was not the object's); ``min_pairs`` below which
    the pose is left as it is; ``max_points`` observed points used at most (evenly
    subsampled); ``cell_px`` the z-buffer cell for the shape's visible surface; ``fix_height``
    keeps the height (the detector sets it when a floor is found). Defaults: the core's."""



@dataclass(frozen=True)
class Refinement:
    """The refined pose (``R``, ``t``, camera frame), the RMS distance of the final pairs and
    their count, the yaw change (radians) and the shift (metres) against the start."""

    R: np.ndarray
    t: np.ndarray
    rms: float
    pairs: int
    yaw_change: float
    shift: float
    converged: bool


def upright_points(depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray, stride: int = 2,
                   floor_height: float | None = None, floor_clearance: float = 0.02) -> np.ndarray:
    """Upright-frame points (N, 3) of the valid pixels on a ``stride`` grid, leaving out those
    less than ``floor_clearance`` above ``floor_height`` (when given)."""
    d = np.asarray(depth, dtype=float)[::stride, ::stride]
    v, u = np.nonzero(d > 0)
    z = d[v, u]
    u, v = u * stride, v * stride
    cam = np.column_stack([(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z])
    # einsum, not a matmul: a threaded BLAS product of a thin (N, 3) array is slow on a busy machine.
    up = np.einsum("ij,nj->ni", np.asarray(R_gravity, dtype=float).reshape(3, 3), cam)
    return up if floor_height is None else up[up[:, 2] > floor_height + floor_clearance]


def refine_pose(points_up: np.ndarray, intrinsics: Intrinsics, R: np.ndarray, t: np.ndarray, shape_points: np.ndarray,
                bounds: np.ndarray, R_gravity: np.ndarray, params: RefineParams = RefineParams(),
                shape_normals: np.ndarray | None = None) -> Refinement:
    """Refine the pose ``(R, t)`` (object to camera) of a shape (object-frame ``shape_points``
    (N, 3), axis-aligned ``bounds`` (2, 3)) on the observed points ``points_up`` (M, 3) in the
    upright frame (``R_gravity`` @ camera points, :func:`upright_points`; the floor left out, so
    that it does not pull the object down).
    With ``shape_normals`` (N, 3) each step is point-to-plane (converges on the surface rather
    than on the nearest sample), else point-to-point.

    ``R_gravity`` is camera to upright (z up).
    """
    f = np.ascontiguousarray
    r = _core.refine_pose(f(points_up, dtype=float).reshape(-1, 3), intrinsics, intrinsics.width, intrinsics.height,
                          np.asarray(R, dtype=float).reshape(3, 3), np.asarray(t, dtype=float).reshape(3),
                          f(shape_points, dtype=float).reshape(-1, 3), np.asarray(bounds, dtype=float).reshape(2, 3),
                          np.asarray(R_gravity, dtype=float).reshape(3, 3), params.to_dict(),
                          None if shape_normals is None else f(shape_normals, dtype=float).reshape(-1, 3))
    return Refinement(**r)

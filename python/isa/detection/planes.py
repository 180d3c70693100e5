"""Dominant planes of a depth frame in its upright frame: the floor (one height searched along
gravity) and large walls (gravity-constrained RANSAC), and their removal from the depth image.

The core finds them (``isa._core.find_planes``, ``isa_core::scene::planes``: a seeded ChaCha
stream, so the samples, not the rules, differ from the numpy version this replaced); this module
holds the parameters (defaults from ``isa._core.DETECT_DEFAULTS``) and the result types."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isa import _core
from isa.camera import Intrinsics
from isa.detection.stage_params import StageParams, core_params
from isa.exceptions import InvalidValueError

__all__ = ["PlaneParams", "Plane", "PlaneRemoval", "remove_planes"]


# The fields are the core's section, one per parameter (stage_params.core_params).
@core_params("planes")
class PlaneParams(StageParams):
    """Plane finding. ``tolerance`` ``(base, k)``: a point is on a plane within
    ``max(base, k * depth**2)`` metres (Kinect noise grows with the square of the depth; k = 3
    sigma of Khoshelham & Elberink's 1.5e-3 z**2). The floor must hold ``min_floor_fraction`` of
    the points and lie at least ``min_floor_drop`` below the camera; a wall must hold
    ``min_wall_fraction``, and its points must span ``min_wall_height`` vertically and
    ``min_wall_width`` along it (so bed sides and cupboard fronts are kept); the best
    ``wall_candidates`` distinct hypotheses are checked in turn. ``samples`` points are used to
    score ``ransac_iterations`` wall hypotheses and ``check_samples`` to screen candidates before
    the test on every point; ``seed`` makes it reproducible. Defaults: the core's."""



@dataclass(frozen=True, eq=False)
class Plane:
    """A plane ``normal . x + offset = 0`` of the upright frame (``normal`` unit, (3,)).

    ``kind``: ``"floor"`` (normal +z, so ``height = -offset``) or ``"wall"`` (horizontal normal);
    ``n_inliers``: valid pixels within tolerance of it.
    """

    kind: str
    normal: np.ndarray
    offset: float
    n_inliers: int

    @property
    def height(self) -> float:
        """The floor's height (z) in the upright frame (only meaningful for a floor)."""
        return -self.offset / float(self.normal[2]) if abs(self.normal[2]) > 1e-9 else float("nan")

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (N,) of upright points (N, 3)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return p[:, 0] * self.normal[0] + p[:, 1] * self.normal[1] + p[:, 2] * self.normal[2] + self.offset

    def to_dict(self) -> dict:
        return {"kind": self.kind, "normal": np.asarray(self.normal).tolist(), "offset": float(self.offset),
                "n_inliers": int(self.n_inliers)}


@dataclass(eq=False)
class PlaneRemoval:
    """What :func:`remove_planes` did: the cleaned ``depth`` (H, W) float32, the ``planes``, and
    ``removed`` (H, W) bool, the pixels set to missing."""

    depth: np.ndarray
    planes: list[Plane]
    removed: np.ndarray

    @property
    def floor(self) -> Plane | None:
        return next((p for p in self.planes if p.kind == "floor"), None)


def checked_depth(depth: np.ndarray, intrinsics: Intrinsics, caller: str) -> np.ndarray:
    """``depth`` as a C-contiguous float32 (H, W) array of the ``intrinsics``' size; the error
    names ``caller``."""
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise InvalidValueError(f"{caller}: depth must be (H, W), got {depth.shape}")
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise InvalidValueError(f"{caller}: depth is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                                f"{intrinsics.width}x{intrinsics.height}")
    return depth


def remove_planes(depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray, params: PlaneParams = PlaneParams(),
                  floor: bool = True, walls: bool = True) -> PlaneRemoval:
    """Set the pixels of the floor (and everything under it) and of walls to 0 (missing).

    ``depth`` (H, W) float metres, 0 = missing; ``R_gravity`` camera to upright (``X_up = R_gravity
    @ X_cam``). See :class:`PlaneParams` for what counts as a floor or a wall.
    """
    depth = checked_depth(depth, intrinsics, "remove_planes")
    found = _core.find_planes(depth, intrinsics, np.asarray(R_gravity, dtype=float).reshape(3, 3), params.to_dict(),
                              floor, walls)
    return removal_from_core(depth, found)


def removal_from_core(depth: np.ndarray, found: dict) -> PlaneRemoval:
    """A :class:`PlaneRemoval` of ``isa._core.find_planes``' answer on ``depth``."""
    removed = found["removed"]
    out = depth.copy()
    out[removed] = 0.0
    planes = [Plane(p["kind"], np.asarray(p["normal"]), p["offset"], p["n_inliers"]) for p in found["planes"]]
    return PlaneRemoval(out, planes, removed)

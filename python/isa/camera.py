"""Pinhole camera model shared by rendering, annotation, voting and evaluation.

Conventions (used everywhere in isa):
- OpenCV camera frame: x right, y down, z forward (metres); pixel centres at integer (u, v).
- A pose (R, t) maps object-frame points into the camera frame: X_cam = R @ X_obj + t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isa.exceptions import InvalidValueError


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics; ``width`` x ``height`` is the image size in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0):
            raise InvalidValueError(f"Intrinsics: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not (self.width > 0 and self.height > 0):
            raise InvalidValueError(f"Intrinsics: image size must be positive, got {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_K(cls, K, width: int, height: int) -> "Intrinsics":
        K = np.asarray(K, dtype=float).reshape(3, 3)
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    def project(self, X: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) -> pixel coordinates (N, 2)."""
        X = np.asarray(X, dtype=float)
        z = X[:, 2]
        return np.stack([self.fx * X[:, 0] / z + self.cx, self.fy * X[:, 1] / z + self.cy], axis=1)

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """Depth image (H, W) in metres -> camera-frame points (H, W, 3); 0 depth stays 0."""
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        z = depth.astype(np.float64)
        return np.stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z], axis=-1)


#: Microsoft Kinect v1 depth camera at 640x480 (the NYU Depth v2 calibration).
KINECT_V1 = Intrinsics(fx=582.62, fy=582.69, cx=313.04, cy=238.44, width=640, height=480)


def metres_to_mm(depth, depth_scale: float = 1.0) -> np.ndarray:
    """Depth in metres -> the nearest integer depth unit (``unit * depth_scale`` = millimetres), as
    floats of the input's dtype, neither clipped nor checked: the one rounding that the core's
    uint16 millimetre images, BOP depth PNGs and Linemod's input share (callers clip or refuse
    out-of-range values their own way)."""
    return np.rint(depth * (1000.0 / depth_scale))


def depth_from_points(points, intrinsics, size: tuple[int, int] | None = None) -> np.ndarray:
    """A point cloud in the camera frame as the float32 depth image :meth:`Forest.predict
    <isa.forest.model.Forest.predict>` and :func:`isa.detection.detect` take, in the points' unit
    (pass ``depth_scale=`` when that is not metres). ``points``: (N, 3) unorganised or (H, W, 3)
    organised; each is projected through ``intrinsics`` (an :class:`Intrinsics`, a 3x3 matrix or
    (fx, fy, cx, cy)) and the nearest kept per pixel (0 = missing; points behind the camera or
    outside the image dropped). ``size`` (width, height): an organised cloud's own, else the
    intrinsics' (``Intrinsics`` carries one), else required."""
    from isa import _core

    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 3 and pts.shape[2] == 3:
        size = size or (pts.shape[1], pts.shape[0])
        pts = pts.reshape(-1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidValueError(f"points: expected (N, 3) or (H, W, 3), got shape {pts.shape}")
    if size is None:
        if not isinstance(intrinsics, Intrinsics):
            raise InvalidValueError("points: give size=(width, height) (the intrinsics carry no image size)")
        size = (intrinsics.width, intrinsics.height)
    return _core.depth_from_points(np.ascontiguousarray(pts), intrinsics, int(size[0]), int(size[1]))

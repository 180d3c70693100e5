"""Cameras as people hold or mount a depth camera in a room: 0.9-1.8 m high, pitched down 0-45
degrees, a few degrees of roll, looking into the room at the furniture.

World frame (every scene of :mod:`isa.scenes`): metres, z up, the floor at z = 0. A camera is the
OpenCV pose of the world in the camera, ``X_cam = R @ X_world + t``, with the gravity rotation
``R_gravity`` (camera to upright, ``X_up = R_gravity @ X_cam``) in the convention of
:mod:`isa.data.sunrgbd`: origin at the camera, z up, y the camera's levelled viewing direction.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from isa.camera import KINECT_V1, Intrinsics
from isa.exceptions import DataError, InvalidParameterError


@dataclass(frozen=True)
class Camera:
    """One view: world-to-camera pose (``X_cam = R @ X_world + t``) and intrinsics."""

    R: np.ndarray
    t: np.ndarray
    intrinsics: Intrinsics = KINECT_V1

    @property
    def eye(self) -> np.ndarray:
        """The camera centre in the world."""
        return -self.R.T @ self.t

    @property
    def gravity(self) -> np.ndarray:
        """``R_gravity``: camera to upright frame (z up, y the levelled optical axis)."""
        return gravity_rotation(self.R)

    def pitch_deg(self) -> float:
        """How far the optical axis points below the horizon (degrees)."""
        axis = self.R[2]  # optical axis in world coordinates
        return float(np.degrees(np.arcsin(np.clip(-axis[2], -1.0, 1.0))))

    def roll_deg(self) -> float:
        """The image's rotation about the optical axis away from level (degrees)."""
        down = self.R[1]  # image "down" in world coordinates
        right = self.R[0]
        return float(np.degrees(np.arctan2(right[2], -down[2]))) if abs(down[2]) > 1e-9 else 90.0


def gravity_rotation(R_world_to_cam: np.ndarray) -> np.ndarray:
    """Camera-to-upright rotation for a camera whose world-to-camera rotation is ``R_world_to_cam``
    (world z up): the world turned about z so that the levelled optical axis is +y."""
    R = np.asarray(R_world_to_cam, float).reshape(3, 3)
    axis = R[2]
    yaw = np.arctan2(axis[1], axis[0])
    a = np.pi / 2 - yaw
    c, s = np.cos(a), np.sin(a)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ R.T


def camera_pose(eye, yaw: float, pitch: float, roll: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at ``eye`` whose optical axis points at azimuth ``yaw``
    (radians, from +x towards +y), ``pitch`` below the horizon, turned by ``roll`` about it."""
    eye = np.asarray(eye, float).reshape(3)
    f = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), -np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])  # f x up, normalised (horizontal)
    down = np.cross(f, right)
    c, s = np.cos(roll), np.sin(roll)
    right, down = c * right + s * down, -s * right + c * down
    R = np.stack([right, down, f])
    return R, -R @ eye


@dataclass(frozen=True)
class CameraRig:
    """How the views are drawn (heights in metres above the floor, angles in degrees).

    ``distance``: horizontal distance from the camera to the point it looks at; ``aim_jitter``:
    how far (metres) the look-at point strays from the chosen target, so targets are not always
    in the image centre; ``pitch_jitter_deg``: extra pitch around the one that centres the target.
    """

    height: tuple[float, float] = (0.9, 1.8)
    pitch_deg: tuple[float, float] = (0.0, 45.0)
    roll_deg: float = 3.0
    distance: tuple[float, float] = (1.2, 4.0)
    aim_jitter: float = 0.25
    pitch_jitter_deg: float = 6.0
    intrinsics: Intrinsics = KINECT_V1

    def __post_init__(self) -> None:
        lo, hi = self.height
        if not (0 < lo <= hi):
            raise InvalidParameterError(f"CameraRig.height: need 0 < lo <= hi, got {self.height}")
        lo, hi = self.pitch_deg
        if not (-90 < lo <= hi < 90):
            raise InvalidParameterError(f"CameraRig.pitch_deg: need -90 < lo <= hi < 90, got {self.pitch_deg}")
        lo, hi = self.distance
        if not (0 < lo <= hi):
            raise InvalidParameterError(f"CameraRig.distance: need 0 < lo <= hi, got {self.distance}")


def sample_camera(
    rng: np.random.Generator,
    targets: np.ndarray,
    is_free: Callable[[np.ndarray], bool],
    rig: CameraRig = CameraRig(),
    attempts: int = 200,
) -> Camera:
    """A view of one of ``targets`` ((N, 3) world points, e.g. the instances' centres).

    A target is drawn, the camera placed at a drawn height and horizontal distance from it in a
    drawn direction, and pitched to look at it (within ``rig.pitch_deg``, plus jitter, clipped);
    ``is_free(eye)`` rejects positions outside the room or inside furniture, and the target must
    project into the image. ``DataError`` when no view passes in ``attempts`` draws.
    """
    targets = np.asarray(targets, float).reshape(-1, 3)
    if len(targets) == 0:
        raise DataError("sample_camera: no targets to look at")
    K = rig.intrinsics
    p_lo, p_hi = np.radians(rig.pitch_deg)
    for _ in range(attempts):
        target = targets[rng.integers(len(targets))]
        aim = target + np.append(rng.normal(0.0, rig.aim_jitter, 2), 0.0)
        h = rng.uniform(*rig.height)
        d = rng.uniform(*rig.distance)
        az = rng.uniform(0.0, 2 * np.pi)
        eye = np.array([aim[0] - d * np.cos(az), aim[1] - d * np.sin(az), h])
        if not is_free(eye):
            continue
        pitch = np.arctan2(h - aim[2], d) + np.radians(rng.normal(0.0, rig.pitch_jitter_deg))
        pitch = float(np.clip(pitch, p_lo, p_hi))
        roll = np.radians(rng.uniform(-rig.roll_deg, rig.roll_deg))
        R, t = camera_pose(eye, az, pitch, roll)
        x = R @ target + t
        if x[2] <= 0.3:
            continue
        u, v = K.fx * x[0] / x[2] + K.cx, K.fy * x[1] / x[2] + K.cy
        if 0 <= u < K.width and 0 <= v < K.height:
            return Camera(R, t, K)
    raise DataError(f"sample_camera: no free view of the {len(targets)} targets in {attempts} draws")

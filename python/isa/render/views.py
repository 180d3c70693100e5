"""Viewpoints: look-at camera poses, the paper's 89 training views, and random test views.

A view is a pose (R, t) of the object frame in the OpenCV camera frame (``X_cam = R @ X_obj + t``)
of an upright camera (no roll unless asked) looking at the object-frame origin from a point of
the upper hemisphere, at indoor distances (1.5-4 m by default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isa.camera import KINECT_V1, Intrinsics
from isa.categories import PAPER_VIEWS
from isa.exceptions import InvalidValueError

__all__ = [
    "GOLDEN_ANGLE", "Views", "ViewBand", "look_at", "hemisphere_directions", "fit_distance", "training_views", "sample_test_views",
]

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True)
class ViewBand:
    """Where the cameras of a dataset stand: distances (metres) uniform in ``distance``, directions
    between the two elevations ``elevation_deg`` (degrees above the horizon), rolls uniform in
    +-``roll_deg``, all looking at ``target`` (object frame). One band describes both the
    training and the test views of a dataset (:func:`training_views`, :func:`sample_test_views`)."""

    distance: tuple[float, float] = (1.5, 4.0)
    elevation_deg: tuple[float, float] = (10.0, 80.0)
    roll_deg: float = 0.0
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Views:
    """N camera poses: ``R`` (N, 3, 3), ``t`` (N, 3) metres, and the camera centres ``eye`` (N, 3)
    in the object frame."""

    R: np.ndarray
    t: np.ndarray
    eye: np.ndarray

    def __len__(self) -> int:
        return len(self.R)

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        return self.R[i], self.t[i]


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), roll: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pose (R, t) of a camera at ``eye`` looking at ``target`` (object frame), image "up" along ``up``.

    ``roll`` (radians) turns the camera about its optical axis. When the viewing direction is
    parallel to ``up`` (looking straight down), the object's +y is used as image up instead.
    """
    eye, target, up = (np.asarray(a, dtype=float) for a in (eye, target, up))
    z = target - eye
    n = np.linalg.norm(z)
    if n == 0:
        raise InvalidValueError("look_at: eye and target coincide")
    z /= n
    y = -(up - (up @ z) * z)  # OpenCV y points down in the image
    if np.linalg.norm(y) < 1e-9:
        alt = np.array([0.0, 1.0, 0.0])
        y = -(alt - (alt @ z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        x, y = c * x + s * y, -s * x + c * y
    R = np.stack([x, y, z])  # rows: camera axes in object coordinates
    return R, -R @ eye


def hemisphere_directions(n: int, elevation_deg: tuple[float, float] = (10.0, 80.0), azimuth0: float = 0.0) -> np.ndarray:
    """``n`` unit vectors spread evenly (Fibonacci lattice, equal area) over a band of the upper
    hemisphere between the two elevations (degrees above the horizon); ``azimuth0`` rotates them."""
    lo, hi = np.radians(elevation_deg)
    if not (0 <= lo < hi <= np.pi / 2):
        raise InvalidValueError(f"elevation_deg must satisfy 0 <= lo < hi <= 90, got {elevation_deg}")
    i = np.arange(n) + 0.5
    # Equal-area: sin(elevation) uniform in [sin lo, sin hi].
    s = np.sin(lo) + (np.sin(hi) - np.sin(lo)) * i / n
    el = np.arcsin(s)
    az = azimuth0 + GOLDEN_ANGLE * i
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)


def fit_distance(R: np.ndarray, points, target, intrinsics: Intrinsics = KINECT_V1, margin_px: float = 8.0, znear: float = 0.1) -> float:
    """Smallest distance from ``target`` along the optical axis of a camera with rotation ``R``
    (looking at ``target``) at which every point of ``points`` (object frame) projects inside the
    image with ``margin_px`` to spare and lies ``znear`` in front of the camera.

    With the camera at distance d, a point's camera coordinates are R (p - target) + (0, 0, d), so
    each image bound gives d >= f |x| / room - z in closed form.
    """
    K = intrinsics
    X = (np.asarray(points, float) - np.asarray(target, float)) @ np.asarray(R).T
    room_u = np.where(X[:, 0] > 0, K.width - 1 - margin_px - K.cx, K.cx - margin_px)
    room_v = np.where(X[:, 1] > 0, K.height - 1 - margin_px - K.cy, K.cy - margin_px)
    if np.any(room_u <= 0) or np.any(room_v <= 0):
        raise InvalidValueError(f"fit_distance: margin {margin_px} px leaves no room in a {K.width}x{K.height} image")
    d = np.concatenate([K.fx * np.abs(X[:, 0]) / room_u - X[:, 2], K.fy * np.abs(X[:, 1]) / room_v - X[:, 2], znear - X[:, 2]])
    return float(d.max())


def _views_from(dirs: np.ndarray, rng: np.random.Generator, band: ViewBand, fit_points, intrinsics: Intrinsics) -> Views:
    """Views along ``dirs`` from the band's target, its distances and rolls drawn from ``rng`` (the
    samplers' common last step)."""
    n = len(dirs)
    dist = rng.uniform(*band.distance, size=n)
    roll = np.radians(rng.uniform(-band.roll_deg, band.roll_deg, size=n))
    target = np.asarray(band.target, float)
    Rs, ts, eyes = [], [], []
    for d, r, dirn in zip(dist, roll, dirs):
        R, _ = look_at(target + dirn, target, roll=r)  # the rotation does not depend on the distance
        if fit_points is not None:
            d = max(d, fit_distance(R, fit_points, target, intrinsics))
        eye = target + dirn * d
        Rs.append(R)
        ts.append(-R @ eye)
        eyes.append(eye)
    return Views(np.array(Rs), np.array(ts), np.array(eyes))


def training_views(
    n: int = PAPER_VIEWS,
    seed: int = 0,
    band: ViewBand = ViewBand(),
    fit_points=None,
    intrinsics: Intrinsics = KINECT_V1,
) -> Views:
    """The training viewpoints: ``n`` (89, as in the paper) directions evenly over the ``band``
    (:class:`ViewBand`) with a seeded azimuth offset, its distances and rolls, all reproducible
    from ``seed``.

    With ``fit_points`` (e.g. the mesh's convex-hull vertices) a view is moved back, when needed,
    until those points are all inside the ``intrinsics`` image (:func:`fit_distance`): large
    objects such as beds then keep whole in view.
    """
    rng = np.random.default_rng(seed)
    dirs = hemisphere_directions(n, band.elevation_deg, azimuth0=rng.uniform(0, 2 * np.pi))
    return _views_from(dirs, rng, band, fit_points, intrinsics)


def sample_test_views(
    n: int,
    seed: int = 1,
    exclude: Views | None = None,
    min_separation_deg: float = 3.0,
    band: ViewBand = ViewBand(),
    fit_points=None,
    intrinsics: Intrinsics = KINECT_V1,
) -> Views:
    """``n`` random viewpoints (uniform over the hemisphere band's area), each at least
    ``min_separation_deg`` away in direction from every view of ``exclude`` (the training set), so
    that no test view is a training view. ``band``, ``fit_points``, ``intrinsics`` as in
    :func:`training_views`."""
    rng = np.random.default_rng(seed)
    lo, hi = np.sin(np.radians(band.elevation_deg))
    ex = None
    if exclude is not None and len(exclude):
        ex = exclude.eye - np.asarray(band.target, float)
        ex /= np.linalg.norm(ex, axis=1, keepdims=True)
    cos_min = np.cos(np.radians(min_separation_deg))
    dirs: list[np.ndarray] = []
    for _ in range(1000 * max(n, 1)):
        if len(dirs) == n:
            break
        el, az = np.arcsin(rng.uniform(lo, hi)), rng.uniform(0, 2 * np.pi)
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        if ex is None or np.max(ex @ d) < cos_min:
            dirs.append(d)
    if len(dirs) < n:
        raise InvalidValueError(f"sample_test_views: could not place {n} views {min_separation_deg} deg away from the training views")
    return _views_from(np.array(dirs).reshape(-1, 3), rng, band, fit_points, intrinsics)

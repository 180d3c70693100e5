"""Optional Kinect-v1-like depth noise, to narrow the synthetic-to-real gap (off by default: the
paper's protocol renders clean depth).

The model combines, in this order:
1. lateral noise: each pixel reads the clean depth at a randomly shifted position (Gaussian,
   ``lateral_px``), as in the ICL-NUIM simulator (Handa et al., ICRA 2014);
2. axial noise growing with depth and with the viewing angle theta (Nguyen, Izadi, Lovell,
   "Modeling Kinect Sensor Noise for Improved 3D Reconstruction and Tracking", 3DIMPVT 2012):
   sigma_z = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2  [m];
3. disparity quantisation: the Kinect v1 measures disparity in 1/8 pixel steps with a
   ~7.5 cm baseline (Khoshelham & Elberink, Sensors 2012), so depth steps grow as z^2;
4. missing pixels: at grazing angles (theta beyond ``grazing_deg``), next to depth
   discontinuities (jumps over ``edge_jump`` m; probability ``edge_drop``), and at random
   (``dropout``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from isa.camera import Intrinsics

__all__ = ["KinectNoise", "apply_kinect_noise"]


@dataclass(frozen=True)
class KinectNoise:
    """Parameters of :func:`apply_kinect_noise` (defaults: a Kinect v1)."""

    lateral_px: float = 0.5
    axial: bool = True
    baseline_m: float = 0.075
    disparity_step_px: float = 1.0 / 8.0
    grazing_deg: float = 78.0
    edge_jump: float = 0.05
    edge_drop: float = 0.5
    dropout: float = 0.005


def _view_angle(depth: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Angle (rad) between each pixel's surface normal (from depth gradients) and its viewing ray."""
    P = K.backproject(depth)
    du = np.gradient(P, axis=1)
    dv = np.gradient(P, axis=0)
    n = np.cross(du, dv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
    ray = P / (np.linalg.norm(P, axis=-1, keepdims=True) + 1e-12)
    return np.arccos(np.clip(np.abs(np.sum(n * ray, axis=-1)), 0.0, 1.0))


def apply_kinect_noise(
    depth: np.ndarray, intrinsics: Intrinsics, seed: int | np.random.Generator | None = 0, params: KinectNoise = KinectNoise()
) -> np.ndarray:
    """Noisy copy of a clean float32 depth image in metres (0 = missing stays missing)."""
    rng = np.random.default_rng(seed)
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    valid = depth > 0
    theta = _view_angle(depth, intrinsics)
    out = depth.copy()
    if params.lateral_px > 0:
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        su = np.clip(np.rint(u + rng.normal(0, params.lateral_px, (h, w))), 0, w - 1).astype(int)
        sv = np.clip(np.rint(v + rng.normal(0, params.lateral_px, (h, w))), 0, h - 1).astype(int)
        out = depth[sv, su]
        theta = theta[sv, su]
        valid = out > 0
    z = np.where(valid, out, 1.0).astype(np.float64)
    if params.axial:
        th = np.minimum(theta, np.radians(89.0))
        sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / np.sqrt(z) * th**2 / (np.pi / 2 - th) ** 2
        z = z + rng.normal(0.0, 1.0, z.shape) * sigma
    if params.disparity_step_px > 0:
        fb = intrinsics.fx * params.baseline_m
        disp = np.round(fb / np.maximum(z, 1e-3) / params.disparity_step_px) * params.disparity_step_px
        z = fb / np.maximum(disp, params.disparity_step_px)
    drop = ~valid | (theta > np.radians(params.grazing_deg))
    if params.edge_drop > 0:
        d = np.where(valid, out, 0.0)
        jump = (ndimage.maximum_filter(d, 3) - ndimage.minimum_filter(np.where(valid, d, np.inf), 3)) > params.edge_jump
        drop |= jump & (rng.random((h, w)) < params.edge_drop)
    drop |= rng.random((h, w)) < params.dropout
    return np.where(drop, 0.0, z).astype(np.float32)


#: Depth agreement tolerance (metres) at depth z: ``max(base, k * z**2)``, the Kinect v1 error envelope;
#: shared by plane finding and hypothesis verification.
DEPTH_TOLERANCE: tuple[float, float] = (0.03, 0.0045)

"""Gravity for a frame that does not come with it: the floor's normal, else the votes' tilt.

A gravity rotation ``R_gravity`` maps camera coordinates to the upright frame (``X_up =
R_gravity @ X_cam``: z up, y the viewing direction levelled, x to its right; as
:mod:`isa.sunrgbd`). It is fixed by one vector, "up" in camera coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from isa.camera import Intrinsics

__all__ = ["LEVEL", "GravityEstimate", "rotation_from_up", "floor_up", "votes_up", "estimate_gravity"]

#: The gravity rotation of a level camera (up is the camera's -y).
LEVEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class GravityEstimate:
    """``R`` the gravity rotation; ``source`` where it came from: "given", "floor", "votes" or
    "level" (nothing to go on: the camera is assumed level); ``support`` the floor's inliers or
    the hypotheses used."""

    R: np.ndarray
    source: str
    support: int = 0


def rotation_from_up(up_cam: np.ndarray) -> np.ndarray:
    """The gravity rotation whose z axis is ``up_cam`` (3,) (camera coordinates)."""
    z = np.asarray(up_cam, dtype=float).reshape(3)
    z = z / np.linalg.norm(z)
    fwd = np.array([0.0, 0.0, 1.0])
    y = fwd - (fwd @ z) * z
    if np.linalg.norm(y) < 1e-6:  # looking straight down or up: image "up" (-y) as the heading
        alt = np.array([0.0, -1.0, 0.0])
        y = alt - (alt @ z) * z
    y /= np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z])


def floor_up(depth: np.ndarray, intrinsics: Intrinsics, max_angle_deg: float = 50.0, min_drop: float = 0.4,
             min_fraction: float = 0.05, iterations: int = 300, samples: int = 4000, tolerance: float = 0.03,
             seed: int = 0) -> tuple[np.ndarray, int] | None:
    """The floor's upward normal in camera coordinates by RANSAC, or None.

    The floor is the best-supported plane whose normal is within ``max_angle_deg`` of the
    camera's -y (people hold cameras roughly upright) with the camera at least ``min_drop`` above
    it, holding at least ``min_fraction`` of the sampled points. Returns (up (3,), inliers)."""
    d = np.asarray(depth, dtype=float)
    v, u = np.nonzero(d > 0)
    if len(v) < 50:
        return None
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(v), min(samples, len(v)), replace=False)
    z = d[v[pick], u[pick]]
    p = np.column_stack([(u[pick] - intrinsics.cx) * z / intrinsics.fx,
                         (v[pick] - intrinsics.cy) * z / intrinsics.fy, z])
    tri = rng.integers(0, len(p), (iterations, 3))
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n[ok] /= norm[ok, None]
    n[n[:, 1] > 0] *= -1  # point the normal up (camera -y)
    off = -np.einsum("ij,ij->i", n, a)  # n.x + off = 0; the camera (x = 0) is at height off
    ok &= (-n[:, 1] >= np.cos(np.radians(max_angle_deg))) & (off >= min_drop)
    if not ok.any():
        return None
    dist = np.abs(np.einsum("kj,nj->kn", n[ok], p) + off[ok, None])
    support = (dist < tolerance).sum(1)
    best = int(np.argmax(support))
    if support[best] < min_fraction * len(p):
        return None
    # Least squares on the inliers.
    inl = p[dist[best] < tolerance]
    centre = inl.mean(0)
    normal = np.linalg.svd(inl - centre, full_matrices=False)[2][2]
    if normal[1] > 0:
        normal = -normal
    return normal, int(support[best])


def votes_up(hypotheses: Sequence[dict], top: int = 10) -> np.ndarray | None:
    """Up in camera coordinates as the score-weighted mean of the best hypotheses' object z axes
    (furniture stands upright), or None without hypotheses."""
    hs = list(hypotheses)[:top]
    if not hs:
        return None
    w = np.array([max(float(h.get("score", 1.0)), 1e-12) for h in hs])
    zs = np.array([np.asarray(h["R"], dtype=float)[:, 2] for h in hs])
    m = (w[:, None] * zs).sum(0)
    return m / np.linalg.norm(m) if np.linalg.norm(m) > 1e-9 else None


def estimate_gravity(depth: np.ndarray, intrinsics: Intrinsics, gravity: np.ndarray | None = None,
                     hypotheses: Sequence[dict] = ()) -> GravityEstimate:
    """``gravity`` when given; else the floor's normal (:func:`floor_up`); else the votes'
    tilt (:func:`votes_up`); else a level camera."""
    if gravity is not None:
        return GravityEstimate(np.asarray(gravity, dtype=float).reshape(3, 3), "given")
    f = floor_up(depth, intrinsics)
    if f is not None:
        return GravityEstimate(rotation_from_up(f[0]), "floor", f[1])
    up = votes_up(hypotheses)
    if up is not None:
        return GravityEstimate(rotation_from_up(up), "votes", min(len(hypotheses), 10))
    return GravityEstimate(LEVEL.copy(), "level")

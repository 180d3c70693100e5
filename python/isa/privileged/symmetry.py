"""Rotational symmetry about the vertical axis: what a depth image cannot tell apart.

A rectangular table turned by 180 degrees about its vertical axis renders the very same depth
image, so no estimator that sees only the image can know which of the two poses is the true one.
This module finds an instance's group of such turns (:func:`find_yaw_symmetry`: none, C2, C3,
C4, C6 or continuous), and uses it twice:

- **Ceiling** (:func:`recall_ceiling`): under the paper's metric (Eq. 14, which does not forgive
  symmetries), an estimator blind to the symmetry is right on at most the share of the group that
  lies within the threshold of the true pose: 1/2 on a C2 table, whatever the method.
- **Canonical training labels** (:func:`canonical_pose`, :func:`canonical_frames`): a training
  view of a symmetric instance is labelled with the one pose of the category's shared group
  (:func:`common_subgroup`) that puts the camera nearest the object's front (-y), so that
  identical-looking training parts carry one rotation label, not two that split the votes, and
  the forest answers with a fixed convention. Views, parts and the evaluation stay as they are.

Poses are ``X_cam = R @ X_obj + t``; a turn ``g`` by ``theta`` about the vertical axis through
``centre`` maps the pose to ``R' = R g``, ``t' = t + R (centre - g centre)``: the same image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from isa.data import bop
from isa.evaluation.boxes3d import rot_z
from isa.exceptions import InvalidParameterError
from isa.privileged.mirror import SYMMETRY_TOLERANCE

__all__ = [
    "ORDERS", "YawSymmetry", "find_yaw_symmetry", "recall_ceiling", "canonical_turn", "canonical_pose", "common_subgroup",
    "canonical_frames",
]

#: Orders of discrete turn groups that are tested, largest first (C6 before C3 and C2, ...).
ORDERS = (6, 4, 3, 2)
#: Turns (degrees) that must all map the surface onto itself for a continuous symmetry (a round
#: table): not multiples of 360/n for any n in ORDERS.
_CONTINUOUS_PROBES_DEG = (25.0, 50.0, 100.0, 155.0)
#: Grid on which the continuous group's share within the threshold is measured.
_CONTINUOUS_GRID = 720


@dataclass(frozen=True)
class YawSymmetry:
    """Turns about the vertical axis through ``centre`` (object frame) that map the instance onto
    itself: ``order`` n for the n turns by 360k/n degrees, 0 for every angle (continuous), 1 for
    none. ``error``: the largest mean surface-to-turned-surface distance over the group's tested
    turns, as a fraction of the diameter (0 when there is no symmetry)."""

    centre: np.ndarray
    order: int
    error: float

    @property
    def is_symmetric(self) -> bool:
        return self.order != 1

    def angles(self, n_continuous: int = _CONTINUOUS_GRID) -> np.ndarray:
        """The group's turns in radians (``n_continuous`` evenly spaced ones if continuous)."""
        n = n_continuous if self.order == 0 else self.order
        return 2 * np.pi * np.arange(n) / n


def find_yaw_symmetry(mesh: trimesh.Trimesh, tolerance: float = SYMMETRY_TOLERANCE, n_points: int = 20000,
                      seed: int = 0) -> YawSymmetry:
    """The largest group of turns about a vertical axis that map ``mesh`` onto itself.

    The axis goes through the surface's area centroid (which every symmetry of the surface keeps).
    A turn counts when the mean distance from the turned surface samples to the surface is below
    ``tolerance`` of the diameter (the same test and tolerance as :func:`isa.privileged.mirror.find_mirror`).
    """
    if not (0 < tolerance < 1):
        raise InvalidParameterError(f"tolerance must be in (0, 1), got {tolerance}")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidParameterError("mesh: expected a trimesh.Trimesh with triangles")
    pts = np.asarray(trimesh.sample.sample_surface(mesh, n_points, seed=seed)[0])
    diam = float(np.linalg.norm(mesh.extents))
    area = float(mesh.area)
    surface_centroid = (mesh.triangles_center * mesh.area_faces[:, None]).sum(0) / area if area > 0 else mesh.centroid
    centre = np.array([surface_centroid[0], surface_centroid[1], 0.0])
    if diam <= 0:
        return YawSymmetry(centre, 1, 0.0)
    tree = cKDTree(pts)
    local = pts - centre

    def error(theta: float) -> float:
        return float(tree.query(local @ rot_z(theta).T + centre)[0].mean()) / diam

    def group_error(angles) -> float | None:
        """The largest error over ``angles``, or None as soon as one turn fails (most shapes fail
        the first turn tested, and a failed turn's nearest-neighbour queries are the slow ones)."""
        worst = 0.0
        for a in angles:
            worst = max(worst, error(a))
            if worst >= tolerance:
                return None
        return worst

    err = group_error(np.radians(_CONTINUOUS_PROBES_DEG))
    if err is not None:
        return YawSymmetry(centre, 0, err)
    for n in ORDERS:
        err = group_error(2 * np.pi * np.arange(1, n) / n)
        if err is not None:
            return YawSymmetry(centre, n, err)
    return YawSymmetry(centre, 1, 0.0)


def recall_ceiling(points: np.ndarray, sym: YawSymmetry, diameter: float, z: float = 0.1) -> float:
    """Best expected recall at ``z`` of any estimator that cannot see the symmetry (Eq. 14-15).

    The image fixes the pose only up to the group; with the views spread evenly around the
    object, each pose of the group is equally likely to be the true one. An estimate is correct
    for the group's poses within ``z * diameter`` of it (Eq. 14 between two poses of the group
    is ``mean |(g - I)(X - centre)|``, whatever the view), so the ceiling is their share.
    """
    X = np.asarray(points, float) - sym.centre
    if not (diameter > 0 and z >= 0):
        raise InvalidParameterError(f"need diameter > 0 and z >= 0, got {diameter}, {z}")
    ok = [np.linalg.norm(X @ (rot_z(a) - np.eye(3)).T, axis=1).mean() <= z * diameter for a in sym.angles()]
    return float(np.mean(ok))


def canonical_turn(R: np.ndarray, t: np.ndarray, sym: YawSymmetry) -> float:
    """The turn (radians) of the group that brings the camera nearest the object's front (-y)."""
    eye = -np.asarray(R).T @ np.asarray(t)  # camera centre in the object frame
    d = eye - sym.centre
    azimuth = np.arctan2(d[1], d[0])
    # Turning the instance by theta moves the camera's azimuth, seen from the object, by -theta.
    want = azimuth + np.pi / 2  # the theta that would put the camera at -90 degrees (front)
    if sym.order == 0:
        return float(want)
    if sym.order == 1:
        return 0.0
    step = 2 * np.pi / sym.order
    return float(step * np.round(want / step))


def canonical_pose(R: np.ndarray, t: np.ndarray, sym: YawSymmetry) -> tuple[np.ndarray, np.ndarray]:
    """The pose of the group that :func:`canonical_turn` picks: the same depth image, one label."""
    R = np.asarray(R, float)
    t = np.asarray(t, float)
    theta = canonical_turn(R, t, sym)
    if theta == 0.0:
        return R, t
    g = rot_z(theta)
    return R @ g, t + R @ (sym.centre - g @ sym.centre)


def common_subgroup(symmetries: dict[int, YawSymmetry]) -> dict[int, YawSymmetry]:
    """Each instance's symmetry cut down to the turn group that the category's symmetric instances share.

    Labels must agree across instances, not only within one: a square table (C4) labelled by its
    own group puts the camera within 45 degrees of its front, where a rectangular one (C2) allows
    90, so the two would vote 90 degrees apart for the same-looking view. The shared group is the
    C_n (n in :data:`ORDERS`) that the most instances' groups contain (continuous ones contain
    every C_n; ties go to the larger n); instances whose group does not contain it (a three-legged
    table among rectangles) are left unlabelled, as are those without a symmetry.
    """
    def contains(s: YawSymmetry, n: int) -> bool:
        return s.order == 0 or (s.order > 1 and s.order % n == 0)

    counts = {n: sum(contains(s, n) for s in symmetries.values()) for n in ORDERS}
    best = max(counts.values(), default=0)
    if best == 0 or all(s.order == 0 for s in symmetries.values() if s.is_symmetric):
        return dict(symmetries)  # nothing symmetric, or only round ones (which share every turn)
    common = max(n for n, c in counts.items() if c == best)
    return {k: replace(s, order=common) if contains(s, common) else YawSymmetry(s.centre, 1, s.error)
            for k, s in symmetries.items()}


def canonical_frames(frames: Sequence[bop.BopFrame], symmetries: dict[int, YawSymmetry | None]) -> bop.MappedFrames:
    """``frames`` with the poses of symmetric instances replaced by their canonical ones (the
    depth images stay; the projected skeleton follows the pose, so its nodes swap with the turn).
    Relabelled when read (:class:`isa.data.bop.MappedFrames`)."""
    items: list = []
    for i, o in enumerate(bop.frame_obj_ids(frames)):
        sym = symmetries.get(o)
        items.append((i, None if sym is None or not sym.is_symmetric else partial(_canonical_frame, sym=sym)))
    return bop.MappedFrames(frames, items)


def _canonical_frame(f: bop.BopFrame, sym: YawSymmetry) -> bop.BopFrame:
    R, t = canonical_pose(f.R, f.t, sym)
    return replace(f, R=R, t=t)

"""Verification: how well the observed depth agrees with a category shape at a hypothesis' pose.

The shape's surface samples are moved to the pose and z-buffered on a grid of image cells (so
only the surface the camera would see counts, self-occlusion included). Each visible cell is
compared with the observed depth at its pixel, within the sensor tolerance ``max(base, k z^2)``:

- **agree**: the observed surface is where the shape's is;
- **violate**: the observed surface is well *behind* the shape's: we see through where the
  object would be, so it is not there (free space); or it is a wall or the floor in front of
  it (nothing stands behind a wall or under the floor), when the planes are known;
- **occluded**: the observed surface (not a plane) is in front: something hides the object, no
  evidence; a shape surface lying on a plane counts here too;
- **missing**: no depth at that pixel (no evidence);
- **outside**: the cell falls outside the image (no evidence; the z-buffer spans the image
  and its size again around it).

With ``unexplained_weight`` > 0 (default 0) one more count enters, from the image's side:
**unexplained**, a cell of observed surface inside the shape's box (grown by ``lateral``, above
the floor) that lies in front of the shape's surface or where the shape has none (a bed's
solid side under a table hypothesis' top).

The score is ``(agree - violation_weight * violate - unexplained_weight * unexplained) /
(agree + violate + occluded + outside)``:
the share of the shape's surface facing the camera that the image confirms, minus what it
refutes; a hypothesis mostly hidden or out of view cannot score high on the little that shows. It is a fraction
in ``[-violation_weight, 1]`` (lower with unexplained cells) whatever the frame, the category or the object's distance, so
scores of different categories and frames can be ranked together. Verification runs on the raw
depth (floor and walls kept): a hypothesis floating in front of a wall or sinking into the floor
is refuted by exactly those pixels.

The core does the work (``isa._core.verify_pose``, ``isa_core::scene::verify``); this module
holds the parameters (defaults from ``isa._core.DETECT_DEFAULTS``) and the result type.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isa import _core
from isa.camera import Intrinsics
from isa.detection.stage_params import StageParams, core_params
from isa.exceptions import InvalidValueError

__all__ = ["VerifyParams", "Verification", "DepthEvidence", "verify_pose", "verify_shapes"]



# The fields are the core's section, one per parameter (stage_params.core_params).
@core_params("verify")
class VerifyParams(StageParams):
    """``tolerance`` ``(base, k)``: a cell agrees within ``max(base, k * z**2)`` metres (Kinect
    noise grows with z squared; as :class:`isa.detection.planes.PlaneParams`); ``violation_weight``
    what one seen-through cell costs against one agreeing; ``cell_spacing`` the grid cell side
    in units of the shape's point spacing (2 leaves no holes in the z-buffer); ``min_cell_px``
    the smallest cell in pixels; ``min_cells`` the visible cells below which a hypothesis scores
    0 (too little of it in the image to say); ``lateral`` (metres) how far sideways the observed
    surface may be from the shape's and still agree (instances of a category differ from its
    training shapes: a leg 3 cm off is still a leg), also the reach of a free-space violation:
    only a cell whose whole ``lateral`` neighbourhood is seen through is refuted;
    ``lateral_fraction``: the detector widens ``lateral`` to this fraction of the shape's
    diagonal (a bed's parts vary by more centimetres than a chair's); ``unexplained_weight`` what
    one cell of observed surface inside the shape's box but in front of its surface, or where it
    has none, costs (0: not counted). Defaults: the core's."""



@dataclass(frozen=True)
class Verification:
    """Counts of visible shape cells per outcome and the score (see the module docstring);
    ``unexplained`` observed cells (counted only with a positive ``unexplained_weight``, else 0;
    not part of :attr:`cells`)."""

    score: float
    agree: int
    violate: int
    occluded: int
    missing: int
    outside: int = 0
    unexplained: int = 0

    @property
    def cells(self) -> int:
        return self.agree + self.violate + self.occluded + self.missing + self.outside


class DepthEvidence:
    """A depth frame prepared for verification: the raw depth (H, W) float32 metres and, when
    known, ``planes`` (H, W) bool marking floor and wall pixels
    (:func:`isa.detection.planes.remove_planes`' ``removed``): no object stands behind a wall or
    under the floor, so a plane in front of a shape cell refutes it, and a shape surface lying on
    a plane is no evidence for the object."""

    def __init__(self, depth: np.ndarray, intrinsics: Intrinsics, planes: np.ndarray | None = None):
        self.depth = np.ascontiguousarray(depth, dtype=np.float32)
        self.intrinsics = intrinsics
        if planes is not None and np.shape(planes) != self.depth.shape:
            raise InvalidValueError(f"DepthEvidence: planes mask {np.shape(planes)} does not match the depth "
                             f"{self.depth.shape}")
        self.planes = None if planes is None else np.ascontiguousarray(planes, dtype=bool)


def verify_pose(evidence: DepthEvidence, R: np.ndarray, t: np.ndarray, points: np.ndarray,
                spacing: float, params: VerifyParams = VerifyParams(), n_points: int | None = None) -> Verification:
    """Verify one shape (object-frame ``points`` (N, 3), mean ``spacing``) at pose ``(R, t)``
    against a frame's :class:`DepthEvidence`. ``n_points``: use only the first that many points
    (the samples are random, so any prefix is an even subsample; the cells grow to match), for a
    quick first look."""
    v = _core.verify_pose(evidence.depth, evidence.intrinsics, np.asarray(R, dtype=float).reshape(3, 3),
                          np.asarray(t, dtype=float).reshape(3), np.ascontiguousarray(points, dtype=float).reshape(-1, 3),
                          float(spacing), evidence.planes, params.to_dict(), n_points)
    return Verification(**v)


def verify_shapes(evidence: DepthEvidence, R: np.ndarray, t: np.ndarray, library,
                  params: VerifyParams = VerifyParams()) -> list[Verification]:
    """:func:`verify_pose` of every shape of a :class:`ShapeLibrary` at one pose."""
    return [verify_pose(evidence, R, t, library.points[s], library.spacing[s], params)
            for s in range(len(library))]

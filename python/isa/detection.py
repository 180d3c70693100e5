"""3D object detection on real depth frames with category forests (paper Table 2, right).

A category model (an ISA forest trained on synthetic renders only) is run on a real frame
(:class:`isa.sunrgbd.SceneFrame`) in four steps:

1. **Planes** (optional, :func:`remove_planes`): the floor and large walls are found in the
   upright frame and their pixels set to missing depth. The forest was trained on isolated objects
   whose background is missing depth, so this makes a room look more like its training data, and
   the floor's height is kept for step 3. The floor is the dominant horizontal layer at the bottom
   of the cloud (gravity gives its normal, so one height is searched, no RANSAC); walls are
   vertical planes found by gravity-constrained RANSAC (two points fix a vertical plane) that are
   both tall and wide, so furniture faces are kept.
2. **Votes**: :func:`isa.pipeline.predict` on the whole (cleaned) depth image gives ranked 6D
   hypotheses ``(R, t)``; ``t`` is the object-frame origin (SSC or centre of mass,
   ``isa.categories.CENTRE``) in the camera frame.
3. **Gravity** (:func:`hypothesis_box`): hypotheses whose object z axis is more than
   ``max_tilt_deg`` from up are rejected (furniture stands upright); the rest are snapped to a yaw
   about gravity; each becomes a gravity-aligned :class:`isa.boxes3d.Box3D` of the category's box
   (:class:`CategoryBox`: size and SSC position learned from the training meshes, stored in the
   model's metadata). With a floor found, boxes whose bottom is more than ``floor_gap`` from it are
   rejected and the rest are set down on it (``rest_on_floor``): all four categories stand on the
   floor.
4. **NMS**: greedy 3D non-maximum suppression at IoU 0.25 per category (as Deep Sliding Shapes).

:func:`evaluate_real` runs every category model on every frame and scores the detections with
average precision at 3D IoU >= 0.25 (:mod:`isa.boxes3d`, the metric of Sliding Shapes);
:func:`real_section` adds the report's real-data section. Command line::

    python -m isa.detection --model chair=out/paper/models/chair.isa --data ../shared/data/sunrgbd --out out/real
    python -m isa.detection --train-procedural 6 --categories chair bed --data ../shared/data/sunrgbd --out out/real

All 3D quantities of boxes and planes are in the frame's upright frame (z up, camera at the
origin; see :mod:`isa.sunrgbd`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from isa.boxes3d import IOU_THRESHOLD, APResult, Box3D, box_from_pose, evaluate_detections, iou_3d, nms, rot_z  # noqa: E402
from isa.camera import Intrinsics  # noqa: E402
from isa.categories import CATEGORIES  # noqa: E402
from isa.exceptions import DataError  # noqa: E402

__all__ = [
    "CategoryBox",
    "category_box",
    "box_metadata",
    "model_box",
    "Plane",
    "PlaneParams",
    "PlaneRemoval",
    "find_planes",
    "remove_planes",
    "DetectionParams",
    "upright_rotation",
    "hypothesis_box",
    "Detections",
    "detect",
    "detect_frame",
    "RealResult",
    "evaluate_real",
    "load_real_frames",
    "real_section",
    "train_detector",
    "main",
]


# ----------------------------------------------------------------------------------------------
# The category's box: size and SSC position, learned from the training instances


@dataclass(frozen=True, eq=False)
class CategoryBox:
    """A category's 3D box in its object frame (metres, z up, front -y, origin at the SSC).

    ``size`` (3,): full extents along the object's x, y, z; ``ssc_offset`` (3,): the SSC's position
    relative to the box centre (so the box centre is at ``-ssc_offset`` in the object frame);
    ``n_instances``: how many training meshes it was learned from.
    """

    category: str
    size: np.ndarray
    ssc_offset: np.ndarray
    n_instances: int = 0

    def __post_init__(self) -> None:
        size = np.asarray(self.size, dtype=float).reshape(-1)
        off = np.asarray(self.ssc_offset, dtype=float).reshape(-1)
        if size.shape != (3,) or off.shape != (3,) or not (np.all(np.isfinite(size)) and np.all(np.isfinite(off))):
            raise ValueError(f"CategoryBox({self.category!r}): size and ssc_offset need 3 finite values, got {size}, {off}")
        if np.any(size <= 0):
            raise ValueError(f"CategoryBox({self.category!r}): sizes must be positive, got {size}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "ssc_offset", off)

    def to_dict(self) -> dict:
        return {"category": self.category, "size": self.size.tolist(), "ssc_offset": self.ssc_offset.tolist(),
                "n_instances": int(self.n_instances)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], category: str | None = None) -> "CategoryBox":
        try:
            return cls(d.get("category", category), d["size"], d["ssc_offset"], int(d.get("n_instances", 0)))
        except (KeyError, TypeError, AttributeError) as exc:
            raise DataError(f"category box: needs 'size' and 'ssc_offset', got {d!r} ({exc})") from None


def category_box(objects, category: str | None = None) -> CategoryBox:
    """The category's box from its training instances: the median over instances of each mesh's
    axis-aligned extents and of its SSC's position relative to the mesh's box centre.

    ``objects``: a :class:`isa.pipeline.PreparedCategory` (meshes already SSC-centred), or a
    sequence of :class:`isa.dataset.ObjectSpec` or ``trimesh.Trimesh`` in SSC-centred object
    frames. The median (not the mean) so one odd instance (a bunk bed) does not stretch the box.
    """
    if hasattr(objects, "objects") and hasattr(objects, "category"):
        category = category or objects.category
        objects = objects.objects
    meshes = [getattr(o, "mesh", o) for o in objects]
    if not meshes:
        raise DataError(f"category_box({category!r}): no training instances")
    if category is None:
        category = getattr(objects[0], "category", None)
    if category is None:
        raise ValueError("category_box: pass category= when giving bare meshes")
    bounds = np.array([np.asarray(m.bounds, dtype=float) for m in meshes])  # (n, 2, 3)
    size = np.median(bounds[:, 1] - bounds[:, 0], axis=0)
    offset = np.median(-(bounds[:, 0] + bounds[:, 1]) / 2, axis=0)  # SSC (origin) minus box centre
    return CategoryBox(category, size, offset, len(meshes))


def box_metadata(box: CategoryBox) -> dict:
    """``{"box": ...}`` to merge into a model's metadata (``train_forest(..., metadata=...)``)."""
    return {"box": box.to_dict()}


def model_box(forest_or_metadata, source: str = "model") -> CategoryBox:
    """The :class:`CategoryBox` stored in a model's metadata (``metadata["box"]``).

    Raises :class:`DataError` naming ``source`` when the model has none (models trained before the
    box was stored: pass the box explicitly, e.g. ``category_box(prepared)``).
    """
    meta = getattr(forest_or_metadata, "metadata", forest_or_metadata)
    if not isinstance(meta, Mapping) or "box" not in meta:
        raise DataError(f"{source}: the model's metadata has no 'box' (category size and SSC offset); "
                        "retrain with metadata=box_metadata(category_box(prepared)) or pass the box explicitly")
    return CategoryBox.from_dict(meta["box"], meta.get("category"))


# ----------------------------------------------------------------------------------------------
# Dominant planes


@dataclass(frozen=True)
class PlaneParams:
    """Plane finding. ``tolerance`` ``(base, k)``: a point is on a plane within
    ``max(base, k * depth**2)`` metres (Kinect noise grows with the square of the depth; k = 3
    sigma of Khoshelham & Elberink's 1.5e-3 z**2). The floor must hold ``min_floor_fraction`` of
    the points and lie at least ``min_floor_drop`` below the camera; a wall must hold
    ``min_wall_fraction``, and its points must span ``min_wall_height`` vertically and
    ``min_wall_width`` along it (so bed sides and cupboard fronts are kept); the best
    ``wall_candidates`` distinct hypotheses are checked in turn. ``samples`` points are used to
    score ``ransac_iterations`` wall hypotheses and ``check_samples`` to screen candidates before
    the test on every point; ``seed`` makes it reproducible."""

    tolerance: tuple[float, float] = (0.03, 0.0045)
    min_floor_fraction: float = 0.03
    min_floor_drop: float = 0.3
    floor_search: float = 0.3
    min_wall_fraction: float = 0.05
    min_wall_height: float = 1.0
    min_wall_width: float = 1.0
    max_walls: int = 3
    wall_candidates: int = 8
    ransac_iterations: int = 200
    samples: int = 5000
    check_samples: int = 40000
    seed: int = 0


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


def _tolerance(depth: np.ndarray, params: PlaneParams) -> np.ndarray:
    base, k = params.tolerance
    return np.maximum(base, k * np.asarray(depth, dtype=float) ** 2)


def _find_floor(z: np.ndarray, tol: np.ndarray, params: PlaneParams, rng: np.random.Generator) -> float | None:
    """Height of the dominant horizontal layer at the bottom of the cloud, or None."""
    n = len(z)
    if n == 0:
        return None
    idx = rng.choice(n, params.samples, replace=False) if n > params.samples else np.arange(n)
    zs, ts = z[idx], tol[idx]
    lo = float(np.percentile(zs, 0.5))
    hs = np.arange(lo - 0.05, lo + params.floor_search, 0.01)
    hs = hs[hs <= -params.min_floor_drop]
    if hs.size == 0:
        return None
    support = (np.abs(zs[None, :] - hs[:, None]) < ts[None, :]).sum(1)
    best = int(np.argmax(support))
    if support[best] < params.min_floor_fraction * len(zs):
        return None
    on = np.abs(z - hs[best]) < tol
    return float(np.median(z[on]))


def _find_wall(p: np.ndarray, tol: np.ndarray, params: PlaneParams, rng: np.random.Generator,
               n_total: int) -> tuple[np.ndarray, float, np.ndarray] | None:
    """One wall by gravity-constrained RANSAC: ``(normal (3,), offset, inlier mask (N,))`` or None."""
    n = len(p)
    if n < 3:
        return None
    idx = rng.choice(n, params.samples, replace=False) if n > params.samples else np.arange(n)
    ps, ts = p[idx], tol[idx]
    i = rng.integers(0, len(ps), params.ransac_iterations)
    j = rng.integers(0, len(ps), params.ransac_iterations)
    dxy = ps[j, :2] - ps[i, :2]
    length = np.hypot(dxy[:, 0], dxy[:, 1])
    ok = length > 0.2  # two close points fix a direction badly
    if not ok.any():
        return None
    # Vertical plane through both points: its normal is horizontal and across their separation.
    nrm = np.column_stack([-dxy[ok, 1], dxy[ok, 0]]) / length[ok, None]
    off = -(nrm * ps[i[ok], :2]).sum(1)
    # Written out, not a (k, 2) @ (2, N) matmul: BLAS threading makes that slow on a busy machine.
    d = np.abs(nrm[:, :1] * ps[None, :, 0] + nrm[:, 1:] * ps[None, :, 1] + off[:, None])
    score = (d < ts[None, :]).sum(1)
    # A mid-size subsample screens candidates before the (costly) test on every point.
    ic = np.sort(rng.choice(n, params.check_samples, replace=False)) if n > params.check_samples else np.arange(n)
    tried: list[tuple[np.ndarray, float]] = []
    # The best-supported plane may be a furniture face (rejected below); try the next distinct ones.
    for best in np.argsort(-score, kind="stable"):
        if len(tried) >= params.wall_candidates or score[best] < params.min_wall_fraction * len(ps) * n_total / n:
            break
        if any(abs(nrm[best] @ nn) > 0.995 and abs(off[best] - oo * np.sign(nrm[best] @ nn)) < 0.15 for nn, oo in tried):
            continue
        tried.append((nrm[best], off[best]))
        wall = _check_wall(p, tol, ps, ts, (p[ic], tol[ic]), nrm[best], off[best], params, n_total)
        if wall is not None:
            return wall
    return None


def _check_wall(p, tol, ps, ts, check, normal, offset, params: PlaneParams, n_total: int):
    """Refine a vertical plane hypothesis on the samples ``ps`` and accept it if it is a wall,
    first on the points ``check`` (points, tolerances), then on all of ``p``: ``(normal (3,), offset, inlier mask)`` or
    None."""
    for _ in range(2):  # least-squares refinement on the inliers (2D line fit, normal stays horizontal)
        on = np.abs(ps[:, 0] * normal[0] + ps[:, 1] * normal[1] + offset) < ts
        if on.sum() < 3:
            return None
        xy = ps[on, :2]
        c = xy.mean(0)
        _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
        normal = vt[1]
        offset = -float(c @ normal)
    if not _wall_extent(ps[on], normal, params):  # cheap rejection on the samples first
        return None
    # Sparser points need fewer per cell to mark a patch.
    for q, tq, min_points in ((*check, 1), (p, tol, 3)):
        on = np.abs(q[:, 0] * normal[0] + q[:, 1] * normal[1] + offset) < tq
        on = _largest_patch(q[on, 0] * -normal[1] + q[on, 1] * normal[0], q[on, 2], on, min_points=min_points)
        if on.sum() < params.min_wall_fraction * n_total * len(q) / len(p) or not _wall_extent(q[on], normal, params):
            return None
    return np.array([normal[0], normal[1], 0.0]), offset, on


def _wall_extent(q: np.ndarray, normal: np.ndarray, params: PlaneParams) -> bool:
    """Whether the points ``q`` (on a vertical plane with this normal) span a wall's height and width."""
    if len(q) < 3:
        return False
    along = q[:, 0] * -normal[1] + q[:, 1] * normal[0]
    return bool(np.ptp(np.percentile(q[:, 2], [2, 98])) >= params.min_wall_height
                and np.ptp(np.percentile(along, [2, 98])) >= params.min_wall_width)


def _largest_patch(along: np.ndarray, z: np.ndarray, on: np.ndarray, cell: float = 0.1, min_points: int = 3) -> np.ndarray:
    """Keep only the inliers of the largest connected patch of the plane (``cell`` m grid in the
    plane's own coordinates): an infinite plane also grazes unrelated objects elsewhere, whose
    points would otherwise be removed and would make a low face look like a tall wall."""
    from scipy import ndimage

    if len(along) == 0:
        return on
    a = np.floor((along - along.min()) / cell).astype(np.int64)
    b = np.floor((z - z.min()) / cell).astype(np.int64)
    shape = (int(a.max()) + 1, int(b.max()) + 1)
    counts = np.bincount(a * shape[1] + b, minlength=shape[0] * shape[1]).reshape(shape)
    occupied = ndimage.binary_closing(counts >= min_points, iterations=1) | (counts >= min_points)
    lab, n = ndimage.label(occupied, structure=np.ones((3, 3)))
    if n == 0:
        out = on.copy()
        out[:] = False
        return out
    weight = ndimage.sum(counts, lab, index=np.arange(1, n + 1))
    keep = lab[a, b] == 1 + int(np.argmax(weight))
    out = np.zeros_like(on)
    out[np.flatnonzero(on)[keep]] = True
    return out


def find_planes(points: np.ndarray, depth: np.ndarray, params: PlaneParams = PlaneParams(),
                floor: bool = True, walls: bool = True) -> tuple[list[Plane], np.ndarray]:
    """The floor and walls of a cloud: ``points`` (N, 3) upright frame, ``depth`` (N,) each
    point's camera depth (for the tolerance). Returns the planes (floor first) and a label (N,)
    int per point: the index of the plane it lies on, -2 below the floor, -1 none."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    depth = np.asarray(depth, dtype=float).reshape(-1)
    if len(points) != len(depth):
        raise ValueError(f"find_planes: {len(points)} points but {len(depth)} depths")
    rng = np.random.default_rng(params.seed)
    tol = _tolerance(depth, params)
    labels = np.full(len(points), -1, dtype=np.int64)
    planes: list[Plane] = []
    if floor:
        h = _find_floor(points[:, 2], tol, params, rng)
        if h is not None:
            dz = points[:, 2] - h
            on = np.abs(dz) < tol
            labels[on] = 0
            labels[dz <= -tol] = -2  # nothing real is under the floor: noise and reflections
            planes.append(Plane("floor", np.array([0.0, 0.0, 1.0]), -h, int(on.sum())))
    if walls:
        for _ in range(params.max_walls):
            free = np.flatnonzero(labels == -1)
            found = _find_wall(points[free], tol[free], params, rng, len(points))
            if found is None:
                break
            normal, offset, inliers = found
            on = free[inliers]
            labels[on] = len(planes)
            planes.append(Plane("wall", normal, offset, len(on)))
    return planes, labels


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


def remove_planes(depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray, params: PlaneParams = PlaneParams(),
                  floor: bool = True, walls: bool = True) -> PlaneRemoval:
    """Set the pixels of the floor (and everything under it) and of walls to 0 (missing).

    ``depth`` (H, W) float metres, 0 = missing; ``R_gravity`` camera to upright (``X_up = R_gravity
    @ X_cam``). See :class:`PlaneParams` for what counts as a floor or a wall.
    """
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"remove_planes: depth must be (H, W), got {depth.shape}")
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f"remove_planes: depth is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                         f"{intrinsics.width}x{intrinsics.height}")
    Rg = np.asarray(R_gravity, dtype=float).reshape(3, 3)
    valid = depth > 0
    cam = intrinsics.backproject(depth)[valid]
    up = np.einsum("ij,nj->ni", Rg, cam)
    planes, labels = find_planes(up, cam[:, 2], params, floor, walls)
    removed = np.zeros(depth.shape, dtype=bool)
    removed[valid] = labels != -1
    out = depth.copy()
    out[removed] = 0.0
    return PlaneRemoval(out, planes, removed)


# ----------------------------------------------------------------------------------------------
# Hypotheses to boxes


@dataclass(frozen=True)
class DetectionParams:
    """Detection settings (see the module docstring for the steps).

    ``stride``, ``max_hypotheses`` and ``predict`` (any other keyword of ``isa._core.predict``)
    go to the voting; ``max_tilt_deg`` (None: off) rejects hypotheses whose object z axis is
    further from gravity-up; ``remove_floor`` / ``remove_walls`` / ``planes`` the plane step;
    ``rest_on_floor`` sets boxes down on a found floor after rejecting those whose bottom is more
    than ``floor_gap`` (None: no rejection) from it; ``nms_iou`` the NMS threshold;
    ``max_detections`` per category and frame; ``min_score`` drops weaker hypotheses.
    """

    stride: int = 4
    max_hypotheses: int = 20
    max_tilt_deg: float | None = 30.0
    remove_floor: bool = True
    remove_walls: bool = True
    planes: PlaneParams = field(default_factory=PlaneParams)
    rest_on_floor: bool = True
    floor_gap: float | None = 0.3
    nms_iou: float = IOU_THRESHOLD
    max_detections: int = 10
    min_score: float = 0.0
    predict: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return json.loads(json.dumps(asdict(self)))


def upright_rotation(R: np.ndarray, R_gravity: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Snap an object rotation (object to camera) to the nearest yaw about gravity.

    Returns ``(R_snapped, yaw, tilt_deg)``: ``R_gravity @ R_snapped`` is the rotation by ``yaw``
    about the upright z axis (closest in Frobenius norm to ``R_gravity @ R``), and ``tilt_deg`` the
    angle between the object's z axis and up before snapping.
    """
    from isa.boxes3d import yaw_from_rotation

    Rg = np.asarray(R_gravity, dtype=float).reshape(3, 3)
    M = Rg @ np.asarray(R, dtype=float).reshape(3, 3)
    yaw = yaw_from_rotation(M)
    tilt = math.degrees(math.acos(float(np.clip(M[2, 2] / max(np.linalg.norm(M[:, 2]), 1e-12), -1.0, 1.0))))
    # solve, not transpose: R_gravity from rounded calibration files is not exactly orthogonal.
    return np.linalg.solve(Rg, rot_z(yaw)), yaw, tilt


def hypothesis_box(hypothesis: Mapping[str, Any], box: CategoryBox, R_gravity: np.ndarray,
                   max_tilt_deg: float | None = None, category: str | None = None) -> Box3D | None:
    """A 6D hypothesis (``R``, ``t`` = object origin in the camera frame, ``score``) as a gravity-aligned
    box in the upright frame, or None when its tilt exceeds ``max_tilt_deg``.

    The rotation is snapped to its yaw about gravity first (:func:`upright_rotation`), so the box
    centre is where an upright object with that SSC would have it. ``meta`` keeps the tilt and the
    hypothesis' support.
    """
    R_up, _, tilt = upright_rotation(hypothesis["R"], R_gravity)
    if max_tilt_deg is not None and tilt > max_tilt_deg:
        return None
    b = box_from_pose(R_up, hypothesis["t"], box.size, box.ssc_offset, R_gravity, category or box.category,
                      float(hypothesis.get("score", 1.0)))
    return b.replace(meta={"tilt_deg": tilt, "support": int(hypothesis.get("support", 0))})


@dataclass(eq=False)
class Detections:
    """One category model on one frame: ``boxes`` after NMS, best first; ``hypotheses`` the votes'
    raw count; ``rejected`` counts per reason (tilt, floor, score); ``planes`` the plane step's
    result (None when skipped); ``seconds`` per step."""

    category: str
    boxes: list[Box3D]
    hypotheses: int
    rejected: dict[str, int]
    planes: PlaneRemoval | None
    seconds: dict[str, float]


def _forest(model, source: str | None = None):
    from isa.forest import Forest

    if isinstance(model, (str, os.PathLike)):
        path = Path(model)
        if not path.is_file():
            raise DataError(f"{path}: model file not found")
        return Forest.load(path), str(path)
    return model, source or "model"


def detect(forest, depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray, box: CategoryBox | None = None,
           params: DetectionParams = DetectionParams(), planes: PlaneRemoval | None = None,
           category: str | None = None) -> Detections:
    """Detect one category in one depth frame (steps in the module docstring).

    ``forest``: :class:`isa.forest.Forest` or a model path; ``depth`` (H, W) float metres; ``box``:
    the category box (default: the model's metadata, :func:`model_box`); ``planes``: a precomputed
    :func:`remove_planes` result to share between categories (default: computed here when
    ``params`` asks for it); ``category``: the detections' class name (default: the box's).
    """
    forest, source = _forest(forest)
    box = box if box is not None else model_box(forest, source)
    category = category or box.category
    if not category:
        raise DataError(f"{source}: no category (neither in the box nor passed)")
    from isa.pipeline import predict

    secs: dict[str, float] = {}
    depth = np.asarray(depth, dtype=np.float32)
    if planes is None and (params.remove_floor or params.remove_walls):
        t0 = time.perf_counter()
        planes = remove_planes(depth, intrinsics, R_gravity, params.planes, params.remove_floor, params.remove_walls)
        secs["planes"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    kw = {"stride": params.stride, "max_hypotheses": params.max_hypotheses, **params.predict}
    hyps = predict(forest, planes.depth if planes is not None else depth, intrinsics, **kw)
    secs["vote"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    floor = planes.floor if planes is not None else None
    rejected = {"score": 0, "tilt": 0, "floor": 0}
    boxes = []
    for rank, h in enumerate(hyps):
        if float(h["score"]) < params.min_score:
            rejected["score"] += 1
            continue
        b = hypothesis_box(h, box, R_gravity, params.max_tilt_deg, category)
        if b is None:
            rejected["tilt"] += 1
            continue
        if floor is not None:
            gap = b.z_range[0] - floor.height
            if params.floor_gap is not None and abs(gap) > params.floor_gap:
                rejected["floor"] += 1
                continue
            if params.rest_on_floor:
                b = b.replace(centre=b.centre - np.array([0.0, 0.0, gap]))
        boxes.append(b.replace(meta={**b.meta, "rank": rank}))
    keep = nms(boxes, params.nms_iou)[: params.max_detections]
    secs["boxes"] = time.perf_counter() - t0
    return Detections(category, [boxes[i] for i in keep], len(hyps), rejected, planes, secs)


def detect_frame(models: Mapping[str, Any], frame, params: DetectionParams = DetectionParams(),
                 boxes: Mapping[str, CategoryBox] | None = None) -> dict[str, Detections]:
    """Every category model on one :class:`isa.sunrgbd.SceneFrame` (the planes are found once).

    ``models``: category -> :class:`isa.forest.Forest` or model path; ``boxes``: category ->
    :class:`CategoryBox` for models without one in their metadata.
    """
    planes = None
    t_planes = 0.0
    if params.remove_floor or params.remove_walls:
        t0 = time.perf_counter()
        planes = remove_planes(frame.depth, frame.intrinsics, frame.R_gravity, params.planes,
                               params.remove_floor, params.remove_walls)
        t_planes = time.perf_counter() - t0
    out = {}
    for cat, model in models.items():
        box = (boxes or {}).get(cat)
        det = detect(model, frame.depth, frame.intrinsics, frame.R_gravity, box, params, planes, category=cat)
        det.seconds["planes"] = t_planes
        out[cat] = det
    return out


# ----------------------------------------------------------------------------------------------
# Real-data evaluation


@dataclass(eq=False)
class RealResult:
    """:func:`evaluate_real`'s answer: per category the :class:`APResult` (AP in [0, 1], ``nan``
    without ground truth), per frame the detections of all categories (``detections[f]``), the
    planes found and the seconds per step."""

    categories: list[str]
    frames: list[str]
    ap: dict[str, APResult]
    detections: list[list[Box3D]]
    planes: list[list[Plane]]
    seconds: list[dict[str, float]]
    params: DetectionParams
    models: dict[str, str]

    def ap_percent(self) -> dict[str, float | None]:
        """AP in percent per category, None where the frames hold no ground truth of it."""
        return {c: (None if math.isnan(r.ap) else 100.0 * r.ap) for c, r in self.ap.items()}

    def to_dict(self, ground_truth: Sequence[Sequence[Box3D]] | None = None) -> dict:
        """JSON-ready summary (AP in percent); with ``ground_truth`` each detection gets its best
        IoU with a ground-truth box of its category."""
        frames = []
        for f, dets in enumerate(self.detections):
            rows = []
            for b in dets:
                row = {"category": b.category, "score": b.score, "centre": b.centre.tolist(), "size": b.size.tolist(),
                       "yaw": b.yaw, "tilt_deg": b.meta.get("tilt_deg")}
                if ground_truth is not None:
                    gts = [g for g in ground_truth[f] if g.category == b.category]
                    row["best_iou"] = max((iou_3d(b, g) for g in gts), default=0.0)
                rows.append(row)
            frames.append({"name": self.frames[f], "detections": rows, "planes": [p.to_dict() for p in self.planes[f]],
                           "seconds": self.seconds[f]})
        return {"iou_threshold": IOU_THRESHOLD, "categories": self.categories, "models": self.models,
                "ap_percent": self.ap_percent(), "n_ground_truth": {c: r.n_ground_truth for c, r in self.ap.items()},
                "frames": frames, "params": self.params.to_dict()}


def evaluate_real(models: Mapping[str, Any], frames: Sequence, params: DetectionParams = DetectionParams(),
                  boxes: Mapping[str, CategoryBox] | None = None, progress: bool = False) -> RealResult:
    """Detect every category of ``models`` (category -> model path or Forest) in every frame
    (:class:`isa.sunrgbd.SceneFrame`) and score AP at 3D IoU >= 0.25 per category (over all frames,
    as Sliding Shapes). ``boxes`` overrides / supplies the models' category boxes."""
    if not models:
        raise ValueError("evaluate_real: no models")
    if not frames:
        raise ValueError("evaluate_real: no frames")
    loaded, sources = {}, {}
    for cat, m in models.items():
        loaded[cat], sources[cat] = _forest(m, f"{cat} model")
        if boxes is None or cat not in boxes:
            model_box(loaded[cat], sources[cat])  # fail early, naming the file
    dets, planes, secs = [], [], []
    for frame in frames:
        t0 = time.perf_counter()
        per_cat = detect_frame(loaded, frame, params, boxes)
        total = time.perf_counter() - t0
        first = next(iter(per_cat.values()))
        s = {"planes": first.seconds.get("planes", 0.0), "total": total}
        for cat, d in per_cat.items():
            s[f"vote_{cat}"] = d.seconds["vote"]
        dets.append([b for d in per_cat.values() for b in d.boxes])
        planes.append(first.planes.planes if first.planes is not None else [])
        secs.append(s)
        if progress:
            print(f"[real] {frame.name}: {len(dets[-1])} detections in {1000 * total:.0f} ms", flush=True)
    cats = list(loaded)
    ap = evaluate_detections(dets, [f.boxes for f in frames], cats)
    return RealResult(cats, [f.name for f in frames], ap, dets, planes, secs, params, sources)


def load_real_frames(root: str | Path, filled: bool = False) -> list:
    """Every SUN RGB-D frame under ``root``: native frame folders (any depth below ``root``) and,
    if ``root`` is or holds a processed ``sunrgbd_trainval`` folder, its frames."""
    from isa import sunrgbd

    root = Path(root)
    if not root.is_dir():
        raise DataError(f"{root}: SUN RGB-D folder not found")
    frames = [sunrgbd.read_native(p, filled=filled) for p in sunrgbd.list_native(root)]
    for proc in (root, root / "sunrgbd_trainval"):
        if (proc / "calib").is_dir():
            frames += list(sunrgbd.iter_processed(proc))
    if not frames:
        raise DataError(f"{root}: no SUN RGB-D frames (native folders with intrinsics.txt or a processed calib/ folder)")
    return frames


def _fmt_ap(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.1f}"


def real_section(report, result: RealResult, frames: Sequence, label: str = "ISA (ours)", heading_level: int = 2) -> dict:
    """Add the real-data section to an :class:`isa.report.Report`: the AP table in the layout of
    the paper's Table 2 (right) with the published numbers, per-frame figures (predicted boxes
    green, ground truth red, over the depth image and in a top view), a per-detection table, and
    the numbers in ``report.results["real"]`` (also returned)."""
    from isa.figures.scenes import scene_figure
    from isa.published import DETECTION_AP, PRINTED_MEANS

    gt = [f.boxes for f in frames]
    data = result.to_dict(gt)
    data["published"] = DETECTION_AP
    n_gt = data["n_ground_truth"]
    report.heading("Real data: 3D detection (Table 2, right)", heading_level)
    report.text(
        f"Category forests trained on synthetic renders only, run on {len(frames)} real Kinect depth frame(s) "
        f"of SUN RGB-D ({', '.join(result.frames)}), which holds the NYU Depth v2 / RMRC frames of the paper. "
        f"Detections are gravity-aligned 3D boxes scored with the Sliding Shapes metric: average precision (%) "
        f"at 3D IoU >= {IOU_THRESHOLD} over all frames. Ground-truth boxes of the evaluated categories: "
        + ", ".join(f"{c} {n_gt[c]}" for c in result.categories) + ".")
    report.text(
        f"**This is not a benchmark.** With {len(frames)} frame(s) and {sum(n_gt.values())} ground-truth box(es) "
        "each AP is computed from one or two objects, so it can only be 0, 100 or a few values between; it shows "
        "that the pipeline runs end to end on real depth, not how well it detects. The paper's numbers are over the "
        "RMRC 2014 test set (hundreds of frames); 'n/a' marks categories without a model or without ground truth "
        "in these frames.")
    header = ["method", "input channel", *CATEGORIES, "mean"]
    rows = []
    for name, row in DETECTION_AP.items():
        rows.append([name + (" (paper)" if name.startswith("ISA") else ""), "depth", *(f"{row[c]:g}" for c in CATEGORIES),
                     f"{PRINTED_MEANS[('right', name)]:g}"])
    ours = result.ap_percent()
    have = [ours[c] for c in CATEGORIES if ours.get(c) is not None]
    mean = f"{np.mean(have):.1f} (over {len(have)})" if have and len(have) < len(CATEGORIES) else (
        f"{np.mean(have):.1f}" if have else "n/a")
    rows.append([f"{label}, {len(frames)} frame(s)", "depth", *(_fmt_ap(ours.get(c)) for c in CATEGORIES), mean])
    report.table(header, rows)
    p = result.params
    report.text(
        f"Settings: stride {p.stride}, up to {p.max_hypotheses} hypotheses per model, tilt limit "
        f"{p.max_tilt_deg} deg, floor removal {'on' if p.remove_floor else 'off'}, wall removal "
        f"{'on' if p.remove_walls else 'off'}, boxes set on the floor {'on' if p.rest_on_floor else 'off'} "
        f"(gap limit {p.floor_gap} m), NMS at IoU {p.nms_iou}. Models: "
        + ", ".join(f"{c} `{s}`" for c, s in result.models.items()) + ".")
    shown = sorted(set(result.categories) | set(CATEGORIES))
    det_rows = []
    for f, frame in enumerate(frames):
        fr = data["frames"][f]
        path = scene_figure(frame, result.detections[f], report.figure_path(f"real-{frame.name}.png"),
                            title=f"{frame.name}: ground truth (red), ISA detections (green)", categories=shown)
        planes = ", ".join(f"{q['kind']}" + (f" at z = {-q['offset']:.2f} m" if q["kind"] == "floor" else "")
                           for q in fr["planes"]) or "none"
        report.image(path, f"{frame.name}: detections (green, with scores) and ground truth (red) over the real depth "
                           f"(left) and from above (right); planes removed: {planes}; "
                           f"{1000 * fr['seconds']['total']:.0f} ms")
        for d in fr["detections"]:
            det_rows.append([frame.name, d["category"], f"{d['score']:.2f}", f"{d['best_iou']:.2f}",
                             "yes" if d["best_iou"] >= IOU_THRESHOLD else "no"])
    if det_rows:
        report.table(["frame", "category", "score", "best IoU with GT", f"IoU >= {IOU_THRESHOLD}"], det_rows)
    report.results["real"] = data
    return data


# ----------------------------------------------------------------------------------------------
# Training a category detector (small, in memory)


def train_detector(category: str, objects: Sequence, views: int = 30, stride: int = 6, forest_params=None,
                   use_ground_truth: bool = False, seed: int = 0, progress: bool = False, intrinsics=None,
                   prepared=None):
    """Train a category forest on renders of ``objects`` (:class:`isa.dataset.ObjectSpec`) and
    store the category box in its metadata; returns ``(forest, prepared)``.

    Everything is kept in memory (no BOP folder), which suits the small sets of the tests, the
    demo and ``--train-procedural``; :mod:`isa.experiment` is the large-scale path. ``prepared``
    skips the skeleton / SSC step when already done (:func:`isa.pipeline.prepare_category`).
    """
    from isa import __version__, pipeline
    from isa.annotate import Frame, build_training_set
    from isa.camera import KINECT_V1
    from isa.dataset import default_views
    from isa.forest import ForestParams
    from isa.render import DepthRenderer

    intrinsics = intrinsics or KINECT_V1
    if prepared is None:
        prepared = pipeline.prepare_category(category, objects, use_ground_truth=use_ground_truth, progress=progress)
    frames = []
    with DepthRenderer(intrinsics) as r:
        for o in prepared.objects:
            v = default_views(o, views, seed, intrinsics)
            for i in range(len(v)):
                R, t = v[i]
                depth, mask = r.render(o.mesh, R, t)
                if mask.any():
                    frames.append(Frame(depth, mask, R, t, intrinsics, prepared.skeletons[o.obj_id]))
    ts = build_training_set(frames, stride=stride)
    params = forest_params or ForestParams(n_trees=4, max_depth=14, n_candidates=40, seed=seed)
    meta = {"category": category, "ssc": prepared.ssc.ssc.to_dict(), "template": prepared.ssc.template.to_dict(),
            "isa_version": __version__, "quality": params.quality, **box_metadata(category_box(prepared))}
    return pipeline.train_forest(ts, params, metadata=meta), prepared


# ----------------------------------------------------------------------------------------------
# Command line


def _parse_models(items: Sequence[str]) -> dict[str, str]:
    out = {}
    for it in items:
        cat, sep, path = it.partition("=")
        if not sep or not cat or not path:
            raise SystemExit(f"--model: expected CATEGORY=PATH, got {it!r}")
        out[cat] = path
    return out


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m isa.detection", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="SUN RGB-D folder (native frame folders and/or sunrgbd_trainval)")
    p.add_argument("--out", required=True, help="output folder (report.md, results.json, figures/, models/)")
    p.add_argument("--model", action="append", default=[], metavar="CATEGORY=PATH",
                   help="a trained category model (its metadata must hold the category box); repeatable")
    p.add_argument("--train-procedural", type=int, metavar="N",
                   help="train a small forest per --categories on N procedural instances first")
    p.add_argument("--categories", nargs="+", default=["bed", "chair"], choices=CATEGORIES,
                   help="categories for --train-procedural (default: those in the shared frames)")
    p.add_argument("--views", type=int, default=30, help="training views per instance for --train-procedural")
    p.add_argument("--trees", type=int, default=4, help="trees for --train-procedural")
    p.add_argument("--quality", default="Q1+Q2+Q3", help="criterion for --train-procedural")
    p.add_argument("--ground-truth-skeletons", action="store_true",
                   help="--train-procedural: use the procedural skeletons instead of extraction (faster)")
    p.add_argument("--stride", type=int, default=DetectionParams.stride, help="voting stride in pixels")
    p.add_argument("--hypotheses", type=int, default=DetectionParams.max_hypotheses)
    p.add_argument("--max-tilt", type=float, default=DetectionParams.max_tilt_deg)
    p.add_argument("--no-planes", action="store_true", help="vote on the raw depth (no floor / wall removal)")
    p.add_argument("--no-floor-rest", action="store_true", help="do not set boxes down on the floor")
    p.add_argument("--seed", type=int, default=0)
    return p


def main(argv: list[str] | None = None) -> None:
    from isa.dataset import procedural_objects
    from isa.forest import ForestParams
    from isa.report import Report

    a = parser().parse_args(argv)
    out = Path(a.out)
    models: dict[str, Any] = _parse_models(a.model)
    if a.train_procedural:
        (out / "models").mkdir(parents=True, exist_ok=True)
        for cat in a.categories:
            t0 = time.perf_counter()
            objs = procedural_objects(cat, a.train_procedural, seed=a.seed * 1000 + 1)
            forest, _ = train_detector(cat, objs, views=a.views, seed=a.seed, progress=True,
                                       use_ground_truth=a.ground_truth_skeletons,
                                       forest_params=ForestParams(n_trees=a.trees, max_depth=14, n_candidates=40,
                                                                  quality=a.quality, seed=a.seed))
            path = out / "models" / f"{cat}.isa"
            forest.save(path)
            models[cat] = str(path)
            print(f"[train] {cat}: {a.train_procedural} procedural instances x {a.views} views, "
                  f"{time.perf_counter() - t0:.0f} s -> {path}", flush=True)
    if not models:
        raise SystemExit("give --model CATEGORY=PATH (repeatable) or --train-procedural N")
    frames = load_real_frames(a.data)
    params = DetectionParams(stride=a.stride, max_hypotheses=a.hypotheses, max_tilt_deg=a.max_tilt,
                             remove_floor=not a.no_planes, remove_walls=not a.no_planes,
                             rest_on_floor=not a.no_floor_rest)
    result = evaluate_real(models, frames, params, progress=True)
    report = Report(out, "ISA on real depth frames: 3D detection")
    real_section(report, result, frames)
    path = report.write()
    print("AP (%): " + ", ".join(f"{c} {_fmt_ap(v)}" for c, v in result.ap_percent().items()))
    print(f"report: {path}")


if __name__ == "__main__":
    main()

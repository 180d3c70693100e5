"""Hypotheses to gravity-aligned boxes and the detector: votes of a category forest on a whole
frame -> upright boxes of the category's size -> NMS."""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from isa.camera import Intrinsics
from isa.detection.category_boxes import CategoryBox, model_box
from isa.detection.planes import PlaneParams, PlaneRemoval, remove_planes
from isa.evaluation.boxes3d import IOU_THRESHOLD, Box3D, box_from_pose, nms, rot_z
from isa.exceptions import DataError, DataNotFoundError

__all__ = ["DetectionParams", "upright_rotation", "hypothesis_box", "Detections", "detect_category", "detect_frame"]


@dataclass(frozen=True)
class DetectionParams:
    """Detection settings (the steps: :mod:`isa.detection`).

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
    from isa.evaluation.boxes3d import yaw_from_rotation

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
    from isa.forest.model import Forest

    if isinstance(model, (str, os.PathLike)):
        path = Path(model)
        if not path.is_file():
            raise DataNotFoundError(f"{path}: model file not found")
        return Forest.load(path), str(path)
    return model, source or "model"


def detect_category(forest, depth: np.ndarray, intrinsics: Intrinsics, R_gravity: np.ndarray,
                    box: CategoryBox | None = None,
                    params: DetectionParams = DetectionParams(), planes: PlaneRemoval | None = None,
                    category: str | None = None) -> Detections:
    """Detect one category in one depth frame (steps: :mod:`isa.detection`).

    ``forest``: :class:`isa.forest.model.Forest` or a model path; ``depth`` (H, W) float metres; ``box``:
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
    """Every category model on one :class:`isa.data.sunrgbd.SceneFrame` (the planes are found once).

    ``models``: category -> :class:`isa.forest.model.Forest` or model path; ``boxes``: category ->
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
        det = detect_category(model, frame.depth, frame.intrinsics, frame.R_gravity, box, params, planes, category=cat)
        det.seconds["planes"] = t_planes
        out[cat] = det
    return out


# ----------------------------------------------------------------------------------------------
# Real-data evaluation

"""Every category in one pass: ``detect(depth, intrinsics, models, gravity=None)``.

1. **Gravity**: given, else the floor's normal, else the votes' tilt (:mod:`isa.detection.gravity`).
2. **Planes**: floor and walls set to missing depth for the voting (the forests were trained on
   isolated objects), found once for all categories (:func:`isa.detection.planes.remove_planes`).
3. **Votes**: each category forest on the cleaned depth gives ranked 6D hypotheses; each is
   snapped upright (tilt limit), rejected when its bottom is far from the floor, set on it.
4. **Verification** (:mod:`isa.detection.verify`) on the *raw* depth against each of the category's
   training shapes; the best shape gives the score (comparable across categories and frames)
   and the size.
5. **Refinement** (:mod:`isa.detection.refine`) of the best hypotheses: upright ICP with the best shape,
   then verified again; kept when the score does not drop.
6. **NMS across categories**: one ranked list; a box overlapping a better one (3D IoU over
   ``nms_iou``, or a smaller box with over ``nms_overlap`` of its volume inside the better one)
   is dropped, whatever its category, since a place holds one object.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from detect_reference.refine import RefineParams, refine_pose, upright_points
from detect_reference.verify import DepthEvidence, VerifyParams, verify_pose
from isa.camera import Intrinsics
from isa.detection.gravity import GravityEstimate, estimate_gravity
from isa.detection.shapes import ShapeLibrary
from isa.evaluation.boxes3d import Box3D, box_from_pose, footprint_intersection_area, iou_3d, rot_z
from isa.exceptions import DataError, InvalidValueError

__all__ = ["CategoryModel", "load_model", "DetectParams", "SceneDetection", "DetectResult", "detect",
           "nms_across", "write_bop_csv"]


@dataclass(frozen=True, eq=False)
class CategoryModel:
    """A category's forest, its box (size and origin offset, :class:`isa.detection.CategoryBox`),
    its shape library (None: no verification, the forest's score and box are used) and its leaf
    foreground probabilities (:mod:`isa.detection.background`; None: every vote counts fully)."""

    category: str
    forest: Any
    box: Any
    shapes: ShapeLibrary | None = None
    foreground: Any = None


def load_model(path: str | Path, shapes: str | Path | ShapeLibrary | None = None,
               category: str | None = None, foreground: str | Path | None = None) -> CategoryModel:
    """A :class:`CategoryModel` from a model file; ``shapes`` a library or its ``.npz`` (default:
    ``<model>.shapes.npz`` beside the model when it exists); ``foreground`` likewise
    (``<model>.foreground.npz``)."""
    from isa.detection.background import LeafForeground
    from isa.detection.category_boxes import model_box
    from isa.forest.model import Forest

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: model file not found")
    forest = Forest.load(path)
    box = model_box(forest, str(path))
    if shapes is None and path.with_suffix(".shapes.npz").is_file():
        shapes = path.with_suffix(".shapes.npz")
    if shapes is not None and not isinstance(shapes, ShapeLibrary):
        shapes = ShapeLibrary.load(shapes)
    if foreground is None and path.with_suffix(".foreground.npz").is_file():
        foreground = path.with_suffix(".foreground.npz")
    if foreground is not None and not isinstance(foreground, LeafForeground):
        foreground = LeafForeground.load(foreground)
    return CategoryModel(category or box.category or forest.metadata.get("category"), forest, box, shapes, foreground)


@dataclass(frozen=True)
class DetectParams:
    """``stride``, ``max_hypotheses`` go to each forest's voting; ``max_tilt_deg`` rejects
    hypotheses tilted further from up; ``floor_gap`` rejects those whose bottom is further from
    the found floor (and the rest are set on it); ``verify`` / ``refine`` None switch the steps
    off; ``size_top`` hypotheses per category get their size fitted (per-axis scale of their
    ``size_shapes`` best shapes, factors ``size_steps``; 0: training sizes only); the shapes are
    screened and sized on their first ``quick_points`` samples (None: all), the final score uses all;
    ``forest_weight`` adds that times the log of the forest's score to a verified score;
    ``refine_top`` hypotheses per category are refined; ``turns`` > 1 also verifies each
    hypothesis turned by multiples of 360 / ``turns`` degrees about gravity (the forest's front and
    back are the easiest to confuse) and keeps the best; ``nms_iou`` / ``nms_overlap`` the
    cross-category suppression; ``max_detections`` per frame; ``min_score`` drops weaker ones."""

    stride: int = 4
    max_hypotheses: int = 20
    max_tilt_deg: float | None = 30.0
    remove_planes: bool = True
    floor_gap: float | None = 0.3
    verify: VerifyParams | None = field(default_factory=VerifyParams)
    refine: RefineParams | None = field(default_factory=RefineParams)
    refine_top: int = 5
    turns: int = 1
    size_top: int = 8
    size_shapes: int = 3
    size_steps: tuple[float, ...] = (0.85, 1.15)
    quick_points: int | None = 1000
    forest_weight: float = 0.05
    nms_iou: float = 0.25
    nms_overlap: float = 0.6
    max_detections: int = 20
    min_score: float = -math.inf
    predict: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class SceneDetection:
    """One detected object: ``category``; pose ``R`` (3, 3), ``t`` (3,) metres (object to camera,
    ``t`` the category's origin); ``size`` (3,) its extents along its own x, y, z; ``box_centre``
    (3,) that box's centre in the object frame; ``score`` (verification score when shapes are
    given, else the forest's); ``support`` the votes behind it; ``meta`` (forest score, shape,
    refinement)."""

    category: str
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    box_centre: np.ndarray
    score: float
    support: int
    meta: dict = field(default_factory=dict)

    def box(self, R_gravity: np.ndarray) -> Box3D:
        """The gravity-aligned box in the upright frame."""
        return box_from_pose(self.R, self.t, self.size, -self.box_centre, R_gravity, self.category, self.score)

    def to_dict(self) -> dict:
        return {"category": self.category, "R": np.asarray(self.R).tolist(), "t": np.asarray(self.t).tolist(),
                "size": np.asarray(self.size).tolist(), "box_centre": np.asarray(self.box_centre).tolist(),
                "score": float(self.score), "support": int(self.support),
                "meta": {k: v for k, v in self.meta.items() if isinstance(v, (int, float, str, bool, type(None)))}}


@dataclass(eq=False)
class DetectResult:
    """``detections`` best first; ``gravity`` the rotation used and its source; ``seconds`` per step."""

    detections: list[SceneDetection]
    gravity: GravityEstimate
    floor_height: float | None
    seconds: dict[str, float]


def _overlap(a: Box3D, b: Box3D) -> tuple[float, float]:
    """3D IoU of two boxes and their intersection over ``a``'s volume."""
    za0, za1 = a.z_range
    zb0, zb1 = b.z_range
    dz = min(za1, zb1) - max(za0, zb0)
    if dz <= 0:
        return 0.0, 0.0
    inter = footprint_intersection_area(a, b) * dz
    if inter <= 0:
        return 0.0, 0.0
    return iou_3d(a, b), inter / a.volume


def nms_across(boxes: Sequence[Box3D], iou: float = 0.25, overlap: float = 0.6) -> list[int]:
    """Greedy NMS over boxes of any category, best score first: a box is dropped when its IoU
    with a kept one exceeds ``iou``, or when it is the smaller and more than ``overlap`` of its
    volume lies inside a kept one (a toilet box inside a chair's: part of the same object). A
    larger box is not dropped for a smaller one inside it (a false chair on a bed must not remove
    the bed). Returns the kept indices, best first."""
    order = sorted(range(len(boxes)), key=lambda i: -boxes[i].score)
    kept: list[int] = []
    for i in order:
        ok = True
        for k in kept:
            o_iou, inside = _overlap(boxes[i], boxes[k])
            if o_iou > iou or (boxes[i].volume <= boxes[k].volume and inside > overlap):
                ok = False
                break
        if ok:
            kept.append(i)
    return kept


def _to_metres(depth: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InvalidValueError(f"detect: depth must be (H, W), got {depth.shape}")
    if depth.dtype == np.uint16:
        return depth.astype(np.float32) / 1000.0
    return np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)


def _models(models) -> list[CategoryModel]:
    if isinstance(models, CategoryModel):
        return [models]
    if isinstance(models, Mapping):
        out = []
        for cat, m in models.items():
            m = load_model(m, category=cat) if isinstance(m, (str, Path)) else m
            out.append(m if isinstance(m, CategoryModel) else CategoryModel(cat, m, _box(m, cat)))
        return out
    return [load_model(m) if isinstance(m, (str, Path)) else m for m in models]


def _box(forest, cat):
    from isa.detection.category_boxes import model_box

    return model_box(forest, f"{cat} model")


def _candidates(model: CategoryModel, hyps, Rg, floor, params: DetectParams) -> list[dict]:
    from isa.detection.hypotheses import upright_rotation

    out = []
    up_z = Rg[2]
    for rank, h in enumerate(hyps):
        R_up, _, tilt = upright_rotation(h["R"], Rg)
        if params.max_tilt_deg is not None and tilt > params.max_tilt_deg:
            continue
        t = np.asarray(h["t"], dtype=float)
        if floor is not None:
            gap = float(up_z @ t) - model.box.ssc_offset[2] - model.box.size[2] / 2 - floor  # box bottom - floor
            if params.floor_gap is not None and abs(gap) > params.floor_gap:
                continue
            t = t - gap * up_z  # set it down on the floor
        out.append({"R": R_up, "t": t, "forest_score": float(h["score"]), "support": int(h.get("support", 0)),
                    "rank": rank, "tilt_deg": tilt})
    return out


def turned(R: np.ndarray, t: np.ndarray, angle: float, centre_obj: np.ndarray, Rg: np.ndarray):
    """The pose turned by ``angle`` about the vertical through the object-frame point ``centre_obj``."""
    Rz = Rg.T @ rot_z(angle) @ Rg  # the turn about gravity, in camera coordinates
    c = R @ centre_obj + t
    R2 = Rz @ R
    return R2, c - R2 @ centre_obj


def _verify_scaled(evidence, R, t, shapes: ShapeLibrary, s: int, scale: np.ndarray, params: VerifyParams,
                   Rg: np.ndarray, floor: float | None, n_points: int | None = None):
    """Verify shape ``s`` scaled per axis by ``scale`` (about the object origin) at ``(R, t)``,
    set on the floor when there is one: ``(Verification, t)``."""
    if floor is not None:
        t = t - (float(Rg[2] @ t) + shapes.bounds[s, 0, 2] * scale[2] - floor) * Rg[2]
    lateral = max(params.lateral, params.lateral_fraction * float(np.linalg.norm(shapes.sizes[s] * scale)))
    v = verify_pose(evidence, R, t, shapes.points[s] * scale, shapes.spacing[s], replace(params, lateral=lateral),
                    n_points)
    return v, t


def _score_shapes(evidence, cand, shapes: ShapeLibrary, params: VerifyParams, Rg: np.ndarray,
                  floor: float | None, turns: int = 1, n_points: int | None = None) -> None:
    """Verify every shape (at its training size) at the candidate's pose, and at the pose turned
    by 360 / ``turns`` degree steps about the shape's box centre, and keep the best: its score,
    shape index, pose and the ranked shape indices (for :func:`_fit_size`)."""
    best, per_shape = None, np.full(len(shapes), -np.inf)
    one = np.ones(3)
    for s in range(len(shapes)):
        for k in range(turns):
            R, t = cand["R"], cand["t"]
            if k:
                R, t = turned(R, t, 2 * math.pi * k / turns, shapes.centres[s], Rg)
            v, t = _verify_scaled(evidence, R, t, shapes, s, one, params, Rg, floor, n_points)
            per_shape[s] = max(per_shape[s], v.score)
            if best is None or v.score > best[0].score:
                best = (v, s, R, t, k)
    cand.update(score=best[0].score, shape=best[1], R=best[2], t=best[3], verification=best[0], turn=best[4],
                scale=one, shape_order=np.argsort(-per_shape, kind="stable"))


def _size_ok(category: str, size: np.ndarray, margin: float = 0.15) -> bool:
    """Whether extents (x, y, z) fit the category's real-world sizes (:data:`isa.categories.SIZES`,
    widened by ``margin``): height in its range, the longer horizontal side in the length range."""
    from isa.categories import SIZES

    r = SIZES.get(category)
    if r is None:
        return True
    h, length = float(size[2]), float(max(size[0], size[1]))
    return ((1 - margin) * r.height[0] <= h <= (1 + margin) * r.height[1]
            and (1 - margin) * r.length[0] <= length <= (1 + margin) * r.length[1])


def _fit_size(evidence, cand, shapes: ShapeLibrary, params: VerifyParams, Rg: np.ndarray, floor: float | None,
              n_shapes: int, steps: Sequence[float], rounds: int = 2, category: str = "",
              n_points: int | None = None) -> None:
    """The object's size (a 9D pose): for the candidate's best ``n_shapes`` shapes, a coordinate
    search over per-axis scale factors (each axis tries ``steps`` times its current factor,
    ``rounds`` times; sizes outside the category's real-world range are not tried), keeping the
    best-verifying shape and scale."""
    best = None
    for s in cand["shape_order"][:n_shapes]:
        scale = np.ones(3)
        v, t = _verify_scaled(evidence, cand["R"], cand["t"], shapes, s, scale, params, Rg, floor, n_points)
        cur = (v.score, scale, t, v)
        for _ in range(rounds):
            for axis in range(3):
                for f in steps:
                    trial = cur[1].copy()
                    trial[axis] *= f
                    if not _size_ok(category, shapes.sizes[s] * trial):
                        continue
                    v, t = _verify_scaled(evidence, cand["R"], cand["t"], shapes, s, trial, params, Rg, floor, n_points)
                    if v.score > cur[0]:
                        cur = (v.score, trial, t, v)
        if best is None or cur[0] > best[0]:
            best = (cur[0], int(s), cur[1], cur[2], cur[3])
    # The final score from every point of the chosen shape and size.
    v, t = _verify_scaled(evidence, cand["R"], cand["t"], shapes, best[1], best[2], params, Rg, floor)
    cand.update(score=v.score, shape=best[1], scale=best[2], t=t, verification=v)


def detect(depth: np.ndarray, intrinsics: Intrinsics, models, gravity: np.ndarray | None = None,
           params: DetectParams = DetectParams()) -> DetectResult:
    """Every category of ``models`` in one depth frame, one ranked list (module docstring).

    ``depth`` (H, W) float metres or uint16 mm (0 = missing); ``models``: a mapping category ->
    model path / :class:`isa.forest.model.Forest` / :class:`CategoryModel`, or a sequence of
    :class:`CategoryModel`; ``gravity`` the camera -> upright rotation when known.
    """
    from detect_reference.planes import PlaneParams, remove_planes

    secs: dict[str, float] = {}
    t0 = time.perf_counter()
    depth = _to_metres(depth)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise InvalidValueError(f"detect: depth is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                         f"{intrinsics.width}x{intrinsics.height}")
    ms = _models(models)
    grav = estimate_gravity(depth, intrinsics, gravity)
    Rg = grav.R
    secs["gravity"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    planes = remove_planes(depth, intrinsics, Rg, PlaneParams()) if params.remove_planes else None
    clean = planes.depth if planes is not None else depth
    floor = planes.floor.height if planes is not None and planes.floor is not None else None
    secs["planes"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    per_model = []
    for m in ms:
        kw = {"stride": params.stride, "max_hypotheses": params.max_hypotheses, **params.predict}
        if m.foreground is not None:
            from isa.detection.background import weighted_predict

            per_model.append(weighted_predict(m.forest, m.foreground, clean, intrinsics, **kw))
        else:
            per_model.append(m.forest.predict(clean, intrinsics, **kw))
    secs["votes"] = time.perf_counter() - t0
    if grav.source == "level" and any(per_model):  # neither given nor a floor: the votes' tilt
        grav = estimate_gravity(np.zeros_like(depth), intrinsics, None, [h for hs in per_model for h in hs])
        Rg = grav.R
    t0 = time.perf_counter()
    evidence = (DepthEvidence(depth, intrinsics, planes.removed if planes is not None else None)
                if params.verify is not None else None)
    pts_up = upright_points(depth, intrinsics, Rg, floor_height=floor) if params.refine is not None else None
    dets: list[SceneDetection] = []
    t_refine = 0.0
    for m, hyps in zip(ms, per_model, strict=True):
        cands = _candidates(m, hyps, Rg, floor, params)
        use_shapes = m.shapes is not None and evidence is not None
        for c in cands:
            if use_shapes:
                _score_shapes(evidence, c, m.shapes, params.verify, Rg, floor, params.turns, params.quick_points)
            else:
                c.update(score=c["forest_score"], shape=None)
        if use_shapes and params.size_top:
            for c in sorted(cands, key=lambda c: -c["score"])[: params.size_top]:
                _fit_size(evidence, c, m.shapes, params.verify, Rg, floor, params.size_shapes, params.size_steps,
                          category=m.category, n_points=params.quick_points)
        if use_shapes and params.refine is not None:
            t1 = time.perf_counter()
            for c in sorted(cands, key=lambda c: -c["score"])[: params.refine_top]:
                s, sc = c["shape"], c["scale"]
                rp = replace(params.refine, fix_height=True) if floor is not None else params.refine
                r = refine_pose(pts_up, intrinsics, c["R"], c["t"], m.shapes.points[s] * sc, m.shapes.bounds[s] * sc,
                                Rg, rp, m.shapes.normals[s] / sc / np.linalg.norm(m.shapes.normals[s] / sc, axis=1,
                                                                                    keepdims=True))
                v, t = _verify_scaled(evidence, r.R, r.t, m.shapes, s, sc, params.verify, Rg, floor)
                if v.score >= c["score"]:
                    c.update(R=r.R, t=t, score=v.score, verification=v, refined=True, refine_rms=r.rms)
            t_refine += time.perf_counter() - t1
        for c in cands:
            if use_shapes and params.forest_weight:
                c["score"] += params.forest_weight * math.log(max(c["forest_score"], 1e-6))
            if c["score"] < params.min_score:
                continue
            if c["shape"] is not None:
                size, centre = m.shapes.sizes[c["shape"]] * c["scale"], m.shapes.centres[c["shape"]] * c["scale"]
            else:
                size, centre = m.box.size, -m.box.ssc_offset
            meta = {k: c[k] for k in ("forest_score", "rank", "tilt_deg") if k in c}
            meta.update(shape=c["shape"], refined=bool(c.get("refined", False)), turn=c.get("turn", 0))
            dets.append(SceneDetection(m.category, c["R"], c["t"], np.array(size), np.array(centre), float(c["score"]),
                                       c["support"], meta))
    secs["refine"] = t_refine
    boxes = [d.box(Rg) for d in dets]
    keep = nms_across(boxes, params.nms_iou, params.nms_overlap)[: params.max_detections]
    secs["verify"] = time.perf_counter() - t0 - t_refine
    return DetectResult([dets[i] for i in keep], grav, floor, secs)


def write_bop_csv(path: str | Path, rows: Sequence[tuple[int, int, float, SceneDetection]],
                  obj_ids: Mapping[str, int]) -> Path:
    """BOP results CSV (``scene_id,im_id,obj_id,score,R,t,time``; R row-major, t in mm):
    ``rows`` of (scene_id, im_id, seconds, detection); ``obj_ids`` category -> the obj_id written."""
    path = Path(path)
    lines = ["scene_id,im_id,obj_id,score,R,t,time"]
    for scene_id, im_id, secs, d in rows:
        if d.category not in obj_ids:
            raise DataError(f"{path}: no obj_id for category {d.category!r}")
        R = " ".join(f"{x:.6f}" for x in np.asarray(d.R).reshape(-1))
        t = " ".join(f"{1000 * x:.3f}" for x in np.asarray(d.t).reshape(-1))
        lines.append(f"{scene_id},{im_id},{obj_ids[d.category]},{d.score:.6f},{R},{t},{secs:.4f}")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(path)
    return path

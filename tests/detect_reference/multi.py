"""The one-pass pipeline in numpy (the reference of ``isa._core.detect``; the steps in
``isa.detection.multi``), with its own planes, verification and refinement."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Sequence

import numpy as np

from detect_reference.refine import refine_pose
from detect_reference.verify import DepthEvidence, verify_pose
from isa import _core
from isa.camera import Intrinsics
from isa.detection.gravity import estimate_gravity
from isa.detection.multi import CategoryModel, DetectParams, DetectResult, SceneDetection, _models
from isa.detection.refine import upright_points
from isa.detection.shapes import ShapeLibrary
from isa.detection.verify import VerifyParams
from isa.evaluation.boxes3d import Box3D, footprint_intersection_area, iou_3d, rot_z


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
    depth = _core.depth_to_metres(depth, intrinsics)  # the package's conversion and checks
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
        if m.forest.leaf_weights is not None:
            from isa.detection.background import weighted_predict

            per_model.append(weighted_predict(m.forest, None, clean, intrinsics, **kw))
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
            if params.min_score is not None and c["score"] < params.min_score:
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

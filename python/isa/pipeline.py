"""The ISA pipeline for one category, end to end: instances -> skeletons + SSC -> object frames
centred at the SSC -> rendered views (BOP) -> annotated parts -> forest -> 6D hypotheses -> metric.

Each step is a plain function over the modules that do the work (``dataset``, ``ssc``,
``annotate``, ``forest``, ``pose_metrics``), so the demo, the paper experiment and users share it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh
from tqdm.auto import tqdm

from isa.camera import Intrinsics
from isa.categories import CENTRE
from isa.data import bop
from isa.evaluation.pose_metrics import average_distance, model_diameter, model_points, symmetric_average_distance
from isa.exceptions import DataError
from isa.forest.model import Forest
from isa.forest.training import (  # noqa: F401  (re-exported: the pipeline's training steps)
    PROBE_REACH,
    VOTE_BANDWIDTH,
    load_frames,
    parts_diameter,
    scaled_max_offset,
    scaled_params,
    scaled_predict_defaults,
    train_forest,
    training_set,
)
from isa.privileged.matching import calibrate_template, match_skeleton, template_from_ground_truth
from isa.privileged.skeleton import extract_skeleton
from isa.privileged.ssc import CategorySSC, centre_of_mass, select_ssc
from isa.render.dataset import ObjectSpec, procedural_objects
from isa.skeleton_graph import SkeletonGraph

#: Procedural instances whose ground-truth skeletons define a category's template (fixed seed, so
#: every run and every user gets the same template).
TEMPLATE_INSTANCES = 16
TEMPLATE_SEED = 12345


#: Of those, the first ones also calibrate the template: the systematic offset between where
#: extraction puts a node (medial) and where the ground truth does (e.g. on a toilet's rim).
CALIBRATION_INSTANCES = 8


def category_template(category: str) -> SkeletonGraph:
    """The category's skeleton template (normalised box frame), from procedural ground truth,
    calibrated against extraction on procedural instances."""
    objs = procedural_objects(category, TEMPLATE_INSTANCES, seed=TEMPLATE_SEED)
    tmpl = template_from_ground_truth([o.skeleton for o in objs], [o.mesh.bounds for o in objs])
    cal = objs[:CALIBRATION_INSTANCES]
    return calibrate_template(tmpl, [extract_skeleton(o.mesh) for o in cal], [o.skeleton for o in cal],
                              [o.mesh.bounds for o in cal])


@dataclass
class PreparedCategory:
    """A category's instances moved into SSC-centred object frames, with matched skeletons."""

    category: str
    ssc: CategorySSC
    objects: list[ObjectSpec]
    skeletons: dict[int, SkeletonGraph]  # obj_id -> matched skeleton, object frame (the chosen origin)
    coms: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    origins: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # the origin before re-centring


def _matched_skeleton(obj: ObjectSpec, template: SkeletonGraph, use_ground_truth: bool,
                      extract: Callable[[trimesh.Trimesh], SkeletonGraph] = extract_skeleton) -> tuple[SkeletonGraph, np.ndarray]:
    """The instance's template-matched skeleton and its solid centre of mass."""
    if use_ground_truth and obj.skeleton is not None:
        # Procedural ground truth already names the template's nodes in the same order.
        sk = SkeletonGraph(obj.skeleton.nodes, template.links, template.names, {"matched": [True] * len(template.nodes)})
        return sk, centre_of_mass(obj.mesh)
    raw = extract(obj.mesh)
    # Extraction's voxelisation already gives the solid COM; no second voxelisation.
    return match_skeleton(raw, template, obj.mesh.bounds), np.asarray(raw.meta["com"], float)


def _recentre(obj: ObjectSpec, sk: SkeletonGraph, origin: np.ndarray) -> tuple[ObjectSpec, SkeletonGraph]:
    mesh = obj.mesh.copy()
    mesh.apply_translation(-origin)
    gt = obj.skeleton.transformed(np.eye(3), -origin) if obj.skeleton is not None else None
    sk2 = sk.transformed(np.eye(3), -origin)
    sk2.meta = {k: v for k, v in sk2.meta.items() if k not in ("bounds", "com")}  # stale after the move
    return replace(obj, mesh=mesh, skeleton=gt), sk2


def prepare_category(
    category: str,
    objects: Sequence[ObjectSpec],
    ssc: CategorySSC | None = None,
    use_ground_truth: bool = False,
    progress: bool = True,
    tie_tolerance: int = 0,
    centre: str | None = None,
    template: SkeletonGraph | None = None,
    extract: Callable[[trimesh.Trimesh], SkeletonGraph] | None = None,
) -> PreparedCategory:
    """Skeletons matched to the category template, the SSC (fitted here on ``objects`` when
    ``ssc`` is None: the training instances; given: the test instances), and every instance moved
    so that its origin (the SSC, its centre of mass or its box centre: ``centre``) is the
    object-frame origin.

    ``use_ground_truth``: procedural objects use their true skeletons instead of extraction.
    ``tie_tolerance``: nodes within this many votes of the most repetitive one share the SSC
    (:func:`isa.privileged.ssc.select_ssc`). ``centre``: ``"ssc"``, ``"com"`` or ``"box"`` (:data:`isa.privileged.ssc.CENTRES`),
    default the category's :data:`isa.categories.CENTRE`; ignored when ``ssc`` is given (it has one).
    ``template``: the skeleton template when ``ssc`` is None (default :func:`category_template`,
    which knows the paper's four categories). ``extract``: the skeleton extractor (default
    :func:`isa.privileged.skeleton.extract_skeleton`; :class:`isa.forest.build.SkeletonCache` remembers it).
    """
    if not objects:
        raise DataError(f"prepare_category({category!r}): no instances")
    template = ssc.template if ssc is not None else (template or category_template(category))
    pairs = [
        _matched_skeleton(o, template, use_ground_truth, extract or extract_skeleton)
        for o in tqdm(objects, desc=f"skeletons {category}", disable=not progress, leave=False)
    ]
    matched = [m for m, _ in pairs]
    coms = np.array([c for _, c in pairs])
    if ssc is None:
        ssc = CategorySSC(template, select_ssc(matched, coms, tie_tolerance=tie_tolerance),
                          centre=centre or CENTRE.get(category, "ssc"))
    out_objs, out_sk, origins = [], {}, []
    for o, sk, com in zip(objects, matched, coms):
        origin = ssc.origin_of(sk, o.mesh.bounds, com)
        o2, sk2 = _recentre(o, sk, origin)
        out_objs.append(o2)
        out_sk[o2.obj_id] = sk2
        origins.append(origin)
    return PreparedCategory(category, ssc, out_objs, out_sk, coms, np.array(origins))


def save_skeletons(path: Path, prepared: PreparedCategory) -> None:
    data = {"ssc": json.loads(json.dumps(prepared.ssc.ssc.to_dict())), "template": prepared.ssc.template.to_dict(),
            "skeletons": {str(k): v.to_dict() for k, v in prepared.skeletons.items()}}
    bop.write_json(path, data)


@dataclass
class Evaluation:
    """Per test frame: the top hypothesis and its SSC average distance."""

    omegas: np.ndarray  # (F,) metres; inf where no hypothesis
    diameters: np.ndarray  # (F,) metres
    R_est: np.ndarray  # (F, 3, 3)
    t_est: np.ndarray  # (F, 3)
    scores: np.ndarray  # (F,)
    seconds: np.ndarray  # (F,) inference wall time per frame
    omegas_symmetric: np.ndarray  # (F,) metres, ADD-S (symmetries forgiven); inf where no hypothesis

    def recall(self, z: float = 0.1, symmetric: bool = False) -> float:
        om = self.omegas_symmetric if symmetric else self.omegas
        return float(np.mean(om <= z * self.diameters)) if len(om) else 0.0

    def to_dict(self) -> dict:
        return {"omega": self.omegas.tolist(), "omega_symmetric": self.omegas_symmetric.tolist(),
                "diameter": self.diameters.tolist(), "score": self.scores.tolist()}


def predict(forest: Forest, depth: np.ndarray, intrinsics: Intrinsics, **params) -> list[dict]:
    """Ranked 6D hypotheses for a whole depth image: :meth:`isa.forest.model.Forest.predict`."""
    return forest.predict(depth, intrinsics, **params)


def evaluate(
    forest: Forest,
    frames: Sequence[bop.BopFrame],
    models: dict[int, trimesh.Trimesh],
    progress: bool = True,
    **predict_params,
) -> Evaluation:
    """Top hypothesis of every test frame scored with the SSC average distance (Eq. 14-15), and
    with ADD-S (which forgives the model's symmetries) beside it."""
    pts = {k: model_points(m) for k, m in models.items()}
    diam = {k: model_diameter(p) for k, p in pts.items()}
    F = len(frames)
    om, om_s, dm, sc, secs = np.full(F, np.inf), np.full(F, np.inf), np.zeros(F), np.zeros(F), np.zeros(F)
    Rs, ts = np.tile(np.eye(3), (F, 1, 1)), np.zeros((F, 3))
    for i, f in enumerate(tqdm(frames, desc="predict", disable=not progress, leave=False)):
        t0 = time.perf_counter()
        hyps = predict(forest, f.depth, f.intrinsics, **predict_params)
        secs[i] = time.perf_counter() - t0
        dm[i] = diam[f.obj_id]
        if hyps:
            h = hyps[0]
            Rs[i], ts[i], sc[i] = np.asarray(h["R"]), np.asarray(h["t"]), float(h["score"])
            om[i] = float(average_distance(pts[f.obj_id], f.R, f.t, Rs[i], ts[i]))
            om_s[i] = symmetric_average_distance(pts[f.obj_id], f.R, f.t, Rs[i], ts[i])
    return Evaluation(om, dm, Rs, ts, sc, secs, om_s)

"""Every category in one pass: ``detect(depth, intrinsics, models, gravity=None)``.

1. **Gravity**: given, else the floor's normal, else the votes' tilt (:mod:`isa.detection.gravity`).
2. **Planes**: floor and walls set to missing depth for the voting (the forests were trained on
   isolated objects), found once for all categories (:func:`isa.detection.planes.remove_planes`).
3. **Votes**: each category forest on the cleaned depth gives ranked 6D hypotheses; each is
   snapped upright (tilt limit), rejected when its bottom is far from the floor, set on it.
4. **Verification** (:mod:`isa.detection.verify`) on the *raw* depth against each of the category's
   training shapes; the best shape gives the score (comparable across categories and frames)
   and the size.
   Beside the forests' hypotheses, footprints on the floor propose each category's box
   (:mod:`isa.detection.proposals`), scored by the same verification.
5. **Refinement** (:mod:`isa.detection.refine`) of the best hypotheses: upright ICP with the best shape,
   then verified again; kept when the score does not drop.
6. **NMS across categories**: one ranked list; a box overlapping a better one (3D IoU over
   ``nms_iou``, or a smaller box with over ``nms_overlap`` of its volume inside the better one)
   is dropped, whatever its category, since a place holds one object.
7. **Ranking** (:mod:`isa.detection.ranking`): the kept detections of a model with a ranker are
   scored by it (the probability of a true object, from the verification's counts, the forest's
   score and the size fit) and sorted again. Every kept detection of a verified model carries
   those features in ``meta["features"]``.

The core runs every step (``isa._core.detect``, ``isa_core::scene::detect``; categories and
hypotheses in parallel); this module loads models, mirrors the parameters (defaults from
``isa._core.DETECT_DEFAULTS``) and wraps the answer. A forest with leaf weights from background
parts (:mod:`isa.detection.background`, kept in its model file) weights its votes in the core.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from isa import _core, atomic
from isa.camera import Intrinsics
from isa.detection.gravity import GravityEstimate
from isa.detection.planes import PlaneParams
from isa.detection.proposals import ProposalParams
from isa.detection.refine import RefineParams
from isa.detection.shapes import ShapeLibrary
from isa.detection.stage_params import core_params
from isa.detection.verify import VerifyParams
from isa.evaluation.boxes3d import Box3D, box_from_pose
from isa.exceptions import DataError, InputWarning

_D = _core.DETECT_DEFAULTS

__all__ = ["CategoryModel", "load_model", "DetectParams", "SceneDetection", "DetectResult", "detect",
           "nms_across", "write_bop_csv"]


@dataclass(frozen=True, eq=False)
class CategoryModel:
    """A category's forest (with its leaf weights, if any: :mod:`isa.detection.background`),
    its box (size and origin offset, :class:`isa.detection.CategoryBox`) and its shape library
    (None: no verification, the forest's score and box are used), and its ranker
    (:class:`isa.detection.ranking.Ranker`; None: the verification score ranks)."""

    category: str
    forest: Any
    box: Any
    shapes: ShapeLibrary | None = None
    ranker: Any = None


def load_model(path: str | Path, shapes: str | Path | ShapeLibrary | None = None,
               category: str | None = None, foreground: str | Path | None = None,
               ranker: str | Path | Any = None) -> CategoryModel:
    """A :class:`CategoryModel` from a model file; ``shapes`` a library or its ``.isl`` / ``.npz``
    (default: ``<model>.shapes.isl``, else ``<model>.shapes.npz``, beside the model when it
    exists); ``foreground`` a leaf foreground file (``.foreground.npz``, as
    ``python -m isa.detection.background -o X.npz`` writes; default ``<model>.foreground.npz``
    when it exists) whose probabilities become the forest's leaf weights, replacing any the
    model file holds; ``ranker`` a :class:`isa.detection.ranking.Ranker` or its ``.ranker.json``
    (default: ``<model>.ranker.json`` beside the model when it exists)."""
    from isa.detection.background import LeafForeground
    from isa.detection.category_boxes import model_box
    from isa.detection.ranking import Ranker
    from isa.forest.model import Forest

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: model file not found")
    forest = Forest.load(path)
    box = model_box(forest, str(path))
    for suffix in (".shapes.isl", ".shapes.npz"):
        if shapes is None and path.with_suffix(suffix).is_file():
            shapes = path.with_suffix(suffix)
    if shapes is not None and not isinstance(shapes, ShapeLibrary):
        shapes = ShapeLibrary.load(shapes)
    if foreground is None and path.with_suffix(".foreground.npz").is_file():
        foreground = path.with_suffix(".foreground.npz")
    if foreground is not None:
        fg = foreground if isinstance(foreground, LeafForeground) else LeafForeground.load(foreground)
        forest = forest.with_leaf_weights(fg.leaf_weights(forest))
    if ranker is None and path.with_suffix(".ranker.json").is_file():
        ranker = path.with_suffix(".ranker.json")
    if ranker is not None and not isinstance(ranker, Ranker):
        ranker = Ranker.load(ranker)
    return CategoryModel(category or box.category or forest.metadata.get("category"), forest, box, shapes, ranker)


@core_params(None)
class DetectParams:
    """``stride``, ``max_hypotheses`` go to each forest's voting; ``max_tilt_deg`` rejects
    hypotheses tilted further from up; ``floor_gap`` rejects those whose bottom is further from
    the found floor (and the rest are set on it); ``planes`` the plane finding; ``verify`` /
    ``refine`` None switch the steps off; ``proposals`` the footprint hypotheses beside the
    forests' (None: off; :mod:`isa.detection.proposals`); ``size_top`` hypotheses per category get their size
    fitted (per-axis scale of their ``size_shapes`` best shapes, factors ``size_steps``; 0:
    training sizes only); the shapes are screened and sized on their first ``quick_points``
    samples (None: all), the final score uses all; ``forest_weight`` adds that times the log of
    the forest's score to a verified score; ``refine_top`` hypotheses per category are refined;
    ``turns`` > 1 also verifies each hypothesis turned by multiples of 360 / ``turns`` degrees
    about gravity (the forest's front and back are the easiest to confuse) and keeps the best;
    ``nms_iou`` / ``nms_overlap`` the suppression (across categories; within each for the
    ``nms_order`` values but ``"joint"``); ``max_detections`` per frame;
    ``min_score`` drops those with a weaker verified score, before ranking (None: none); ``rank_before_nms`` ranks every candidate
    before NMS (the rankers' probabilities decide overlaps) instead of the kept detections
    only; ``nms_order`` ``"joint"`` runs one NMS over every category on the verified scores and
    then ranks what it keeps, ``"ranked"`` runs NMS within each category, ranks those, then NMS
    across categories on the ranked scores with ``cross_iou`` / ``cross_overlap`` (so a ranker's
    probability decides between categories), ``"per_category"`` leaves out the NMS across
    categories (what the rankers of ``"ranked"`` are fitted on, :func:`isa.detection.ranking.detection_outcomes`);
    ``predict`` further voting keywords.
    Defaults: the core's (``isa._core.DETECT_DEFAULTS``); the nested stages are declared here
    because each is a class of its own."""

    planes: PlaneParams = field(default_factory=PlaneParams)
    verify: VerifyParams | None = field(default_factory=VerifyParams)
    refine: RefineParams | None = field(default_factory=RefineParams)
    proposals: ProposalParams | None = field(default_factory=ProposalParams)
    predict: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The core's JSON form (``isa_core::DetectParams``)."""
        d = asdict(self)
        d["size_steps"] = list(self.size_steps)
        if d["min_score"] is not None and math.isinf(d["min_score"]) and d["min_score"] < 0:
            d["min_score"] = None
        return d


@dataclass(frozen=True, eq=False)
class SceneDetection:
    """One detected object: ``category``; pose ``R`` (3, 3), ``t`` (3,) metres (object to camera,
    ``t`` the category's origin); ``size`` (3,) its extents along its own x, y, z; ``box_centre``
    (3,) that box's centre in the object frame; ``score`` (verification score when shapes are
    given, else the forest's; a ranker's probability when the model has one); ``support`` the
    votes behind it; ``meta`` (forest score, ranking features, shape,
    refinement)."""

    category: str
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    box_centre: np.ndarray
    score: float
    support: int
    meta: dict = field(default_factory=dict)

    @property
    def pose(self) -> np.ndarray:
        """The 4x4 pose ``[[R, t], [0, 0, 0, 1]]``: ``X_cam = pose @ [X_obj, 1]``."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        return T

    def box(self, R_gravity: np.ndarray) -> Box3D:
        """The gravity-aligned box in the upright frame."""
        return box_from_pose(self.R, self.t, self.size, -self.box_centre, R_gravity, self.category, self.score)

    def to_dict(self) -> dict:
        return {"category": self.category, "R": np.asarray(self.R).tolist(), "t": np.asarray(self.t).tolist(),
                "pose": self.pose.tolist(),
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


def nms_across(boxes: Sequence[Box3D], iou: float = _D["nms_iou"], overlap: float = _D["nms_overlap"]) -> list[int]:
    """Greedy NMS over boxes of any category, best score first: a box is dropped when its IoU
    with a kept one exceeds ``iou``, or when it is the smaller and more than ``overlap`` of its
    volume lies inside a kept one (a toilet box inside a chair's: part of the same object). A
    larger box is not dropped for a smaller one inside it (a false chair on a bed must not remove
    the bed). Returns the kept indices, best first (``isa._core.nms_across``)."""
    rows = np.array([[*b.centre, *b.size, b.yaw, b.score] for b in boxes], dtype=float).reshape(-1, 8)
    return list(_core.nms_across(rows, iou, overlap))


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


def _size_range(m: CategoryModel):
    """The real-world sizes the model's category keeps to in the size fit: its library's when
    the library is of that category, else :data:`isa.categories.SIZES`' (None: any)."""
    from isa.categories import SIZES

    if m.shapes is not None and m.shapes.category == m.category:
        return m.shapes.size_range
    r = SIZES.get(m.category)
    return None if r is None else (tuple(r.height), tuple(r.length))


def _check_nms_order(models, params: DetectParams) -> None:
    """Warn when a ranker was fitted under another NMS order than ``params``': it then sees
    other detections than it learnt from (a ``"ranked"`` ranker under ``"joint"`` NMS, or the
    reverse, ranks worse: docs/experiments.md, session 19), or when it does not record its order
    and detection runs another than ``"joint"`` (files from before the record were fitted under
    it, the default then)."""
    for m in models:
        if m.ranker is None:
            continue
        fitted = m.ranker.nms_order
        if fitted is None and params.nms_order != "joint":
            warnings.warn(f"{m.category}: its ranker does not record the NMS order it was fitted under (files "
                          f"written before the record were fitted under 'joint', the default then); detection "
                          f"runs nms_order={params.nms_order!r}: refit it (python -m isa.detection.ranking) or "
                          f"detect with nms_order='joint'", InputWarning, stacklevel=3)
        elif fitted is not None and fitted != params.nms_order:
            warnings.warn(f"{m.category}: its ranker was fitted under nms_order={fitted!r}, detection runs "
                          f"nms_order={params.nms_order!r}; refit it (python -m isa.detection.ranking --set "
                          f"'nms_order=\"{params.nms_order}\"') or detect with nms_order={fitted!r}",
                          InputWarning, stacklevel=3)


def detect(depth: np.ndarray, intrinsics: Intrinsics, models, gravity: np.ndarray | None = None,
           params: DetectParams = DetectParams(), depth_scale: float | None = None) -> DetectResult:
    """Every category of ``models`` in one depth frame, one ranked list (module docstring).

    ``depth`` (H, W) float metres or uint16 mm (0 = missing), or an organised point cloud
    (H, W, 3); ``depth_scale`` millimetres per stored unit otherwise (as :meth:`Forest.predict
    <isa.forest.model.Forest.predict>`: TUM's 5000 per metre is 0.2, float millimetres 1). The
    size must match ``intrinsics`` (a transposed image is an error); an implausible depth range
    raises :class:`isa.InputWarning`. ``models``: a mapping category -> model path /
    :class:`isa.forest.model.Forest` / :class:`CategoryModel`, or a sequence of
    :class:`CategoryModel`; ``gravity`` the camera -> upright rotation when known.
    """
    depth = _core.depth_to_metres(depth, intrinsics, depth_scale)
    ms = _models(models)
    _check_nms_order(ms, params)
    g = None if gravity is None else np.asarray(gravity, dtype=float).reshape(3, 3)
    specs = [{"category": m.category, "forest": m.forest, "size": m.box.size, "ssc_offset": m.box.ssc_offset,
              "shapes": None if m.shapes is None else m.shapes.core, "size_range": _size_range(m),
              "ranker": None if m.ranker is None else m.ranker.to_json()}
             for m in ms]
    out = _core.detect(np.ascontiguousarray(depth), intrinsics, specs, g, params=params.to_dict())
    dets = [SceneDetection(d["category"], d["R"], d["t"], d["size"], d["box_centre"], d["score"], d["support"],
                           {k: d[k] for k in ("forest_score", "rank", "tilt_deg", "shape", "refined", "turn", "features")})
            for d in out["detections"]]
    grav = GravityEstimate(out["gravity"], out["gravity_source"])
    return DetectResult(dets, grav, out["floor_height"], dict(out["seconds"]))


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
    atomic.write_text(path, "\n".join(lines) + "\n")
    return path

"""The scene benchmark: run category models on scenes, score them, write the report section.

A *dataset* here is a list of :class:`View` (one depth frame with its calibration, gravity and
ground truth): BOP scene folders written by :func:`isa.scenes.make_scenes` or the Scan2CAD views
(:func:`scene_views`, ground truth with exact 6D poses), or SUN RGB-D frames (:func:`sun_views`,
ground-truth boxes only). Every dataset goes through the same steps:

1. :func:`detect_views`: today's detection (:func:`isa.detection.hypotheses.detect_frame`: planes removed,
   votes, gravity snapping, floor rest, NMS) with the gravity the dataset gives, each box turned
   back into a 6D :class:`isa.scenes.scoring.Detection` with the category box's size;
2. :func:`isa.scenes.scoring.evaluate`: 6D and 3D-box AP, recall and AP by visible fraction;
3. :func:`scenes_section`: tables and pictures into an :class:`isa.report.report.Report`, the numbers
   into ``report.results["scenes"][name]`` (``results.json``, schema in docs/results.md).

Detections are stored (:func:`save_detections`, ``detections.json``) so that they can be scored
again without the models (``python -m isa scenes evaluate``).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from isa import atomic
from isa.camera import Intrinsics
from isa.exceptions import DataError, DataNotFoundError
from isa.scenes.scoring import (
    METRICS,
    VISIB_BINS,
    Detection,
    Scores,
    evaluate,
    ground_truth_box,
)

__all__ = [
    "DETECTIONS_SCHEMA",
    "View",
    "dataset_views",
    "detect_views",
    "load_detections",
    "load_models",
    "rescore",
    "run_datasets",
    "save_detections",
    "scene_views",
    "scenes_section",
    "score_views",
    "sun_views",
]

#: Version tag of ``detections.json``.
DETECTIONS_SCHEMA = "isa-scene-detections/1"

_METRIC_NAMES = {"6d": "6D (Eq. 14, z = 0.1)", "6d_sym": "6D, symmetries forgiven", "box_0.25": "3D box IoU 0.25",
                 "box_0.5": "3D box IoU 0.5"}


@dataclass(frozen=True, eq=False)
class View:
    """One frame of a dataset: ``name`` (``scene/im`` ids or the SUN frame), ``depth`` (H, W)
    float32 metres, ``intrinsics``, ``gravity`` (3, 3) camera to upright or None, ``gt`` the
    ground truth (:class:`isa.scenes.io.GroundTruth` or :class:`isa.evaluation.boxes3d.Box3D`)."""

    name: str
    depth: np.ndarray
    intrinsics: Intrinsics
    gravity: np.ndarray | None
    gt: tuple


def _frame_name(frame, i: int) -> str:
    sid, iid = getattr(frame, "scene_id", None), getattr(frame, "im_id", None)
    if sid is not None and iid is not None:
        return f"{int(sid):06d}/{int(iid):06d}"
    return str(getattr(frame, "name", i))


def scene_views(root: str | os.PathLike, split: str = "test", limit: int | None = None) -> list[View]:
    """The frames of a BOP scene dataset (:func:`isa.scenes.io.read_scene_dataset`)."""
    from isa.scenes.io import read_scene_dataset

    frames = read_scene_dataset(root, split)
    if limit is not None:
        frames = frames[:limit]
    if not frames:
        raise DataError(f"{root}: no frames in split {split!r}")
    return [View(_frame_name(f, i), np.asarray(f.depth, np.float32), f.intrinsics, f.gravity, tuple(f.gt))
            for i, f in enumerate(frames)]


def sun_views(root: str | os.PathLike) -> list[View]:
    """The SUN RGB-D frames under ``root`` (:func:`isa.detection.real.load_real_frames`), boxes as ground truth."""
    from isa.detection.real import load_real_frames

    return [View(f.name, f.depth, f.intrinsics, f.R_gravity, tuple(f.boxes)) for f in load_real_frames(root)]


def load_models(models: Mapping[str, Any]) -> tuple[dict, dict]:
    """``(forests, sources)``: category -> :class:`isa.forest.model.Forest` (paths are loaded; a
    missing file or a model without a category box is a :class:`DataError` naming it)."""
    from isa.detection.category_boxes import model_box
    from isa.forest.model import Forest

    if not models:
        raise DataError("no category models given")
    forests, sources = {}, {}
    for cat, m in models.items():
        if isinstance(m, (str, os.PathLike)):
            path = Path(m)
            if not path.is_file():
                raise DataNotFoundError(f"{path}: {cat} model file not found")
            forests[cat], sources[cat] = Forest.load(path), str(path)
        else:
            forests[cat], sources[cat] = m, "in memory"
        model_box(forests[cat], sources[cat])  # fail early, naming the file
    return forests, sources


def detect_views(models: Mapping[str, Any], views: Sequence[View], params=None, progress: bool = True,
                 desc: str = "detect") -> tuple[list[list[Detection]], list[float]]:
    """Today's detection (:func:`isa.detection.hypotheses.detect_frame`) on every view: per view the
    detections of all categories (6D, from the gravity-aligned boxes) and the seconds taken."""
    from types import SimpleNamespace

    from isa.detection.category_boxes import model_box
    from isa.detection.hypotheses import DetectionParams, detect_frame
    from isa.scenes.scoring import LEVEL_GRAVITY

    params = params or DetectionParams()
    forests, _ = load_models(models)
    boxes = {c: model_box(f) for c, f in forests.items()}
    out, secs = [], []
    for v in tqdm(views, desc=desc, unit="frame", disable=not progress):
        grav = LEVEL_GRAVITY if v.gravity is None else np.asarray(v.gravity, float)
        t0 = time.perf_counter()
        per_cat = detect_frame(forests, SimpleNamespace(depth=v.depth, intrinsics=v.intrinsics, R_gravity=grav), params)
        secs.append(time.perf_counter() - t0)
        out.append([Detection.from_box(b, grav, -boxes[c].ssc_offset) for c, d in per_cat.items() for b in d.boxes])
    return out, secs


def detect_views_full(models: Sequence[Any], views: Sequence[View], params=None, progress: bool = True,
                      desc: str = "detect") -> tuple[list[list[Detection]], list[float]]:
    """The full detector (:func:`isa.detection.multi.detect`: every category in one pass,
    verification, proposals, refinement, NMS, ranking) on every view, with the view's gravity:
    per view its detections and the seconds taken. ``models``: :class:`isa.detection.multi.CategoryModel`."""
    from isa.detection.multi import DetectParams, detect

    params = params or DetectParams()
    out, secs = [], []
    for v in tqdm(views, desc=desc, unit="frame", disable=not progress):
        t0 = time.perf_counter()
        res = detect(v.depth, v.intrinsics, models, gravity=v.gravity, params=params)
        secs.append(time.perf_counter() - t0)
        out.append([Detection(d.category, d.R, d.t, d.size, d.score, d.box_centre) for d in res.detections])
    return out, secs


def save_detections(path: str | os.PathLike, datasets: Mapping[str, Mapping[str, Any]]) -> Path:
    """Write ``detections.json``: ``datasets`` name -> {"kind": "scenes" | "sun", "source": root,
    "split": str | None, "models": {...}, "frames": [names], "detections": [[Detection]]}."""
    path = Path(path)
    doc = {"schema": DETECTIONS_SCHEMA, "datasets": {}}
    for name, d in datasets.items():
        doc["datasets"][name] = {**{k: v for k, v in d.items() if k not in ("detections", "frames")},
                                 "frames": [{"name": n, "detections": [x.to_dict() for x in dets]}
                                            for n, dets in zip(d["frames"], d["detections"])]}
    atomic.write_text(path, json.dumps(doc, indent=1))
    return path


def load_detections(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Read :func:`save_detections`' file back (detections as :class:`Detection`)."""
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"{path}: detections file not found")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("schema") != DETECTIONS_SCHEMA:
        raise DataError(f"{path}: not a {DETECTIONS_SCHEMA} file (schema {doc.get('schema') if isinstance(doc, dict) else None!r})")
    out = {}
    for name, d in doc["datasets"].items():
        out[name] = {**{k: v for k, v in d.items() if k != "frames"}, "frames": [f["name"] for f in d["frames"]],
                     "detections": [[Detection.from_dict(x) for x in f["detections"]] for f in d["frames"]]}
    return out


def score_views(views: Sequence[View], detections: Sequence[Sequence[Detection]], categories: Sequence[str],
                min_visib: float | None = None) -> Scores:
    """:func:`isa.scenes.scoring.evaluate` on a dataset (boxes in each view's upright frame)."""
    kw = {} if min_visib is None else {"min_visib": min_visib}
    return evaluate([v.gt for v in views], detections, [v.gravity for v in views], categories, **kw)


# ----------------------------------------------------------------------------------------------
# Report


def _pct(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.1f}"


def scenes_section(report, name: str, views: Sequence[View], detections: Sequence[Sequence[Detection]],
                   scores: Scores, info: Mapping[str, Any] | None = None, n_figures: int = 3,
                   heading_level: int = 2, description: str = "", draw_top: int = 3) -> dict:
    """Add one dataset's section to ``report`` (tables, AP over visible fraction, ``n_figures``
    frames with their ground truth and ``draw_top`` best detections per category) and put its
    numbers in ``report.results["scenes"][name]`` (also returned)."""
    from isa.data.sunrgbd import SceneFrame
    from isa.report.figures.scenes import scene_figure
    from isa.scenes.figures import ap_by_visibility_figure
    from isa.scenes.scoring import LEVEL_GRAVITY

    cats = scores.categories
    data = {"n_frames": len(views), **(dict(info) if info else {}), "scores": scores.to_dict()}
    report.heading(f"Scenes: {name}", heading_level)
    n_obj = {c: sum(1 for v in views for g in v.gt if g.category == c) for c in cats}
    if description:
        report.text(description)
    report.text(
        f"{len(views)} frames; objects of the scored categories: " + ", ".join(f"{c} {n_obj[c]}" for c in cats)
        + f". Average precision (%) per category, detections matched greedily by score, one per object; "
          f"objects less than {scores.min_visib:g} visible are ignored (a detection on one is neither right nor "
          f"wrong). 6D: Eq. 14's average distance at most {scores.z:g} x the diameter; with symmetries forgiven: "
          f"its minimum over the object's symmetry group; 3D box: IoU of the gravity-aligned boxes.")
    rows = []
    for c in cats:
        ms = scores.metrics[c]
        some = next(m for m in ms.values() if m is not None)
        rows.append([c, *(_pct(None if ms[m] is None else 100 * ms[m].ap) for m in METRICS),
                     f"{some.n_ground_truth} (+{some.n_ignored})", f"{some.n_detections}"])
    report.table(["category", *(_METRIC_NAMES[m] for m in METRICS), "objects (+ ignored)", "detections"], rows)
    bins = [f"{lo:g}-{hi:g}" for lo, hi in VISIB_BINS]
    rows = []
    for c in cats:
        for m in METRICS:
            s = scores.metrics[c][m]
            if s is None or s.n_ground_truth + s.n_ignored == 0:
                continue
            rec = [f"{_pct(100 * s.recall_by_visib[b][0])} ({s.recall_by_visib[b][1]})" for b in bins]
            t = "n/a" if s.median_translation_m is None else f"{100 * s.median_translation_m:.1f}"
            r = "n/a" if s.median_rotation_deg is None else f"{s.median_rotation_deg:.1f}"
            rows.append([c, _METRIC_NAMES[m], _pct(100 * s.final_recall), *rec, f"{s.n_true_positive}", t, r])
    report.text("Recall (%) of all detections: of the counted objects, and by the objects' visible fraction "
                "(objects in the bin in brackets, ignored ones included); median errors of the true positives "
                "(translation of the pose, or of the box centre without one; rotation against the nearest "
                "symmetric pose, except under Eq. 14).")
    report.table(["category", "metric", "recall", *(f"recall, visib {b}" for b in bins), "TPs", "median t error (cm)",
                  "median rotation error (deg)"], rows)
    slug = "".join(ch if ch.isalnum() else "-" for ch in name.lower())
    if any(s is not None and not all(math.isnan(v) for v in s.ap_by_visib.values())
           for ms in scores.metrics.values() for s in ms.values()):
        p = ap_by_visibility_figure(scores, report.figure_path(f"scenes-{slug}-ap-visib.png"), title=name)
        report.image(p, f"{name}: AP over the visible fraction (only the objects of each bin counted)")
    for i in np.linspace(0, len(views) - 1, min(n_figures, len(views))).round().astype(int) if views else []:
        v = views[i]
        grav = LEVEL_GRAVITY if v.gravity is None else v.gravity
        gt = tuple(ground_truth_box(g, grav) for g in v.gt if g.category in cats)
        frame = SceneFrame(v.name, v.depth, v.intrinsics, grav, gt, Path("."))
        boxes = [d.box(grav) for c in cats
                 for d in sorted((d for d in detections[i] if d.category == c), key=lambda d: -d.score)[:draw_top]]
        p = scene_figure(frame, boxes, report.figure_path(f"scenes-{slug}-{v.name.replace('/', '-')}.png"),
                         title=f"{name} {v.name}: ground truth (red), detections (green)")
        report.image(p, f"{name}, frame {v.name}: the {draw_top} best detections per category (green, with scores) "
                        "and the ground truth (red) over the depth image (left) and from above (right)")
    report.results.setdefault("scenes", {})[name] = data
    return data


# ----------------------------------------------------------------------------------------------
# The whole run


def dataset_views(kind: str, source: str | os.PathLike, split: str | None = None, limit: int | None = None) -> list[View]:
    """The views of a dataset: ``kind`` "scenes" (a BOP scene root and split) or "sun" (SUN RGB-D)."""
    if kind == "scenes":
        return scene_views(source, split or "test", limit)
    if kind == "sun":
        return sun_views(source)[:limit]
    raise DataError(f"dataset kind must be 'scenes' or 'sun', got {kind!r}")


def run_datasets(report, datasets: Mapping[str, Mapping[str, Any]], models: Mapping[str, Any], params=None,
                 min_visib: float | None = None, n_figures: int = 3, progress: bool = True,
                 heading_level: int = 2, detector: str = "baseline") -> dict[str, dict[str, Any]]:
    """Detect, score and report every dataset. ``datasets``: name -> {"kind", "source", "split",
    optional "limit", "description", "views" (already read)}; ``models``: category -> model path or Forest.
    ``detector``: "baseline" (the one-class detection, :func:`detect_views`) or "full"
    (:func:`detect_views_full`; each model's shape library and ranker are read from beside its
    file, :func:`isa.detection.multi.load_model`). Returns what :func:`save_detections` stores
    (name -> the dataset's entry with its frames and detections)."""
    from isa.detection.category_boxes import model_box
    from isa.detection.hypotheses import DetectionParams
    from isa.detection.multi import CategoryModel, DetectParams, load_model

    if detector not in ("baseline", "full"):
        raise DataError(f"detector must be 'baseline' or 'full', got {detector!r}")
    forests, sources = load_models(models)
    if detector == "full":
        params = params or DetectParams()
        full = [load_model(models[c], category=c) if isinstance(models[c], (str, os.PathLike))
                else CategoryModel(c, f, model_box(f)) for c, f in forests.items()]
        # As the evaluation's variants: votes unweighted.
        full = [replace(m, forest=m.forest.with_leaf_weights(None)) for m in full]
        sources = {m.category: f"{sources[m.category]} (shapes: {'yes' if m.shapes else 'none'}, "
                               f"ranker: {'yes' if m.ranker else 'none'})" for m in full}
    else:
        params = params or DetectionParams()
    stored = {}
    for name, d in datasets.items():
        views = d.get("views") or dataset_views(d["kind"], d["source"], d.get("split"), d.get("limit"))
        t0 = time.perf_counter()
        if detector == "full":
            dets, secs = detect_views_full(full, views, params, progress, desc=f"detect {name}")
        else:
            dets, secs = detect_views(forests, views, params, progress, desc=f"detect {name}")
        seconds = time.perf_counter() - t0
        scores = score_views(views, dets, list(forests), min_visib)
        entry = {"kind": d["kind"], "source": str(d["source"]), "split": d.get("split"), "models": sources,
                 "params": params.to_dict()}
        info = {**entry, "detect_seconds": seconds, "detect_ms_median": 1000 * float(np.median(secs))}
        scenes_section(report, name, views, dets, scores, info, n_figures, heading_level, d.get("description", ""))
        stored[name] = {**entry, "frames": [v.name for v in views], "detections": dets}
    return stored


def rescore(report, stored: Mapping[str, Mapping[str, Any]], min_visib: float | None = None, n_figures: int = 3,
            heading_level: int = 2) -> None:
    """Score stored detections (:func:`load_detections`) again against their datasets' ground truth."""
    for name, d in stored.items():
        views = dataset_views(d["kind"], d["source"], d.get("split"))
        by_name = {v.name: v for v in views}
        missing = [n for n in d["frames"] if n not in by_name]
        if missing:
            raise DataError(f"{d['source']}: frames of the stored detections not found: {', '.join(missing[:5])}")
        views = [by_name[n] for n in d["frames"]]
        scores = score_views(views, d["detections"], list(d["models"]), min_visib)
        info = {k: d[k] for k in ("kind", "source", "split", "models", "params") if k in d}
        scenes_section(report, name, views, d["detections"], scores, info, n_figures, heading_level)

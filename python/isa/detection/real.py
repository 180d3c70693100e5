"""Real-data evaluation: every category model on every SUN RGB-D frame, AP at 3D IoU >= 0.25, and
the report's real-data section."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from isa.categories import CATEGORIES
from isa.detection.category_boxes import CategoryBox, model_box
from isa.detection.hypotheses import DetectionParams, _forest, detect_frame
from isa.detection.planes import Plane
from isa.evaluation.boxes3d import IOU_THRESHOLD, APResult, Box3D, evaluate_detections, iou_3d
from isa.exceptions import DataError, InvalidValueError

__all__ = ["RealResult", "evaluate_real", "load_real_frames", "real_section"]


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
    (:class:`isa.data.sunrgbd.SceneFrame`) and score AP at 3D IoU >= 0.25 per category (over all frames,
    as Sliding Shapes). ``boxes`` overrides / supplies the models' category boxes."""
    if not models:
        raise InvalidValueError("evaluate_real: no models")
    if not frames:
        raise InvalidValueError("evaluate_real: no frames")
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
    from isa.data import sunrgbd

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
    """Add the real-data section to an :class:`isa.report.report.Report`: the AP table in the layout of
    the paper's Table 2 (right) with the published numbers, per-frame figures (predicted boxes
    green, ground truth red, over the depth image and in a top view), a per-detection table, and
    the numbers in ``report.results["real"]`` (also returned)."""
    from isa.evaluation.published import DETECTION_AP, PRINTED_MEANS
    from isa.report.figures.scenes import scene_figure

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

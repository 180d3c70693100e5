"""Wrong-category rejection (issue 19 item 5): does a category model's score say whether a frame
shows its category at all?

Every category model answers every frame with a best hypothesis, a table image included. What
tells a user to drop the answer is its score, and three are measured here, each on the model's
top hypothesis of a frame (isolated object, background missing, as the experiment renders):

- ``score``: the forest's raw mode density (:attr:`isa.Hypothesis.score`). It grows with the
  number of parts the image has (object size and distance), so it is not comparable across
  frames;
- ``vote_share``: that density over the total weight of the votes cast (``Forest.image_votes``):
  the share of the frame's votes that agree on this pose, in ``[0, 1]`` whatever the object's size
  in the image;
- ``verified``: the score of :func:`isa.detection.detect` with the category's training shapes
  (:mod:`isa.detection.verify`: the share of the shape's visible surface the depth confirms,
  minus what it refutes, after refinement, plus ``DetectParams.forest_weight`` times the log of
  the forest's score, so it can exceed 1).

For each score, the threshold is the one that best separates a model's own category's frames
from the other categories' frames (highest balanced accuracy: the mean of the acceptance rate on
its own category and the rejection rate on the others), chosen on validation frames
(``python -m isa experiment --validation``) and then applied unchanged to test frames.

``python -m isa.evaluation.rejection EXPERIMENT_OUT [--thresholds FILE]`` reads an experiment's
output folder (``models/<category>-<quality>.isa`` and the rendered ``data/<category>/test``
frames) and writes ``rejection.json`` (and the thresholds chosen, unless given) there.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from isa import atomic
from isa.exceptions import DataError

__all__ = ["SCORES", "FrameScores", "frame_scores", "cross_scores", "choose_threshold", "rates", "first_frames", "main"]

#: The scores compared (module docstring).
SCORES = ("score", "vote_share", "verified")


@dataclass(frozen=True)
class FrameScores:
    """One model's scores on a list of frames: one array per name in :data:`SCORES`
    (``verified`` is NaN for frames without a detection, -inf is never used)."""

    score: np.ndarray
    vote_share: np.ndarray
    verified: np.ndarray

    def get(self, name: str) -> np.ndarray:
        return getattr(self, name)


def frame_scores(forest, frames: Sequence, shapes=None, category: str | None = None) -> FrameScores:
    """``forest``'s top-hypothesis scores on ``frames`` (objects with ``depth`` in metres and
    ``intrinsics``); ``verified`` needs ``shapes`` (a :class:`isa.detection.shapes.ShapeLibrary`),
    else it is NaN."""
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel, DetectParams, detect

    raw, share, ver = [], [], []
    model = None
    if shapes is not None:
        model = CategoryModel(category or shapes.category, forest, model_box(forest, category or ""), shapes)
    for f in frames:
        hyps = forest.predict(f.depth, f.intrinsics)
        if not hyps:
            raw.append(0.0)
            share.append(0.0)
        else:
            votes = forest.image_votes(f.depth, f.intrinsics)
            total = float(np.sum(votes["weight"]))
            raw.append(float(hyps[0].score))
            share.append(float(hyps[0].score) / total if total > 0 else 0.0)
        if model is None:
            ver.append(np.nan)
        else:
            dets = detect(f.depth, f.intrinsics, [model], params=DetectParams(max_detections=1)).detections
            ver.append(float(dets[0].score) if dets else np.nan)
    return FrameScores(np.asarray(raw), np.asarray(share), np.asarray(ver))


def cross_scores(models: Mapping[str, object], frames: Mapping[str, Sequence], shapes: Mapping[str, object] | None = None,
                 progress: Callable[[str, str], None] | None = None) -> dict[str, dict[str, FrameScores]]:
    """``[model category][frame category]`` -> :class:`FrameScores` of that model on those frames."""
    out: dict[str, dict[str, FrameScores]] = {}
    for mc, forest in models.items():
        out[mc] = {}
        for fc, fs in frames.items():
            if progress is not None:
                progress(mc, fc)
            out[mc][fc] = frame_scores(forest, fs, None if shapes is None else shapes.get(mc), mc)
    return out


def _valid(x: np.ndarray) -> np.ndarray:
    # A frame without a detection has no score: it is rejected at any threshold.
    return np.where(np.isfinite(x), x, -np.inf)


def rates(own: np.ndarray, other: np.ndarray, threshold: float) -> tuple[float, float]:
    """(acceptance of ``own``-category frames, rejection of ``other``-category frames) at
    ``threshold`` (a frame is accepted when its score is at least the threshold)."""
    own, other = _valid(np.asarray(own, float)), _valid(np.asarray(other, float))
    return float(np.mean(own >= threshold)), float(np.mean(other < threshold))


def choose_threshold(own: np.ndarray, other: np.ndarray) -> float:
    """The threshold with the highest balanced accuracy (mean of :func:`rates`); ties go to the
    lowest such threshold (accept more). Candidates: midpoints between consecutive distinct
    scores."""
    own, other = _valid(np.asarray(own, float)), _valid(np.asarray(other, float))
    if own.size == 0 or other.size == 0:
        raise DataError("choose_threshold: needs frames of the model's own category and of others")
    v = np.unique(np.concatenate([own, other])[np.isfinite(np.concatenate([own, other]))])
    if v.size == 0:
        return 0.0
    cands = np.concatenate([[v[0] - 1e-9], (v[1:] + v[:-1]) / 2, [v[-1] + 1e-9]])
    acc = [(np.mean(own >= c) + np.mean(other < c)) / 2 for c in cands]
    return float(cands[int(np.argmax(acc))])


def _auc(own: np.ndarray, other: np.ndarray) -> float:
    """Probability that an own-category frame scores above another category's (ties count half)."""
    a, b = _valid(np.asarray(own, float))[:, None], _valid(np.asarray(other, float))[None, :]
    return float(np.mean((a > b) + 0.5 * (a == b)))


def summarise(cross: Mapping[str, Mapping[str, FrameScores]], thresholds: Mapping[str, Mapping[str, float]] | None = None
              ) -> tuple[dict, dict]:
    """(per model and score: threshold, acceptance, rejection per other category, AUC; the
    thresholds used). ``thresholds`` [model][score]; None: chosen on these frames."""
    table: dict = {}
    used: dict = {}
    for mc, by_frame in cross.items():
        table[mc], used[mc] = {}, {}
        for name in SCORES:
            own = by_frame[mc].get(name)
            others = {fc: s.get(name) for fc, s in by_frame.items() if fc != mc}
            if not others:
                continue
            allo = np.concatenate(list(others.values()))
            if np.all(np.isnan(own)):
                continue
            t = choose_threshold(own, allo) if thresholds is None else float(thresholds[mc][name])
            used[mc][name] = t
            acc, rej = rates(own, allo, t)
            table[mc][name] = {"threshold": t, "accept_own": 100 * acc, "reject_others": 100 * rej,
                               "reject": {fc: 100 * rates(own, o, t)[1] for fc, o in others.items()},
                               "auc": _auc(own, allo), "n_own": int(own.size), "n_others": int(allo.size)}
    return table, used


def first_frames(frames: Sequence, n: int) -> list:
    """The first ``n`` of ``frames`` in the experiment's round-robin order over instances (by
    ``(im_id, obj_id)``, as :func:`isa.experiment._test_frames` picks its test images): every
    instance contributes, not only the first scenes."""
    return sorted(frames, key=lambda f: (f.im_id, f.obj_id))[:n]


def _experiment_inputs(out: Path, quality: str):
    from isa import pipeline
    from isa.detection.shapes import bop_shape_library
    from isa.forest.model import Forest

    models, frames, shapes = {}, {}, {}
    for path in sorted((out / "models").glob(f"*-{quality.replace('+', '')}.isa")):
        c = path.name[: -len(f"-{quality.replace('+', '')}.isa")]
        models[c] = Forest.load(path)
        frames[c] = pipeline.load_frames(out / "data" / c, "test")
        shapes[c] = bop_shape_library(out / "data" / c, c, "train")
    if len(models) < 2:
        raise DataError(f"{out}/models: needs the {quality} models of at least two categories, found {sorted(models)}")
    return models, frames, shapes


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m isa.evaluation.rejection", description=__doc__.split("\n\n")[0])
    p.add_argument("experiment", type=Path, help="an experiment's output folder (models/, data/)")
    p.add_argument("--quality", default="Q1+Q2+Q3", help="which of its models (default Q1+Q2+Q3)")
    p.add_argument("--thresholds", type=Path, help="thresholds.json chosen on validation frames (default: choose here)")
    p.add_argument("--images", type=int, default=None,
                   help="use only N test frames per category, round-robin over instances (as the experiment)")
    a = p.parse_args(argv)
    models, frames, shapes = _experiment_inputs(a.experiment, a.quality)
    if a.images:
        frames = {c: first_frames(f, a.images) for c, f in frames.items()}
    thresholds = None
    if a.thresholds is not None:
        if not a.thresholds.is_file():
            raise DataError(f"{a.thresholds}: thresholds file not found")
        thresholds = json.loads(a.thresholds.read_text())["thresholds"]
    cross = cross_scores(models, frames, shapes, progress=lambda m, f: print(f"[rejection] {m} model on {f} frames",
                                                                              flush=True))
    table, used = summarise(cross, thresholds)
    raw = {mc: {fc: {n: s.get(n).tolist() for n in SCORES} for fc, s in bf.items()} for mc, bf in cross.items()}
    doc = {"quality": a.quality, "thresholds_from": str(a.thresholds) if a.thresholds else "these frames",
           "summary": table, "scores": raw}
    atomic.write_text(a.experiment / "rejection.json", json.dumps(doc, indent=1))
    if thresholds is None:
        atomic.write_text(a.experiment / "thresholds.json", json.dumps({"quality": a.quality, "thresholds": used}, indent=1))
    for mc, by in table.items():
        for name, r in by.items():
            print(f"{mc:7s} {name:10s} threshold {r['threshold']:.4g}  accept own {r['accept_own']:5.1f}%  "
                  f"reject others {r['reject_others']:5.1f}%  AUC {r['auc']:.3f}  "
                  + " ".join(f"{fc} {v:.0f}%" for fc, v in r["reject"].items()))


if __name__ == "__main__":
    main()

"""Score detection variants on a scene benchmark split, beside the one-class baseline.

    python -m isa.detection.evaluate --scenes ROOT --split val --model chair=chair.isa ... \\
        [--shapes DIR] [--foreground DIR] [--rankers DIR] [--variants baseline verify refine] [--json out.json]

Every variant runs on the same frames (:func:`isa.scenes.io.read_scene_dataset`, the scene's
gravity given unless the variant says ``nogravity``) and is scored by
:func:`isa.scenes.scoring.evaluate` (box AP at IoU 0.25, 6D AP with symmetries forgiven and under
the paper's Eq. 14, z = 0.1; objects under 30% visible ignored). Variants:

- ``baseline``: today's one-class detection (:func:`isa.scenes.benchmark.detect_views`);
- ``forest``: :func:`isa.detection.multi.detect` with the forests' scores and boxes (no shapes),
  one list and NMS across categories;
- ``verify``: + verification against the training shapes (score, shape, size);
- ``refine``: + upright ICP of the best hypotheses, + 0.05 x the log of the forest's score (the
  default pipeline);
- ``turnsN``: ``refine`` also verifying each hypothesis turned by 360/N degree steps;
- ``foreground``: ``refine`` keeping the forests' leaf weights (in their model files, or from
  ``--foreground DIR``); every other variant votes without them;
- ``nogravity``: ``refine`` without the scene's gravity (floor normal, else the votes' tilt);
- ``fwW``: ``refine`` with ``W`` times the log of the forest's score added to the verified one
  (``fw0``: none);
- ``noproposals``: ``refine`` without the footprint proposals (the forests' hypotheses only);
- ``noranker``: ``refine`` without the models' rankers (the verification score ranks); every
  other variant but ``baseline`` and ``forest`` ranks with them when the models have one;
- ``set:KEY=JSON,...``: ``refine`` with those parameters (``section.key`` for a nested one,
  e.g. ``set:max_hypotheses=10,proposals.cell=0.04``);
- ``unexplainedW``: ``refine`` with ``verify.unexplained_weight`` ``W`` (observed surface inside
  a hypothesis' box that its shape does not explain costs ``W`` a cell).

``--shapes DIR`` holds ``<category>.shapes.npz`` (:func:`isa.detection.shapes.bop_shape_library`
writes them from the training renders), ``--foreground DIR`` ``<category>.foreground.npz``,
``--rankers DIR`` ``<category>.ranker.json`` (:mod:`isa.detection.ranking` fits them on
validation rooms).
"""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from isa import atomic
from isa.exceptions import DataError, InvalidValueError

if TYPE_CHECKING:
    from isa.detection.multi import DetectParams

__all__ = ["VARIANTS", "variant_params", "run_variant", "found_within", "models_from_args", "main"]

VARIANTS = ("baseline", "forest", "verify", "refine", "turns2", "turns4", "foreground", "nogravity", "noproposals",
            "noranker")


def variant_params(name: str):
    """The :class:`isa.detection.multi.DetectParams` of a variant (None for ``baseline``)."""
    from isa.detection.multi import DetectParams

    if name == "baseline":
        return None
    if name == "forest":
        return DetectParams(verify=None, refine=None)
    if name == "verify":
        return DetectParams(refine=None)
    if name.startswith("turns"):
        return DetectParams(turns=int(name[5:]))
    if name in ("refine", "foreground", "nogravity", "noranker"):
        return DetectParams()
    if name.startswith("fw"):
        return DetectParams(forest_weight=float(name[2:]))
    if name == "noproposals":
        return DetectParams(proposals=None)
    if name.startswith("set:"):  # set:key=JSON,section.key=JSON (any detection parameter, for tuning)
        return with_settings(DetectParams(), name[4:])
    if name.startswith("unexplained"):
        from isa.detection.verify import VerifyParams

        return DetectParams(verify=VerifyParams(unexplained_weight=float(name[11:])))
    raise DataError(f"unknown variant {name!r}; expected one of {', '.join(VARIANTS)} "
                    "(turnsN, fwW, unexplainedW for any N, W; set:KEY=JSON,...)")


def with_settings(params: DetectParams, spec: str) -> DetectParams:
    """``params`` with ``spec``'s settings, ``KEY=JSON,section.key=JSON,...`` (e.g.
    ``max_hypotheses=10,proposals.cell=0.04,size_steps=[0.7,1.4]``: a comma starts the next
    setting only where a ``KEY=`` follows it, so lists keep theirs)."""
    for item in re.split(r",(?=[A-Za-z_][\w.]*=)", spec):
        key, _, value = item.partition("=")
        section, _, sub = key.rpartition(".")
        try:
            v = json.loads(value)
        except json.JSONDecodeError as e:
            raise InvalidValueError(f"setting {item!r}: the value after '=' is not JSON ({e})") from None
        params = (replace(params, **{sub: v}) if not section
                  else replace(params, **{section: replace(getattr(params, section), **{sub: v})}))
    return params


def run_variant(name: str, views, models, progress: bool = True) -> tuple[list[list], list[float]]:
    """Detections (as :class:`isa.scenes.scoring.Detection`) of every view
    (:class:`isa.scenes.benchmark.View`) and the seconds per view."""
    from isa.scenes.benchmark import detect_views, detect_views_full

    if name == "baseline":
        return detect_views({m.category: m.forest for m in models}, views, progress=progress, desc=name)
    params = variant_params(name)
    # Only the ``foreground`` variant keeps the forests' leaf weights.
    use = models if name == "foreground" else [replace(m, forest=m.forest.with_leaf_weights(None)) for m in models]
    if name == "forest":
        use = [replace(m, shapes=None, ranker=None) for m in use]
    if name == "noranker":
        use = [replace(m, ranker=None) for m in use]
    if name == "nogravity":
        views = [replace(v, gravity=None) for v in views]
    return detect_views_full(use, views, params, progress, desc=name)


def found_within(ground_truth, detections, gravity, category: str, min_visib: float = 0.5, max_dist: float = 0.10,
                 max_yaw_deg: float | None = 20.0) -> tuple[int, int]:
    """Issue 17's Scan2CAD count: of the ``category`` objects at least ``min_visib`` visible, how
    many have a detection of the category in their frame whose box centre is within ``max_dist``
    metres of theirs and (unless None) whose rotation is within ``max_yaw_deg`` (both upright:
    the yaw difference); returns (found, objects)."""
    from isa.scenes.io import GroundTruth
    from isa.scenes.scoring import ground_truth_box, rotation_error_deg

    found = total = 0
    for gts, dets, Rg in zip(ground_truth, detections, gravity, strict=True):
        mine = [(d, d.box(Rg).centre) for d in dets if d.category == category]
        for g in gts:
            if not isinstance(g, GroundTruth) or g.category != category or g.visib_fract < min_visib:
                continue
            total += 1
            c = ground_truth_box(g, Rg).centre
            found += any(np.linalg.norm(dc - c) <= max_dist
                         and (max_yaw_deg is None or rotation_error_deg(d.R, g.R) <= max_yaw_deg) for d, dc in mine)
    return found, total


def models_from_args(specs, shapes: Path | None, foreground: Path | None = None, rankers: Path | None = None) -> list:
    """The models of ``--model CATEGORY=PATH`` arguments, with ``<category>.shapes.isl`` (else
    ``.shapes.npz``), ``<category>.foreground.npz`` and ``<category>.ranker.json`` from the given folders (else
    whatever lies beside each model)."""
    from isa.detection.multi import load_model

    models = []
    for item in specs:
        cat, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"--model: expected CATEGORY=PATH, got {item!r}")
        fg = foreground / f"{cat}.foreground.npz" if foreground else None
        if fg is not None and not fg.is_file():
            print(f"{cat}: no {fg.name} in {foreground}, its votes are not weighted")
            fg = None
        lib = None
        if shapes:
            lib = shapes / f"{cat}.shapes.isl"
            lib = lib if lib.is_file() else shapes / f"{cat}.shapes.npz"
        models.append(load_model(path, shapes=lib, category=cat,
                                 foreground=fg, ranker=rankers / f"{cat}.ranker.json" if rankers else None))
    return models


def _pct(v) -> float | None:
    return None if v is None or math.isnan(v) else round(100.0 * v, 1)


def main(argv: list[str] | None = None) -> None:
    from isa.scenes.benchmark import scene_views, sun_views
    from isa.scenes.scoring import evaluate

    p = argparse.ArgumentParser(prog="python -m isa.detection.evaluate", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", action="append", default=[], help="scene benchmark root (BOP; repeatable: pooled)")
    p.add_argument("--sun", help="SUN RGB-D folder instead (boxes only: the 6D columns are n/a)")
    p.add_argument("--split", default="val")
    p.add_argument("--model", action="append", required=True, metavar="CATEGORY=PATH")
    p.add_argument("--shapes", type=Path, help="folder of <category>.shapes.isl (or .npz)")
    p.add_argument("--foreground", type=Path,
                   help="folder of <category>.foreground.npz (a category without one votes unweighted)")
    p.add_argument("--rankers", type=Path, help="folder of <category>.ranker.json (default: beside each model)")
    p.add_argument("--variants", nargs="+", default=["baseline", "forest", "verify", "refine"])
    p.add_argument("--limit", type=int, default=None, help="first N frames only")
    p.add_argument("--json", type=Path, help="write the numbers here")
    a = p.parse_args(argv)
    for v in a.variants:
        variant_params(v)  # fail before any work on a misspelt variant
    models = models_from_args(a.model, a.shapes, a.foreground, a.rankers)
    cats = [m.category for m in models]
    if bool(a.scenes) == bool(a.sun):
        raise SystemExit("give one of --scenes ROOT or --sun DIR")
    frames = ([v for root in a.scenes for v in scene_views(root, a.split, a.limit)] if a.scenes
              else sun_views(a.sun)[: a.limit])
    results = {}
    where = " + ".join(f"{r}/{a.split}" for r in a.scenes) if a.scenes else a.sun
    print(f"{len(frames)} frames of {where}; AP (%) box IoU 0.25 / 6D sym / 6D Eq. 14, ms per frame")
    for v in a.variants:
        dets, secs = run_variant(v, frames, models)
        sc = evaluate([f.gt for f in frames], dets, [f.gravity for f in frames], cats)
        row = {c: {m: (None if sc.metrics[c][m] is None else _pct(sc.metrics[c][m].ap))
                   for m in ("box_0.25", "6d_sym", "6d")} for c in cats}
        results[v] = {"ap": row, "ms_per_frame": 1000 * float(np.mean(secs)), "frames": len(frames)}
        cells = " | ".join(f"{c} {row[c]['box_0.25']} / {row[c]['6d_sym']} / {row[c]['6d']}" for c in cats)
        print(f"| {v} | {cells} | {results[v]['ms_per_frame']:.0f} ms |", flush=True)
        if a.scenes:  # issue 17's Scan2CAD target, counted on any scene dataset
            grav = [f.gravity for f in frames]
            within = {c: found_within([f.gt for f in frames], dets, grav, c, max_yaw_deg=None if c == "table" else 20.0)
                      for c in cats}
            results[v]["found_10cm"] = within
            print("  at least half visible, found within 10 cm" + " (and 20 deg, but table):  "
                  + ", ".join(f"{c} {k}/{n}" for c, (k, n) in within.items()), flush=True)
    if a.json:
        doc = {"scenes": a.scenes or a.sun, "split": a.split, "models": a.model, "results": results}
        atomic.write_text(a.json, json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()

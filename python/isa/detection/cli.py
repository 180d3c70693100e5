"""3D object detection on real depth frames with category forests (paper Table 2, right): the command
line, ``python -m isa detect-real``."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Sequence

from isa.categories import CATEGORIES
from isa.detection.hypotheses import DetectionParams
from isa.detection.real import _fmt_ap, evaluate_real, load_real_frames, real_section
from isa.detection.training import train_detector

__all__ = ["main"]


def _parse_models(items: Sequence[str]) -> dict[str, str]:
    out = {}
    for it in items:
        cat, sep, path = it.partition("=")
        if not sep or not cat or not path:
            raise SystemExit(f"--model: expected CATEGORY=PATH, got {it!r}")
        out[cat] = path
    return out


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m isa detect-real", description=__doc__.split("\n\n")[0])
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
    from isa.forest.model import ForestParams
    from isa.render.dataset import procedural_objects
    from isa.report.report import Report

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

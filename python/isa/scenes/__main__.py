"""``python -m isa scenes {make,run,evaluate}`` (or ``python -m isa.scenes``): the scene benchmark from the command line.

    python -m isa scenes make --out out/scenes/procedural --source procedural --scenes 4 --views 3
    python -m isa scenes run --models chair=chair.isa,table=table.isa --scenes out/scenes/procedural \\
        --split test --sun ../shared/data/sunrgbd --out out/bench
    python -m isa scenes evaluate --detections out/bench/detections.json --out out/bench-rescored

``run`` writes ``report.md`` (tables and PNGs), ``results.json`` (schema ``isa-results/2``,
docs/results.md) and ``detections.json`` (what ``evaluate`` scores again without the models).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

from isa.exceptions import IsaError


def parse_models(text: str) -> dict[str, str]:
    """``chair=a.isa,table=b.isa`` -> {category: path}."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        cat, sep, path = item.partition("=")
        if not sep or not cat or not path:
            raise SystemExit(f"--models: expected CATEGORY=PATH[,CATEGORY=PATH...], got {item!r}")
        out[cat.strip()] = path.strip()
    if not out:
        raise SystemExit("--models: no CATEGORY=PATH given")
    return out


def _detection_params(a):
    from isa.detection.hypotheses import DetectionParams
    from isa.detection.multi import DetectParams

    cls = DetectParams if a.detector == "full" else DetectionParams
    return cls(stride=a.stride, max_hypotheses=a.hypotheses)


def _write(report, a, t0: float, title_kind: str) -> Path:
    from isa import __version__
    from isa.report.report import RESULTS_SCHEMA

    report.results.update({"schema": RESULTS_SCHEMA, "isa_version": __version__, "command": title_kind,
                           "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()
                                      if k != "func"},
                           "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
                           "seconds": time.perf_counter() - t0})
    return report.write()


def add_make_arguments(p: argparse.ArgumentParser) -> None:
    from isa.categories import CATEGORIES

    p.add_argument("--out", required=True, help="dataset root to write (BOP; resumable)")
    p.add_argument("--split", default="test", help="split folder (default test)")
    p.add_argument("--source", required=True, choices=("procedural", "modelnet-test", "modelnet-validation", "scan2cad"),
                   help="instance meshes: procedural, ModelNet10 test meshes, the last train-split meshes "
                        "(validation), or the Scan2CAD scan's views")
    p.add_argument("--modelnet", metavar="ROOT", help="ModelNet10 root (modelnet-* sources)")
    p.add_argument("--scan", metavar="DIR", help="the Scan2CAD scan folder (scan2cad source)")
    p.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    p.add_argument("--validation-instances", type=int, default=12, help="modelnet-validation: last N per category")
    p.add_argument("--validation-skip", type=int, default=0, metavar="K",
                   help="modelnet-validation: the N before the last K instead (shapes other validation rooms, "
                        "made with N <= K, do not hold: rooms to fit rankers on)")
    p.add_argument("--scenes", type=int, default=10, help="rooms (scan2cad: ignored)")
    p.add_argument("--views", type=int, default=3, help="camera views per room (scan2cad: views of the scan)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-noise", action="store_true", help="no depth sensor noise")


def cmd_make(a) -> None:
    from isa.scenes import make_scenes, sources

    if a.source == "scan2cad":
        from isa.scenes.scan2cad import make_scan2cad_scenes

        if not a.scan:
            raise SystemExit("make --source scan2cad needs --scan DIR")
        summary = make_scan2cad_scenes(a.out, a.scan, a.views, seed=a.seed, noise=not a.no_noise, split=a.split)
    else:
        if a.validation_skip and a.source != "modelnet-validation":
            raise SystemExit(f"make --validation-skip applies to --source modelnet-validation, not {a.source}")
        if a.source == "procedural":
            src = sources.procedural(a.categories, a.seed)
        elif not a.modelnet:
            raise SystemExit(f"make --source {a.source} needs --modelnet ROOT")
        elif a.source == "modelnet-test":
            src = sources.modelnet_test(a.modelnet, a.categories)
        else:
            src = sources.modelnet_validation(a.modelnet, a.categories, a.validation_instances,
                                              skip=a.validation_skip)
        summary = make_scenes(a.out, a.split, src, a.scenes, a.views, a.seed, noise=not a.no_noise)
    print(f"scenes: {a.out}/{a.split}: {summary}")


def cmd_run(a) -> None:
    from isa.report.report import Report
    from isa.scenes.benchmark import (
        dataset_views,
        load_models,
        run_datasets,
        save_detections,
    )

    t0 = time.perf_counter()
    datasets = {}
    for root in a.scenes:
        datasets[Path(root).name] = {"kind": "scenes", "source": root, "split": a.split, "limit": a.limit}
    if a.sun:
        datasets["SUN RGB-D"] = {"kind": "sun", "source": a.sun, "limit": a.limit}
    if not datasets:
        raise SystemExit("run: give --scenes ROOT (repeatable) and/or --sun DIR")
    # Models and frames are read before anything is written, so a bad argument leaves no output.
    paths = parse_models(a.models)
    forests, _ = load_models(paths)
    for d in datasets.values():
        d["views"] = dataset_views(d["kind"], d["source"], d.get("split"), d.get("limit"))
    out = Path(a.out)
    report = Report(out, a.title)
    # The detector reads each model's shape library and ranker from beside its file.
    models = paths if a.detector == "full" else forests
    stored = run_datasets(report, datasets, models, _detection_params(a), a.min_visib, a.figures, detector=a.detector)
    save_detections(out / "detections.json", stored)
    path = _write(report, a, t0, "run")
    _print_summary(report.results["scenes"])
    print(f"report: {path}")


def cmd_evaluate(a) -> None:
    from isa.report.report import Report
    from isa.scenes.benchmark import load_detections, rescore

    t0 = time.perf_counter()
    report = Report(Path(a.out), a.title)
    rescore(report, load_detections(a.detections), a.min_visib, a.figures)
    path = _write(report, a, t0, "evaluate")
    _print_summary(report.results["scenes"])
    print(f"report: {path}")


def _print_summary(scenes: dict) -> None:
    for name, d in scenes.items():
        per = d["scores"]["per_category"]
        cells = []
        for c, ms in per.items():
            vals = [("n/a" if ms[m] is None or ms[m]["ap"] is None else f"{ms[m]['ap']:.1f}") for m in ms]
            cells.append(f"{c} " + "/".join(vals))
        print(f"[{name}] AP % (" + "/".join(next(iter(per.values())).keys()) + "): " + ", ".join(cells))


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m isa scenes", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    mk = sub.add_parser("make", help="write a scene benchmark split (BOP)")
    add_make_arguments(mk)
    mk.set_defaults(func=cmd_make)

    def common(q):
        q.add_argument("--out", required=True, help="output folder (report.md, results.json, figures/)")
        q.add_argument("--min-visib", type=float, default=None,
                       help="objects less visible than this are ignored ground truth (default 0.3)")
        q.add_argument("--figures", type=int, default=3, help="frames drawn per dataset")
        q.add_argument("--title", default="isa: scene benchmark")

    run = sub.add_parser("run", help="detect with category models on scenes (and SUN RGB-D frames), score, report")
    run.add_argument("--models", required=True, metavar="CAT=PATH,...", help="category models, comma-separated")
    run.add_argument("--scenes", action="append", default=[], metavar="ROOT", help="a BOP scene root (repeatable)")
    run.add_argument("--split", default="test", help="split folder of the scene roots (default test)")
    run.add_argument("--sun", metavar="DIR", help="also score the SUN RGB-D frames under DIR (boxes only)")
    run.add_argument("--limit", type=int, default=None, help="first N frames of each dataset only")
    from isa.detection.hypotheses import DetectionParams

    run.add_argument("--stride", type=int, default=DetectionParams.stride, help="voting stride in pixels")
    run.add_argument("--hypotheses", type=int, default=DetectionParams.max_hypotheses,
                     help="hypotheses per model and frame")
    run.add_argument("--detector", choices=("baseline", "full"), default="baseline",
                     help="baseline: the one-class detection per category (default); full: isa.detection.detect "
                          "(every category in one pass, verification against <model>.shapes.isl, proposals, "
                          "refinement, NMS, <model>.ranker.json when present)")
    common(run)
    run.set_defaults(func=cmd_run)

    ev = sub.add_parser("evaluate", help="score stored detections (detections.json) again")
    ev.add_argument("--detections", required=True, help="detections.json written by run")
    common(ev)
    ev.set_defaults(func=cmd_evaluate)
    return p


def main(argv: list[str] | None = None) -> None:
    a = parser().parse_args(argv)
    try:
        a.func(a)
    except IsaError as exc:
        raise SystemExit(f"error: {exc}") from None


if __name__ == "__main__":
    main()

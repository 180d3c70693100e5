"""Whole-frame detection time: every category model on one 640x480 room frame, end to end, the
core's path (``isa.detection.detect`` -> ``isa._core.detect``) against the numpy path it
replaced (tests/detect_reference, the baseline), measured in the same run.

    python benches/bench_detect.py --model chair=chair.isa --model bed=bed.isa ... [--shapes DIR]
        [--rankers DIR] [--scenes ROOT:SPLIT] [--frames 5] [--repeats 3] [--against PYTHON_DIR]
        [--core-only]

Prints median wall times (ms) per stage (gravity, planes, votes of all categories,
verification with the size fit and NMS, refinement, total) for three pipelines (no
verification; verification and size; verification, size and refinement: the default) on each
path, and the speed-up. ``--rankers DIR`` ranks with ``<category>.ranker.json`` from there (as
the default pipeline does when models have rankers; the numpy path has no ranking stage).
Frames come from a scene benchmark folder (``isa.scenes``); without ``--scenes`` a procedural
room is made first. ``--shapes DIR`` holds ``<category>.shapes.npz``
or ``.isl`` (:mod:`isa.detection.shapes`); without it the shapes come from beside each model.
``--against DIR`` adds the core path of another checkout (e.g. ``/work/main/python`` with its
built extension) as a row: it runs in a worker process fed the same frames, each repeat of a
frame alternating between the two, so both see the same machine load; ``--core-only`` leaves the
numpy path out.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the numpy reference


def _frames(spec: str | None, n: int):
    from isa.scenes import make_scenes, read_scene_dataset
    from isa.scenes.sources import procedural

    if spec:
        root, _, split = spec.partition(":")
        return read_scene_dataset(root, split or "test")[:n]
    tmp = tempfile.mkdtemp(prefix="bench_detect_")
    make_scenes(tmp, "test", procedural(["bed", "chair", "table", "toilet"], seed=0), n_scenes=1,
                views_per_scene=n, seed=0, progress=False)
    return read_scene_dataset(tmp, "test")


def _shapes(folder: Path | None, cat: str):
    if folder is None:
        return None
    isl = folder / f"{cat}.shapes.isl"
    return isl if isl.is_file() else folder / f"{cat}.shapes.npz"


def _worker(a, pipelines) -> int:
    """``--worker``: the core path of this process's ``isa``, one line of stage seconds per
    request line ``PIPELINE FRAME``."""
    from isa.detection import detect

    models, frames = _inputs(a)
    print("ready", flush=True)
    for line in sys.stdin:
        name, _, i = line.rstrip("\n").rpartition(" ")
        f = frames[int(i)]
        t0 = time.perf_counter()
        secs = dict(detect(f.depth, f.intrinsics, models, gravity=f.gravity, params=pipelines[name]).seconds)
        secs["total"] = time.perf_counter() - t0
        print(json.dumps(secs), flush=True)
    return 0


def _inputs(a):
    from isa.detection import load_model

    models = []
    for item in a.model:
        cat, _, path = item.partition("=")
        ranker = None if a.rankers is None else a.rankers / f"{cat}.ranker.json"
        models.append(load_model(path, shapes=_shapes(a.shapes, cat), category=cat, ranker=ranker))
    return models, _frames(a.scenes, a.frames)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", action="append", required=True, metavar="CATEGORY=PATH")
    ap.add_argument("--shapes", type=Path, help="folder of <category>.shapes.isl / .npz")
    ap.add_argument("--rankers", type=Path, help="folder of <category>.ranker.json")
    ap.add_argument("--scenes", help="ROOT:SPLIT of a scene benchmark (default: one procedural room)")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--against", metavar="PYTHON_DIR", help="also time the core path of this isa package folder")
    ap.add_argument("--core-only", action="store_true", help="leave the numpy path out")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()

    from isa.detection import DetectParams, detect

    pipelines = {
        "no verification": DetectParams(verify=None, refine=None),
        "verification + size": DetectParams(refine=None),
        "verification + size + refinement": DetectParams(),
    }
    if a.worker:
        return _worker(a, pipelines)
    models, frames = _inputs(a)
    w, h = frames[0].intrinsics.width, frames[0].intrinsics.height
    paths = [] if a.core_only else [("numpy (baseline)", __import__("detect_reference.multi").multi.detect)]
    paths.append(("core", detect))
    worker = None
    if a.against:
        env = {**os.environ, "PYTHONPATH": str(Path(a.against).resolve())}
        worker = subprocess.Popen([sys.executable, *sys.argv, "--worker"], env=env, text=True,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert worker.stdout.readline().strip() == "ready", "the --against worker did not start"

        def elsewhere(name):
            def run(i):
                worker.stdin.write(f"{name} {i}\n")
                worker.stdin.flush()
                return json.loads(worker.stdout.readline())
            return run
    keys = ["gravity", "planes", "votes", "verify", "refine", "rank", "total"]
    rows = []
    for name, params in pipelines.items():
        per_path: dict[str, list[dict[str, float]]] = {}
        for i, f in enumerate(frames):
            runs: dict[str, list[dict[str, float]]] = {}
            for _ in range(a.repeats):
                here = []
                for path, run in paths:
                    t0 = time.perf_counter()
                    secs = dict(run(f.depth, f.intrinsics, models, gravity=f.gravity, params=params).seconds)
                    secs["total"] = time.perf_counter() - t0
                    here.append((path, secs))
                if worker is not None:
                    here.append((f"core at {a.against}", elsewhere(name)(i)))
                for path, secs in here:
                    secs["verify"] = secs.get("verify", 0.0) + secs.pop("nms", 0.0)  # the numpy path times NMS in it
                    runs.setdefault(path, []).append(secs)
            for path, rs in runs.items():
                per_path.setdefault(path, []).append({k: statistics.median(r.get(k, 0.0) for r in rs) for k in keys})
        for path, per_frame in per_path.items():
            rows.append((name, path, {k: 1000 * statistics.median(p[k] for p in per_frame) for k in keys}))
    if worker is not None:
        worker.stdin.close()
        worker.wait()
    print(f"{len(frames)} frame(s) {w}x{h}, {len(models)} categories ({', '.join(m.category for m in models)}), "
          f"gravity given, median of {a.repeats} runs per frame, then median over frames; ms "
          f"(load average {os.getloadavg()[0]:.1f} at the end)")
    print(f"| {'pipeline':34s} | {'path':16s} | gravity | planes | votes | verify | refine | rank | total | speed-up |")
    print("|" + "---|" * 10)
    base = {}  # the speed-up against the first row of a pipeline, or against --against's
    for name, path, r in rows:
        if path.startswith("core at") or name not in base:
            base[name] = r["total"]
    for name, path, r in rows:
        print(f"| {name:34s} | {path:16s} | {r['gravity']:7.1f} | {r['planes']:6.1f} | {r['votes']:5.1f} | {r['verify']:6.1f} "
              f"| {r['refine']:6.1f} | {r['rank']:4.1f} | {r['total']:5.1f} | {base[name] / r['total']:8.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Whole-frame detection time: every category model on one 640x480 room frame, end to end.

    python benches/bench_detect.py --model chair=chair.isa --model bed=bed.isa ... [--shapes DIR]
        [--scenes ROOT:SPLIT] [--frames 5] [--repeats 3]

Prints median wall times per step of ``isa.detection.detect`` (gravity, planes, votes of all
categories, verification, refinement, total) for: the one-class baseline of the same run
(``isa.detection.detect_frame``: planes once, each forest, boxes, per-category NMS), the new
pipeline without verification, with verification, and with verification + refinement. Frames
come from a scene benchmark folder (``isa.scenes``); without ``--scenes`` a procedural room is
made first. ``--shapes DIR`` holds ``<category>.shapes.npz`` (:mod:`isa.detection.shapes`);
without it the shapes come from ``<model>.shapes.npz`` beside each model.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", action="append", required=True, metavar="CATEGORY=PATH")
    ap.add_argument("--shapes", type=Path, help="folder of <category>.shapes.npz")
    ap.add_argument("--scenes", help="ROOT:SPLIT of a scene benchmark (default: one procedural room)")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()

    from types import SimpleNamespace

    from isa.detection import DetectionParams, DetectParams, detect, detect_frame, load_model

    models = []
    for item in a.model:
        cat, _, path = item.partition("=")
        shapes = a.shapes / f"{cat}.shapes.npz" if a.shapes else None
        models.append(load_model(path, shapes=shapes, category=cat))
    forests = {m.category: m.forest for m in models}
    frames = _frames(a.scenes, a.frames)
    w, h = frames[0].intrinsics.width, frames[0].intrinsics.height
    variants = {
        "baseline: detect_frame (one-class, per-category NMS)": None,
        "detect, no verification": DetectParams(verify=None, refine=None),
        "detect, verification": DetectParams(refine=None),
        "detect, verification + refinement": DetectParams(),
    }
    rows = []
    for name, params in variants.items():
        per_frame: list[dict[str, float]] = []
        for f in frames:
            runs = []
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                if params is None:
                    frame = SimpleNamespace(depth=f.depth, intrinsics=f.intrinsics, R_gravity=f.gravity)
                    res = detect_frame(forests, frame, DetectionParams())
                    secs = {"planes": next(iter(res.values())).seconds.get("planes", 0.0),
                            "votes": sum(d.seconds["vote"] for d in res.values())}
                else:
                    secs = dict(detect(f.depth, f.intrinsics, models, gravity=f.gravity, params=params).seconds)
                secs["total"] = time.perf_counter() - t0
                runs.append(secs)
            per_frame.append({k: statistics.median(r.get(k, 0.0) for r in runs) for k in runs[0]})
        keys = ["gravity", "planes", "votes", "verify", "refine", "total"]
        rows.append((name, {k: 1000 * statistics.median(p.get(k, 0.0) for p in per_frame) for k in keys}))
    base = rows[0][1]["total"]
    print(f"{len(frames)} frame(s) {w}x{h}, {len(models)} categories ({', '.join(forests)}), "
          f"median of {a.repeats} runs per frame, then median over frames; ms")
    print(f"| {'pipeline':55s} | gravity | planes | votes | verify | refine | total | x baseline |")
    print("|" + "---|" * 8)
    for name, r in rows:
        print(f"| {name:55s} | {r['gravity']:7.1f} | {r['planes']:6.1f} | {r['votes']:5.1f} | {r['verify']:6.1f} "
              f"| {r['refine']:6.1f} | {r['total']:5.1f} | {r['total'] / base:10.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

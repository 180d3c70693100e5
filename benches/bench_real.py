"""Real-frame inference time: one category model on SUN RGB-D frame 000001 (730x530).

    python benches/bench_real.py [--model chair.isa] [--repeats 5] [--stride 4]

Prints a table of median wall times per step of ``isa.detection.detect`` (plane removal, voting,
boxes + NMS, total) on the real frame, against the baseline of the same run: voting on a 640x480
synthetic render of a procedural chair (the synthetic experiment's per-frame work). Without
``--model`` a small procedural chair forest is trained first (4 trees, depth 14: the demo's size;
voting time grows with trees and depth). Skips, saying why, when ../shared/data is absent.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))


def _median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, help="a category model with its box in the metadata (default: train a small chair forest)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--stride", type=int, default=4, help="voting stride in pixels")
    a = ap.parse_args()
    proc = SHARED / "sunrgbd" / "sunrgbd_trainval"
    if not proc.is_dir():
        print(f"SKIP bench_real: real data not found at {proc} (set ISA_SHARED_DATA or check out ../shared)")
        return 0

    from isa import detection as D
    from isa.camera import KINECT_V1
    from isa.data.sunrgbd import read_processed
    from isa.forest.model import Forest, ForestParams
    from isa.pipeline import predict
    from isa.render.dataset import default_test_views, procedural_objects
    from isa.render.renderer import DepthRenderer

    frame = read_processed(proc, "000001")
    t0 = time.perf_counter()
    if a.model:
        forest = Forest.load(a.model)
        what = str(a.model)
    else:
        forest, _ = D.train_detector("chair", procedural_objects("chair", 4, seed=1), views=20, stride=6,
                                            use_ground_truth=True,
                                            forest_params=ForestParams(n_trees=4, max_depth=14, n_candidates=40))
        what = f"procedural chair forest trained here in {time.perf_counter() - t0:.0f} s"
    box = D.model_box(forest, what)
    # Baseline: a 640x480 synthetic test render (an unseen procedural chair).
    obj = procedural_objects("chair", 1, seed=99)[0]
    R, t = default_test_views(obj, 1, seed=0)[0]
    with DepthRenderer(KINECT_V1) as r:
        synth, _ = r.render(obj.mesh, R, t)

    p = D.DetectionParams(stride=a.stride)
    h, w = frame.depth.shape
    planes = D.remove_planes(frame.depth, frame.intrinsics, frame.R_gravity, p.planes)
    kw = dict(stride=a.stride, max_hypotheses=p.max_hypotheses)
    rows = [
        ("vote, synthetic 640x480 (baseline)", _median_s(lambda: predict(forest, synth, KINECT_V1, **kw), a.repeats)),
        ("floor removal only",
         _median_s(lambda: D.remove_planes(frame.depth, frame.intrinsics, frame.R_gravity, p.planes, walls=False), a.repeats)),
        ("floor + wall removal", _median_s(lambda: D.remove_planes(frame.depth, frame.intrinsics, frame.R_gravity, p.planes), a.repeats)),
        ("vote, raw real depth", _median_s(lambda: predict(forest, frame.depth, frame.intrinsics, **kw), a.repeats)),
        ("vote, planes removed", _median_s(lambda: predict(forest, planes.depth, frame.intrinsics, **kw), a.repeats)),
        ("boxes + NMS (planes given)", None),
        ("detect total (planes + vote + boxes)",
         _median_s(lambda: D.detect_category(forest, frame.depth, frame.intrinsics, frame.R_gravity, box, p), a.repeats)),
    ]
    det = D.detect_category(forest, frame.depth, frame.intrinsics, frame.R_gravity, box, p, planes=planes)
    rows[5] = (rows[5][0], det.seconds["boxes"])
    base = rows[0][1]
    print(f"real frame {frame.name}: {w}x{h}, {int((frame.depth > 0).sum()):,} valid pixels "
          f"({int((planes.depth > 0).sum()):,} after plane removal); stride {a.stride}; model: {what} "
          f"({forest.n_trees} trees, depth {max(forest.depths)}); median of {a.repeats}; {os.cpu_count()} cpus")
    print(f"| {'step':<38} | {'ms':>8} | {'x baseline':>10} |")
    print(f"|{'-' * 40}|{'-' * 10}|{'-' * 12}|")
    for name, s in rows:
        print(f"| {name:<38} | {1000 * s:8.1f} | {s / base:10.2f} |")
    print(f"{det.hypotheses} hypotheses, {len(det.boxes)} boxes after the gravity / floor checks and NMS "
          f"(rejected: {det.rejected})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Peak memory and time of building a training set from frames held in memory against frames read
from disk on use (``pipeline.load_frames(..., lazy=True)``), in one run.

    python benches/bench_annotate.py [--objects 8] [--views 89] [--stride 8]

Renders ``objects`` procedural chairs x ``views`` 640x480 views into a temporary BOP folder, then
builds the annotated parts twice, each in a fresh process so that its peak resident memory is its
own: once from the whole split loaded (the baseline) and once from the lazy sequence, with the
training views also mirrored (as ``--mirror`` does). Prints a table of peak RSS, wall time and the
ratios; both must give the same parts. Needs no data.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def _objects(n: int):
    from isa import pipeline
    from isa.render.dataset import procedural_objects

    return pipeline.prepare_category("chair", procedural_objects("chair", n, seed=1))


def worker(root: Path, n: int, stride: int, lazy: bool) -> dict:
    """Build the (mirrored) training set of ``root``; report peak RSS (MB), seconds and a digest."""
    from isa import pipeline
    from isa.privileged.mirror import find_mirror, with_mirrored

    train = _objects(n)
    mirrors = {o.obj_id: find_mirror(o.mesh) for o in train.objects}
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    frames = with_mirrored(pipeline.load_frames(root, "train", lazy=lazy), mirrors)
    ts = pipeline.training_set(frames, train.skeletons, stride=stride)
    secs = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"peak_mb": peak, "before_mb": base, "seconds": secs, "frames": len(frames), "parts": len(ts),
            "digest": float(ts.offsets.astype("float64").sum() + ts.parts.sum())}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", type=int, default=8)
    ap.add_argument("--views", type=int, default=89)
    ap.add_argument("--stride", type=int, default=8)
    ap.add_argument("--worker", choices=["eager", "lazy"], help=argparse.SUPPRESS)
    ap.add_argument("--root", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        print(json.dumps(worker(a.root, a.objects, a.stride, a.worker == "lazy")))
        return
    from isa.render.dataset import render_dataset

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        render_dataset(root, _objects(a.objects).objects, split="train", n_views=a.views)
        rows = {}
        for mode in ("eager", "lazy"):
            cmd = [sys.executable, __file__, "--worker", mode, "--root", str(root), "--objects", str(a.objects),
                   "--stride", str(a.stride)]
            rows[mode] = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.splitlines()[-1])
    e, lz = rows["eager"], rows["lazy"]
    if e["parts"] != lz["parts"] or e["digest"] != lz["digest"]:
        sys.exit(f"lazy and eager training sets differ: {e['parts']} vs {lz['parts']} parts")
    print(f"{a.objects} chairs x {a.views} views, mirrored: {e['frames']} frames of 640x480, "
          f"{e['parts']:,} parts (stride {a.stride})")
    print("| frames | peak RSS (MB) | over start (MB) | seconds |")
    print("|---|---|---|---|")
    for mode, r in rows.items():
        print(f"| {mode} | {r['peak_mb']:.0f} | {r['peak_mb'] - r['before_mb']:.0f} | {r['seconds']:.1f} |")
    print(f"| lazy / eager | {lz['peak_mb'] / e['peak_mb']:.2f} | "
          f"{(lz['peak_mb'] - lz['before_mb']) / max(e['peak_mb'] - e['before_mb'], 1):.2f} | "
          f"{lz['seconds'] / e['seconds']:.2f} |")


if __name__ == "__main__":
    main()

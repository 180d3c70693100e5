"""Memory of training from a shard folder, tree by tree (issue 18): resident memory after the
folder is opened and the targets built, and the peak while each tree grows, per training part.

``isa._core.ShardTrainer`` on ``SHARDS`` (a folder with its ``manifest.json``; e.g. the first
shards of a larger set, linked into a folder of their own and listed with
``isa._core.write_shard_manifest``), then ``fit_tree(t)`` for ``t < --trees``, each tree's bytes
hashed, so two builds of the core can be compared on real data: same hashes, same trees. Peak
RSS is the process's high-water mark (``VmHWM``); run it under ``/usr/bin/time -v`` for the
same figure from outside.

Usage::

    python benches/bench_shard_memory.py SHARDS [--trees 1] [--depth 20] [--candidates 100]
        [--max-offset 700]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path


def status() -> dict[str, float]:
    """VmRSS and VmHWM of this process, MiB."""
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0]) / 1024
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("shards", type=Path)
    ap.add_argument("--trees", type=int, default=1)
    ap.add_argument("--depth", type=int, default=20)
    ap.add_argument("--candidates", type=int, default=100)
    ap.add_argument("--max-offset", type=float, default=700.0)
    ap.add_argument("--quality", default="Q1+Q2+Q3")
    a = ap.parse_args()
    from isa import _core

    shards = json.loads((a.shards / "manifest.json").read_text())["shards"]
    parts = sum(s["parts"] for s in shards)
    pixels = sum(s["pixels"] for s in shards)
    print(f"{parts} parts, {sum(s['images'] for s in shards)} crops, {pixels} pixels "
          f"({2 * pixels / parts:.1f} bytes of depth a part as stored)")
    t0 = time.time()
    trainer = _core.ShardTrainer(str(a.shards), n_trees=a.trees, max_depth=a.depth, n_candidates=a.candidates,
                                 quality=a.quality, max_offset=a.max_offset, seed=0)
    s = status()
    print(f"open + prepare: {time.time() - t0:.1f} s, RSS {s['VmRSS']:.0f} MiB "
          f"({s['VmRSS'] * 2**20 / parts:.0f} bytes a part), peak so far {s['VmHWM']:.0f} MiB")
    for t in range(a.trees):
        t0 = time.time()
        digest = hashlib.sha256(trainer.fit_tree(t)).hexdigest()[:16]
        s = status()
        print(f"tree {t}: {time.time() - t0:.1f} s, sha256 {digest}, peak RSS so far {s['VmHWM']:.0f} MiB "
              f"({s['VmHWM'] * 2**20 / parts:.0f} bytes a part)")


if __name__ == "__main__":
    main()

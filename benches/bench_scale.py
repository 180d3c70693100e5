"""Training sets larger than memory and trees on a Dask cluster (issue 18), in one run.

Synthetic parts (said so in the table): instances of 96 x 96 depth crops holding a disk of
depth, parts every 4 pixels on it (~310 a crop, ~30 crop pixels a part, as rendered views give),
SSC offsets, rotations and the paper's privileged targets (18 link angles, 19 nodes: 75 wide
columns, 300 bytes a part), one shard per instance of 89 crops.

* peak RSS per training part, for each size in ``--parts`` (default 1M and 4M): ``in-memory``
  is ``Forest.fit`` on the NumPy arrays (what ``isa.pipeline.train_forest`` does; the arrays are
  built in the same process first), ``sharded`` is ``Forest.fit_shards`` on the shard folder
  (written beforehand by another process). Each in a fresh subprocess; ``B/part`` is its peak
  RSS over the parts, ``above start`` the same less the RSS of the interpreter with isa
  imported (measured in that subprocess before any data).
* wall time of the same forest's trees on a ``LocalCluster`` of 1 and of 2 single-threaded
  workers (``isa.cluster.fit_forest``, one task per tree), on the smallest size, with the
  one-process ``Forest.fit_shards`` (all cores) as baseline; all three give the same bytes.
  Each worker opens the shards and builds the targets once (``prepare``, timed alone first), so
  on W free cores the wall time is about ``prepare + ceil(trees / W) * tree``.

Usage::

    python benches/bench_scale.py [--parts 1000000 4000000] [--trees 4] [--depth 10]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

CROP, RADIUS, STRIDE, VIEWS = 96, 40, 4, 89
N_LINKS, N_NODES = 18, 19


def instance(seed: int, n_images: int):
    """One synthetic instance's arrays (the TrainingSet fields the forest reads)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:CROP, :CROP]
    disk = (yy - CROP / 2) ** 2 + (xx - CROP / 2) ** 2 < RADIUS**2
    images, parts = [], []
    for i in range(n_images):
        d = np.where(disk, rng.integers(900, 1400) + (xx * rng.normal(0, 2)).astype(np.int64), 0).astype(np.uint16)
        images.append(d)
        v, u = np.nonzero(d[::STRIDE, ::STRIDE])
        parts.append(np.stack([np.full(len(u), i), u * STRIDE, v * STRIDE], 1))
    p = np.concatenate(parts).astype(np.int32)
    n = len(p)
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    offsets = f32(np.stack([(CROP / 2 - p[:, 1]) * 0.01, (CROP / 2 - p[:, 2]) * 0.01, rng.normal(0, 0.02, n)], 1))
    q = np.concatenate([np.ones((n, 1)), rng.normal(0, 0.3, (n, 3))], 1)
    rot = f32(q / np.linalg.norm(q, axis=1, keepdims=True))
    links = f32(rng.uniform(-np.pi, np.pi, (n, N_LINKS)))
    nodes = f32(rng.normal(0, 20, (n, 3 * N_NODES)) + p[:, 1:2])
    return images, p, offsets, rot, links, nodes


def n_instances(parts: int) -> int:
    per = len(instance(0, 1)[1]) * VIEWS
    return max(1, round(parts / per))


def params(trees: int, depth: int) -> dict:
    return {"n_trees": trees, "max_depth": depth, "n_candidates": 30, "quality": "Q1+Q2+Q3", "seed": 7}


def rss_now() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


# -- subprocess bodies ----------------------------------------------------------------------
def child_write(folder: str, k: int) -> None:
    from isa import _core

    names = []
    for s in range(k):
        images, p, off, rot, la, no = instance(s, VIEWS)
        name = f"{s:06d}.isat"
        _core.TrainSet(images, p, off, rot, la, no).write(os.path.join(folder, name))
        names.append(name)
    _core.write_shard_manifest(folder, names)


def child_fit(mode: str, folder: str, k: int, prm: dict) -> None:
    from isa import _core

    start = rss_now()
    t0 = time.perf_counter()
    f = _core.Forest(**prm)
    if mode == "sharded":
        f.fit_shards(folder)
        n = json.load(open(os.path.join(folder, _core.SHARD_MANIFEST)))
        n = sum(s["parts"] for s in n["shards"])
    else:
        arrays = [instance(s, VIEWS) for s in range(k)]
        first = np.cumsum([0] + [len(a[0]) for a in arrays])[:-1]
        images = [im for a in arrays for im in a[0]]
        parts = np.concatenate([a[1] + np.array([f0, 0, 0], np.int32) for a, f0 in zip(arrays, first)])
        cat = [np.ascontiguousarray(np.concatenate([a[j] for a in arrays])) for j in range(2, 6)]
        del arrays
        n = len(parts)
        f.fit(_core.TrainSet(images, parts, *cat))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"parts": n, "peak": peak, "start": start, "seconds": time.perf_counter() - t0,
                      "bytes": len(f.to_bytes())}))


def run_child(*args: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", *args], check=True, capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    return json.loads(lines[-1]) if lines else {}


def cluster_times(folder: str, prm: dict) -> list[tuple[str, float, bytes]]:
    from isa import _core, cluster
    from isa.forest import Forest, ForestParams

    fp = ForestParams(**prm)
    t0 = time.perf_counter()
    trainer = _core.ShardTrainer(folder, n_threads=1, **prm)
    t1 = time.perf_counter()
    trainer.fit_tree(0)
    t2 = time.perf_counter()
    del trainer
    print(f"  one task, 1 thread: open + prepare the shards {t1 - t0:.1f} s (once per worker), one tree {t2 - t1:.1f} s")
    rows = []
    t0 = time.perf_counter()
    ref = Forest(fp).fit_shards(folder).to_bytes()
    rows.append(("1 process, all cores (Forest.fit_shards)", time.perf_counter() - t0, ref))
    for w in (1, 2):
        with cluster.connect(workers=w) as client:
            client.run(lambda: None)  # workers up before the clock starts
            t0 = time.perf_counter()
            got = cluster.fit_forest(client, folder, fp, progress=False, n_threads=1).to_bytes()
            rows.append((f"LocalCluster, {w} worker(s) x 1 thread", time.perf_counter() - t0, got))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", type=int, nargs="+", default=[1_000_000, 4_000_000])
    ap.add_argument("--trees", type=int, default=4)
    ap.add_argument("--depth", type=int, default=10)
    ap.add_argument("--tmp", default=None, help="folder for the shards (default: the system's temporary folder)")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        mode, folder, k, prm = a.child[0], a.child[1], int(a.child[2]), json.loads(a.child[3]) if len(a.child) > 3 else {}
        child_write(folder, k) if mode == "write" else child_fit(mode, folder, k, prm)
        return
    prm = params(a.trees, a.depth)
    print(f"synthetic parts (bench docstring); forest {json.dumps(prm)}; {os.cpu_count()} cores")
    print(f"{'parts':>10} {'mode':>10} {'peak RSS MB':>12} {'B/part':>8} {'above start':>12} {'fit s':>7}")
    first_folder = None
    base = tempfile.mkdtemp(prefix="isa-bench-scale-", dir=a.tmp)
    try:
        for target in a.parts:
            k = n_instances(target)
            folder = os.path.join(base, f"s{target}")
            os.makedirs(folder)
            run_child("write", folder, str(k))
            first_folder = first_folder or folder
            sizes = set()
            for mode in ("in-memory", "sharded"):
                r = run_child(mode, folder, str(k), json.dumps(prm))
                sizes.add(r["bytes"])
                print(f"{r['parts']:>10} {mode:>10} {r['peak'] / 2**20:>12.0f} {r['peak'] / r['parts']:>8.0f} "
                      f"{(r['peak'] - r['start']) / r['parts']:>12.0f} {r['seconds']:>7.1f}", flush=True)
        print(f"\ntrees on {n_instances(a.parts[0]) * len(instance(0, 1)[1]) * VIEWS} parts ({a.trees} trees):")
        rows = cluster_times(first_folder, prm)
        for label, s, b in rows:
            print(f"  {label:<42} {s:7.1f} s  x{rows[1][1] / s:4.2f} vs 1 worker  same bytes: {b == rows[0][2]}")
    finally:
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()

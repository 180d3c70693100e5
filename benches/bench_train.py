"""Split search and training throughput: the Rust core vs a careful NumPy reference vs
scikit-learn's ExtraTreesRegressor, on the same features and targets, in one run.

Default run (about a minute): one node holding N parts (default 100k), C = 100 candidate
features with 16 thresholds each, targets = SSC offsets (3), rotations (4), 18 link angles and
11 nodes (33 node offsets), i.e. the 76-dimensional regression target of the paper's chair
forest. It times

* ``rust``: ``isa._testing.split_search`` (the forest's own split search), for Q1 and for
  Q1+Q2+Q3 with the full 36 + 33 privileged dimensions and with ``reduce_dims`` components;
* ``numpy``: the same search written carefully in NumPy, the faster of two strategies: (a)
  per-part statistics precomputed once, bins by ``searchsorted``, per-bin sums of a batch of
  candidates with one BLAS product, prefix sums over the 17 bins, batched ``slogdet``; (b) parts
  sorted by bin and one ``X_b^T X_b`` BLAS product per bin and block; its thresholds come from another random stream,
  so its best gain is close to, not equal to, Rust's;
* ``sklearn``: ``ExtraTreesRegressor(n_estimators=1, max_depth=1, max_features=C)`` fitting
  the same features and the 76-dim (or 7-dim) targets: one root split search (ExtraTrees draws
  one threshold per feature, with a cheap MSE criterion).

Throughput is part x candidate evaluations per second of wall time; ratios are Rust / other
(``rust`` uses both cores, ``rust/1t`` one thread, each the best of 3 calls after an untimed
warm-up call; the NumPy row is the best of its 2-4 runs and its label names the strategy and
BLAS threads).

``--paper-scale`` trains the full forest instead: 10 trees, depth 20, 100 candidates per node,
Q1+Q2+Q3, on ~1M parts of ~2,500 synthetic depth crops, reporting wall time and peak memory
(of a fresh subprocess), then fits ExtraTreesRegressor(n_estimators=10, max_depth=20,
max_features=100) on the same parts with 100 precomputed features and the 76-dim targets
(``--skip-sklearn`` to leave that out: it takes several minutes).

Usage::

    python benches/bench_train.py [--parts 100000] [--candidates 100] [--reduce-dims 4]
    python benches/bench_train.py --paper-scale [--parts 1000000] [--skip-sklearn]
    python benches/bench_train.py --reduction-effect
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from isa import _core
from isa._core import _testing

N_LINKS, N_NODES, K = 18, 11, 16


# ------------------------------------------------------------------ synthetic data ----------
_SK = np.random.default_rng(12345)
#: A few instance skeletons of N_NODES nodes (object frame, metres) and N_LINKS links.
SKELETONS = [_SK.normal(0.0, 0.3, (N_NODES, 3)) for _ in range(8)]
LINKS = np.array([(i, i + 1) for i in range(N_NODES - 1)]
                 + [tuple(_SK.choice(N_NODES, 2, replace=False)) for _ in range(N_LINKS - N_NODES + 1)])


def quat_to_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def synthetic_crops(n_images: int, rng: np.random.Generator, f: float = 525.0):
    """Foreground-only depth crops of box-assembly "objects" (uint16 mm) with per-image views,
    and per-part targets following the data contract (offsets to an object centre, the view's
    rotation, link angles and node positions of an instance skeleton projected in this view)."""
    images, meta = [], []
    for _ in range(n_images):
        h, w = rng.integers(70, 110, 2)
        img = np.zeros((h, w), np.uint16)
        base = rng.uniform(1500, 3000)
        for _ in range(rng.integers(3, 7)):
            y0, x0 = rng.integers(0, h - 10), rng.integers(0, w - 10)
            y1, x1 = y0 + rng.integers(8, h // 2 + 10), x0 + rng.integers(8, w // 2 + 10)
            yy, xx = np.mgrid[y0:min(y1, h), x0:min(x1, w)]
            d = base + rng.uniform(-200, 200) + rng.uniform(-3, 3) * (yy - y0) + rng.uniform(-3, 3) * (xx - x0)
            cur = img[y0:y1, x0:x1]
            img[y0:y1, x0:x1] = np.where((cur == 0) | (d < cur), d, cur).astype(np.uint16)
        # Skeleton targets as the data pipeline makes them: one of a few instance skeletons
        # (object frame, metres) seen from this view, projected with a pinhole camera.
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        skel = SKELETONS[rng.integers(len(SKELETONS))]
        cam = skel @ quat_to_matrix(q).T + [0.0, 0.0, base / 1000]
        nodes = np.stack([f * cam[:, 0] / cam[:, 2] + w / 2, f * cam[:, 1] / cam[:, 2] + h / 2, cam[:, 2]], 1)
        dv = nodes[LINKS[:, 1]] - nodes[LINKS[:, 0]]
        links = np.arctan2(dv[:, 1], dv[:, 0])
        images.append(img)
        meta.append((q, nodes, links, (w / 2, h / 2, base / 1000 + 0.2)))
    return images, meta


def make_parts(n_parts: int, rng: np.random.Generator, per_image: int = 400):
    """Crops until ``n_parts`` foreground parts (stride 2, at most ``per_image`` per crop)."""
    images, meta, chunks, total = [], [], [], 0
    while total < n_parts:
        im, me = synthetic_crops(64, rng)
        p = _core.sample_parts(im, stride=2, max_per_image=per_image, seed=len(images))
        p[:, 0] += len(images)
        images += im
        meta += me
        chunks.append(p)
        total += len(p)
    parts = np.concatenate(chunks)[:n_parts]
    keep = int(parts[-1, 0]) + 1
    return images[:keep], meta[:keep], np.ascontiguousarray(parts)


def targets_for(parts: np.ndarray, images, meta):
    n = len(parts)
    off = np.empty((n, 3), np.float32)
    rot = np.empty((n, 4), np.float32)
    la = np.empty((n, N_LINKS), np.float32)
    no = np.empty((n, 3 * N_NODES), np.float32)
    bounds = np.searchsorted(parts[:, 0], np.arange(len(meta) + 1))  # parts are image-sorted
    for i, (q, nodes, links, c) in enumerate(meta):
        sel = slice(bounds[i], bounds[i + 1])
        p = parts[sel]
        z = images[i][p[:, 2], p[:, 1]].astype(np.float64) / 1000
        off[sel] = np.stack([(c[0] - p[:, 1]) * z / 525, (c[1] - p[:, 2]) * z / 525, c[2] - z], 1)
        rot[sel] = q
        la[sel] = links
        d = np.stack([nodes[None, :, 0] - p[:, 1:2], nodes[None, :, 1] - p[:, 2:3], nodes[None, :, 2] - z[:, None]], 2)
        no[sel] = d.reshape(len(p), -1)
    return off, rot, la, no


def sklearn_targets(off, rot, la, no):
    """The 76-dim regression target: offsets 3, quaternion 4, (cos, sin) of 18 links, 33 node offsets."""
    return np.concatenate([off, rot, np.cos(la), np.sin(la), no], 1).astype(np.float32)


def random_features(rng, n_cand, max_offset=150.0):
    return (rng.uniform(-max_offset, max_offset, (n_cand, 2)).astype(np.float32),
            rng.uniform(-max_offset, max_offset, (n_cand, 2)).astype(np.float32))


# ------------------------------------------------------------------ NumPy reference ---------
def block_dims(dims):
    return list(dims)


def numpy_split_search(features, targets, dims, reg=1e-4, seed=0, batch=8, dtype=np.float32):
    """Best (gain, candidate, threshold) over all candidates x 16 thresholds.

    ``targets`` are the criterion's target vectors (``_testing.criterion_targets``), ``dims`` the
    block sizes [3, 6, (links), (nodes)]; Q1 = logaddexp of the first two blocks' log-dets.
    Per-part statistics ``z = [1, x, upper(x x^T) per block]`` are precomputed once; per batch of
    candidates one BLAS product ``onehot(bins) @ z`` gives the per-bin sums (in ``dtype``:
    float32 doubles BLAS speed, in NumPy's favour), prefix sums over bins give every left child,
    and all thresholds of the batch go through one batched ``slogdet`` per block.
    """
    n, c = features.shape
    x = targets.astype(np.float64)
    x = x - x.mean(0)
    starts = np.cumsum([0] + dims[:-1])
    cols = [np.ones((n, 1)), x]
    tri_idx = []
    for s, d in zip(starts, dims):
        iu = np.triu_indices(d)
        xb = x[:, s:s + d]
        cols.append(xb[:, iu[0]] * xb[:, iu[1]])
        tri_idx.append(iu)
    z = np.concatenate(cols, 1)
    zt = z.astype(dtype)
    dim = x.shape[1]
    rng = np.random.default_rng(seed)

    def entropies(stats):  # (T, m) -> (T,) summed entropies
        cnt = stats[:, 0]
        mean = stats[:, 1:1 + dim] / cnt[:, None]
        off = 1 + dim
        lds = []
        for s, d, iu in zip(starts, dims, tri_idx):
            k = len(iu[0])
            s2 = np.empty((len(stats), d, d))
            s2[:, iu[0], iu[1]] = stats[:, off:off + k] / cnt[:, None]
            s2[:, iu[1], iu[0]] = s2[:, iu[0], iu[1]]
            off += k
            mb = mean[:, s:s + d]
            lds.append(np.linalg.slogdet(s2 - mb[:, :, None] * mb[:, None, :] + reg * np.eye(d))[1])
        return np.logaddexp(lds[0], lds[1]) + sum(lds[2:])

    parent = z.sum(0)
    hp = entropies(parent[None])[0]
    best = (-np.inf, -1, 0.0)
    bins_range = np.arange(K + 1)[:, None]
    for c0 in range(0, c, batch):
        cs = np.arange(c0, min(c0 + batch, c))
        thr = np.sort(features[rng.integers(0, n, (len(cs), K)), cs[:, None]], axis=1)  # (B, K)
        onehot = np.empty((len(cs) * (K + 1), n), dtype)
        for j, ci in enumerate(cs):
            bins = np.searchsorted(thr[j], features[:, ci], side="right")
            onehot[j * (K + 1):(j + 1) * (K + 1)] = bins[None, :] == bins_range
        per_bin = (onehot @ zt).astype(np.float64).reshape(len(cs), K + 1, -1)
        left = np.cumsum(per_bin, 1)[:, :K].reshape(len(cs) * K, -1)
        right = parent[None] - left
        ok = (left[:, 0] >= 1) & (right[:, 0] >= 1)
        if not ok.any():
            continue
        g = np.full(len(left), -np.inf)
        g[ok] = hp - left[ok, 0] / n * entropies(left[ok]) - right[ok, 0] / n * entropies(right[ok])
        k = int(np.argmax(g))
        if g[k] > best[0]:
            best = (float(g[k]), int(cs[k // K]), float(thr[k // K, k % K]))
    return best


def numpy_split_search_sorted(features, targets, dims, reg=1e-4, seed=0):
    """The same search, second NumPy strategy (better for wide targets): per candidate, sort the
    parts by bin (``argsort`` of the bin index), then per bin one small BLAS product
    ``X_b^T X_b`` per block, i.e. n * sum(d^2) multiply-adds per candidate without one-hot
    overhead; prefix sums over bins and batched ``slogdet`` as above."""
    n, c = features.shape
    x = targets.astype(np.float64)
    x = x - x.mean(0)
    starts = [int(v) for v in np.cumsum([0] + dims[:-1])]
    rng = np.random.default_rng(seed)
    xb = [np.ascontiguousarray(x[:, s:s + d]) for s, d in zip(starts, dims)]
    p1 = x.sum(0)
    p2 = [b.T @ b for b in xb]

    def entropies(cnt, s1, s2s):  # cnt (T,), s1 (T, D), s2s list of (T, d, d)
        mean = s1 / cnt[:, None]
        lds = []
        for s, d, s2 in zip(starts, dims, s2s):
            mb = mean[:, s:s + d]
            lds.append(np.linalg.slogdet(s2 / cnt[:, None, None] - mb[:, :, None] * mb[:, None, :] + reg * np.eye(d))[1])
        return np.logaddexp(lds[0], lds[1]) + sum(lds[2:])

    hp = entropies(np.array([float(n)]), p1[None], [q[None] for q in p2])[0]
    best = (-np.inf, -1, 0.0)
    for ci in range(c):
        f = features[:, ci]
        thr = np.sort(f[rng.integers(0, n, K)])
        bins = np.searchsorted(thr, f, side="right")
        order = np.argsort(bins, kind="stable")
        counts = np.bincount(bins, minlength=K + 1)
        edges = np.concatenate([[0], np.cumsum(counts)])
        s1 = np.zeros((K + 1, x.shape[1]))
        s2 = []
        for bi, (s, d) in enumerate(zip(starts, dims)):
            xs = xb[bi][order]  # contiguous block rows in bin order: BLAS-friendly segments
            blk = np.zeros((K + 1, d, d))
            for b in range(K + 1):
                if counts[b]:
                    seg = xs[edges[b]:edges[b + 1]]
                    blk[b] = seg.T @ seg
                    s1[b, s:s + d] = seg.sum(0)
            s2.append(np.cumsum(blk, 0)[:K])
        cl = np.cumsum(counts)[:K].astype(float)
        l1 = np.cumsum(s1, 0)[:K]
        ok = (cl >= 1) & (cl <= n - 1)
        if not ok.any():
            continue
        hl = entropies(cl[ok], l1[ok], [q[ok] for q in s2])
        hr = entropies(n - cl[ok], p1 - l1[ok], [p[None] - q[ok] for p, q in zip(p2, s2)])
        g = hp - cl[ok] / n * hl - (n - cl[ok]) / n * hr
        k = int(np.argmax(g))
        if g[k] > best[0]:
            best = (float(g[k]), ci, float(thr[ok][k]))
    return best


# ------------------------------------------------------------------ runs -------------------
def timed(fn, *a, **kw):
    t0 = time.perf_counter()
    out = fn(*a, **kw)
    return time.perf_counter() - t0, out


def bench_split(args):
    rng = np.random.default_rng(args.seed)
    images, meta, parts = make_parts(args.parts, rng)
    off, rot, la, no = targets_for(parts, images, meta)
    u, v = random_features(rng, args.candidates)
    feats = _core.depth_features(images, parts, u, v)
    n, c = feats.shape
    evals = n * c
    print(f"split search: {n} parts x {c} candidates x {K} thresholds, {os.cpu_count()} cores\n")
    rows = []
    configs = [("Q1", None, None, 0), ("Q1+Q2+Q3 full", la, no, 0), (f"Q1+Q2+Q3 reduce_dims={args.reduce_dims}", la, no, args.reduce_dims)]
    for name, a, s, rd in configs:
        q = "Q1" if a is None else "Q1+Q2+Q3"
        # Rust: one untimed warm-up call (thread pool start, first touch of the allocator's
        # pages), then the best of 3 calls (the NumPy row is the best of its 2-4 runs).
        def rust(**kw):
            runs = [_testing.split_search(feats, (off, rot, a, s), quality=q, n_thresholds=K, reduce_dims=rd, seed=1, **kw)
                    for _ in range(4)][1:]
            return min(runs, key=lambda x: x["seconds"])
        r = rust()
        t_rust = r["seconds"]
        r1 = rust(n_threads=1)
        tg, dims = _testing.criterion_targets((off, rot, a, s), reduce_dims=rd)
        # The faster of the two NumPy strategies (one-hot GEMM is hopeless for full a, s), with
        # the faster BLAS thread count (a second OpenBLAS thread busy-waits: on a loaded 2-core
        # machine it made the tall-skinny products up to 10x slower).
        best_np = None
        for blas_threads in (1, 2):
            with threadpool_limits(blas_threads):
                cands = [("sorted", numpy_split_search_sorted)]
                if rd or a is None:
                    cands.append(("one-hot", numpy_split_search))
                for how, fn in cands:
                    t_np, (g_np, _, _) = timed(fn, feats, tg, dims, seed=1)
                    if best_np is None or t_np < best_np[0]:
                        best_np = (t_np, g_np, f"numpy:{how}/{blas_threads}t")
        rows.append((name, "rust", t_rust, evals / t_rust, r["gain"]))
        rows.append((name, "rust/1t", r1["seconds"], evals / r1["seconds"], r1["gain"]))
        rows.append((name, best_np[2], best_np[0], evals / best_np[0], best_np[1]))
    from sklearn.ensemble import ExtraTreesRegressor

    for name, y in [("sklearn 76-dim", sklearn_targets(off, rot, la, no)), ("sklearn 7-dim", np.concatenate([off, rot], 1))]:
        et = ExtraTreesRegressor(n_estimators=1, max_depth=1, max_features=c, bootstrap=False, random_state=0, n_jobs=-1)
        t_sk, _ = timed(et.fit, feats, y)
        rows.append((name, "sklearn", t_sk, evals / t_sk, float("nan")))
    print(f"{'search':34s} {'impl':14s} {'seconds':>9s} {'M evals/s':>10s} {'best gain':>10s}")
    for name, impl, t, rate, g in rows:
        print(f"{name:34s} {impl:14s} {t:9.3f} {rate / 1e6:10.2f} {g:10.4f}")
    print("\nratios (Rust throughput / other):")
    rust = {r[0]: r[3] for r in rows if r[1] == "rust"}
    for name, impl, _, rate, _ in rows:
        if impl.startswith("numpy"):
            r1 = next(r[3] for r in rows if r[0] == name and r[1] == "rust/1t")
            print(f"  {name:34s} rust / numpy   = {rust[name] / rate:6.1f}x   (rust 1 thread / numpy: {r1 / rate:5.1f}x)")
    full = rust["Q1+Q2+Q3 full"]
    red = rust[f"Q1+Q2+Q3 reduce_dims={args.reduce_dims}"]
    np_full = next(r[3] for r in rows if r[0] == "Q1+Q2+Q3 full" and r[1].startswith("numpy"))
    print(f"  Q1+Q2+Q3 reduce_dims={args.reduce_dims} (rust) / full (numpy) = {red / np_full:6.1f}x")
    for name, impl, _, rate, _ in rows:
        if impl == "sklearn":
            print(f"  Q1+Q2+Q3 full (rust) / {name:15s} = {full / rate:6.2f}x;  reduced / {name}: {red / rate:6.2f}x")


TRAIN_CHILD = r"""
import json, resource, sys, time
import numpy as np
from isa import _core
d = np.load(sys.argv[1], allow_pickle=True)
images = list(d["images"])
f = _core.Forest(**json.loads(sys.argv[2]))
t0 = time.perf_counter(); c0 = time.process_time()
f.fit(_core.TrainSet(images, d["parts"], d["off"], d["rot"], d["la"], d["no"]))
t = time.perf_counter() - t0
print(json.dumps({"seconds": t, "cpu_seconds": time.process_time() - c0,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "nodes": sum(f.n_nodes), "depths": f.depths}))
"""


def bench_paper_scale(args):
    import tempfile

    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    images, meta, parts = make_parts(args.parts, rng)
    n_img = len(images)
    off, rot, la, no = targets_for(parts, images, meta)
    print(f"paper scale: {len(parts)} parts from {n_img} crops ({sum(i.size for i in images) * 2 / 1e6:.0f} MB of depth), "
          f"data in {time.perf_counter() - t0:.0f} s")
    params = dict(n_trees=10, max_depth=20, n_candidates=100, quality="Q1+Q2+Q3", reduce_dims=args.reduce_dims, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "data.npz")
        arr = np.empty(len(images), object)
        arr[:] = images
        np.savez(path, images=arr, parts=parts, off=off, rot=rot, la=la, no=no)
        out = subprocess.run([sys.executable, "-c", TRAIN_CHILD, path, json.dumps(params)], check=True,
                             capture_output=True, text=True)
        res = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"rust forest {params}:\n  {res['seconds']:.1f} s wall ({res['cpu_seconds']:.0f} s CPU), peak RSS {res['peak_rss_mb']:.0f} MB "
          f"(child process incl. its copy of the data), {res['nodes']} nodes, depths {res['depths']}")
    if args.skip_sklearn:
        return
    from sklearn.ensemble import ExtraTreesRegressor

    u, v = random_features(rng, 100)
    feats = _core.depth_features(images, parts, u, v)
    y = sklearn_targets(off, rot, la, no)
    et = ExtraTreesRegressor(n_estimators=10, max_depth=20, max_features=100, n_jobs=-1, random_state=0)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t_sk, _ = timed(et.fit, feats, y)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"sklearn ExtraTreesRegressor(10 trees, depth 20, 100 features, 76-dim y): {t_sk:.1f} s wall, "
          f"peak RSS {after:.0f} MB (was {before:.0f} MB before fitting)")
    print(f"ratio sklearn / rust time: {t_sk / res['seconds']:.2f}x")


def bench_reduction_effect(args):
    """Effect of ``reduce_dims`` on the split the criterion picks: on nodes made of the parts of
    random sets of crops, the Q1+Q2+Q3 split chosen with k principal components is scored with
    the full-dimension criterion and compared with the full-dimension best (same candidates and
    thresholds: the threshold streams do not depend on k)."""
    rng = np.random.default_rng(args.seed)
    images, meta, parts = make_parts(args.parts, rng)
    off, rot, la, no = targets_for(parts, images, meta)
    ks = [2, 4, 6, 8, 12, 0]
    ratios = {k: [] for k in ks}
    q1 = {k: [] for k in ks}
    same = {k: 0 for k in ks}
    times = {k: 0.0 for k in ks}
    trials = 8
    for t in range(trials):
        imgs = rng.choice(len(images), size=min(len(images), 60), replace=False)
        sel = np.isin(parts[:, 0], imgs)
        p = np.ascontiguousarray(parts[sel])
        u, v = random_features(rng, args.candidates)
        feats = _core.depth_features(images, p, u, v)
        a, b, c, d = (np.ascontiguousarray(x[sel]) for x in (off, rot, la, no))
        full = None
        res = {}
        for k in ks:
            r = _testing.split_search(feats, (a, b, c, d), quality="Q1+Q2+Q3", reduce_dims=k, min_samples_leaf=5, seed=t)
            times[k] += r["seconds"]
            mask = feats[:, r["candidate"]] < r["threshold"]
            g = _testing.criterion_gains((a, b, c, d), mask, reduce_dims=0)
            res[k] = (r["candidate"], r["threshold"], g["Q1"] + g["Q2"] + g["Q3"], g["Q1"])
        full = res[0]
        for k in ks:
            ratios[k].append(res[k][2] / full[2])
            q1[k].append(res[k][3] / max(r[3] for r in res.values()))
            same[k] += res[k][:2] == full[:2]
    print(f"reduce_dims effect on the chosen split ({trials} nodes of ~{int(sel.sum())} parts, "
          f"{args.candidates} candidates x {K} thresholds):")
    print("columns: full-dimension Q1+Q2+Q3 gain of the chosen split / the best one; its Q1 gain /")
    print("the largest Q1 gain any k found; splits equal to the full-dimension choice; search time")
    print(f"{'k':>6s} {'full gain ratio':>22s} {'Q1 gain ratio':>14s} {'same split':>11s} {'search s':>9s}")
    for k in ks:
        print(f"{(k or 'full'):>6} {np.mean(ratios[k]):8.3f} (min {np.min(ratios[k]):.3f}) {np.mean(q1[k]):14.3f} "
              f"{same[k]:7d}/{trials} {times[k]:9.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", type=int, default=None, help="parts (default 100k; 1M with --paper-scale)")
    ap.add_argument("--candidates", type=int, default=100)
    ap.add_argument("--reduce-dims", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--paper-scale", action="store_true")
    ap.add_argument("--skip-sklearn", action="store_true")
    ap.add_argument("--reduction-effect", action="store_true",
                    help="measure how reduce_dims changes the chosen split (vs the full criterion)")
    args = ap.parse_args()
    if args.reduction_effect:
        args.parts = args.parts or 200_000
        bench_reduction_effect(args)
    elif args.paper_scale:
        args.parts = args.parts or 1_000_000
        bench_paper_scale(args)
    else:
        args.parts = args.parts or 100_000
        bench_split(args)


if __name__ == "__main__":
    main()

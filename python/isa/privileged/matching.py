"""Graph matching of raw skeletons to a category template: node i = the same place on every instance.

A raw skeleton (from :func:`isa.privileged.skeleton.extract_skeleton`) has as many nodes as its mesh's
thinning happened to give. The forest's privileged data needs *one* topology per category, so every
instance is given the template's nodes and links, each template node placed on the instance.

Coordinates are compared in a **normalised box frame**: each instance's points are mapped by its
own axis-aligned bounding box to ``[-0.5, 0.5]^3`` (``normalise``). ModelNet10 and the procedural
objects are upright with a consistent front, so after this map a chair's front-left foot is near
(-0.5, -0.5, -0.5) whatever the chair's size; what differs between instances is proportions.

Matching (``match_skeleton``) minimises, over a one-to-one assignment p of template nodes to raw
nodes (or "unmatched"),

    E(p) = sum_i |A(t_i) - r_p(i)|^2 / s_u^2 + kind penalty
         + lam * sum_{(i,k) in links} (g(p(i), p(k)) - |A(t_i) - A(t_k)|)^2 / s_p^2

where A is a per-axis scale and offset fitted to the matches (so proportions may differ), r are
normalised raw nodes and g the raw skeleton's geodesic distance (the structural, quadratic term:
linked template nodes must stay linked-and-as-far on the instance). It is solved by a Hungarian
assignment on the unary term, refined by iterated conditional modes, alternated with the refit of
A. Unmatched template nodes (a missing part) are placed at A(t_i), and ``meta["matched"]`` says so.

``match_graphs_qap`` is the plain quadratic-assignment matcher (scipy's FAQ) for two graphs of
the same size, useful when no geometry is shared (e.g. the symmetric test graphs of issue #3).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment, quadratic_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from isa.exceptions import InvalidTypeError, InvalidValueError
from isa.skeleton_graph import SkeletonGraph

__all__ = [
    "normalise", "denormalise", "template_from_ground_truth", "match_skeleton", "calibrate_template", "template_from_instances",
    "match_graphs_qap",
]


def _bounds(bounds) -> np.ndarray:
    b = np.asarray(bounds, dtype=float)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)):
        raise InvalidValueError(f"bounds: expected a finite (2, 3) array [min xyz, max xyz], got shape {b.shape}")
    if np.any(b[1] - b[0] <= 0):
        raise InvalidValueError(f"bounds: every extent must be positive, got {(b[1] - b[0]).tolist()}")
    return b


def normalise(points, bounds) -> np.ndarray:
    """Map points (N, 3) into the normalised box frame of ``bounds`` (box -> [-0.5, 0.5]^3)."""
    b = _bounds(bounds)
    return (np.asarray(points, float) - b.mean(0)) / (b[1] - b[0])


def denormalise(q, bounds) -> np.ndarray:
    """Inverse of :func:`normalise`."""
    b = _bounds(bounds)
    return np.asarray(q, float) * (b[1] - b[0]) + b.mean(0)


def _graph_bounds(graph: SkeletonGraph, bounds) -> np.ndarray:
    if bounds is not None:
        return _bounds(bounds)
    if "bounds" in graph.meta:
        return _bounds(graph.meta["bounds"])
    raise InvalidValueError("bounds: not given and the skeleton's meta has no 'bounds' (pass the mesh's bounds)")


def template_from_ground_truth(skeletons: Sequence[SkeletonGraph], bounds: Sequence) -> SkeletonGraph:
    """Category template from ground-truth skeletons that share node names and links.

    The template's nodes are the mean normalised positions (each skeleton normalised by its own
    mesh ``bounds``); its links and names are the skeletons' (checked identical).
    """
    if len(skeletons) == 0:
        raise InvalidValueError("skeletons: need at least one ground-truth skeleton")
    if len(bounds) != len(skeletons):
        raise InvalidValueError(f"bounds: {len(bounds)} given for {len(skeletons)} skeletons")
    ref = skeletons[0]
    if ref.names is None:
        raise InvalidValueError("skeletons: ground-truth skeletons must carry node names")
    q = []
    for s, b in zip(skeletons, bounds):
        if s.names != ref.names or not np.array_equal(s.links, ref.links):
            raise InvalidValueError("skeletons: all ground-truth skeletons must have the same names and links")
        q.append(normalise(s.nodes, b))
    q = np.stack(q)
    meta = {"frame": "normalised-box", "n_instances": len(skeletons), "spread": q.std(0).tolist()}
    return SkeletonGraph(q.mean(0), ref.links.copy(), list(ref.names), meta)


def _geodesic(nodes: np.ndarray, links: np.ndarray) -> np.ndarray:
    n = len(nodes)
    if len(links) == 0:
        g = np.full((n, n), np.inf)
        np.fill_diagonal(g, 0)
        return g
    w = np.linalg.norm(nodes[links[:, 0]] - nodes[links[:, 1]], axis=1) + 1e-9
    m = coo_matrix((np.r_[w, w], (np.r_[links[:, 0], links[:, 1]], np.r_[links[:, 1], links[:, 0]])), shape=(n, n))
    return shortest_path(m.tocsr(), directed=False)


def _degrees(links: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(links.ravel(), minlength=n) if len(links) else np.zeros(n, int)


def match_skeleton(
    raw: SkeletonGraph,
    template: SkeletonGraph,
    bounds=None,
    sigma: float = 0.15,
    structure: float = 1.0,
    max_dist: float = 0.25,
    iterations: int = 4,
) -> SkeletonGraph:
    """Place ``template``'s nodes on the instance whose raw skeleton is ``raw``.

    ``template`` is in the normalised box frame (see :func:`template_from_ground_truth`);
    ``bounds`` is the instance mesh's (2, 3) bounds (default ``raw.meta["bounds"]``). ``sigma``
    is the unary scale and ``max_dist`` the normalised distance beyond which a template node is
    left unmatched; ``structure`` weighs the link-length (quadratic) term. Deterministic.

    Returns a :class:`SkeletonGraph` with the template's links and names and nodes in the
    instance's coordinates (metres); ``meta`` has ``matched`` (bool per node), ``raw_index``
    (raw node per template node, -1 if unmatched) and ``cost``.
    """
    if not isinstance(raw, SkeletonGraph) or not isinstance(template, SkeletonGraph):
        raise InvalidTypeError("raw, template: expected SkeletonGraph objects")
    if len(raw.nodes) == 0:
        raise InvalidValueError("raw: the skeleton has no nodes")
    if len(template.nodes) == 0:
        raise InvalidValueError("template: the template has no nodes")
    for name, v in (("sigma", sigma), ("max_dist", max_dist)):
        if not v > 0:
            raise InvalidValueError(f"{name}: must be positive, got {v}")
    if structure < 0:
        raise InvalidValueError(f"structure: must be >= 0, got {structure}")
    b = _graph_bounds(raw, bounds)
    R = normalise(raw.nodes, b)
    T = template.nodes
    N, M = len(T), len(R)
    G = _geodesic(R, raw.links)
    kinds = np.asarray(raw.meta.get("kind", ["inner"] * M))
    rdeg = np.where(kinds == "end", 1, np.where(kinds == "junction", 3, 2)) if "kind" in raw.meta else _degrees(raw.links, M)
    tdeg = _degrees(template.links, N)
    # Kind penalty: a template end should land on a raw end, a junction on a junction (soft).
    kind_pen = 0.25 * (((tdeg[:, None] == 1) & (rdeg[None] != 1)) | ((tdeg[:, None] >= 3) & (rdeg[None] == 1)))
    miss = (max_dist / sigma) ** 2
    scale, offset = np.ones(3), np.zeros(3)
    tl = template.links
    p = -np.ones(N, np.int64)
    for _ in range(max(1, iterations)):
        At = T * scale + offset
        D2 = ((At[:, None] - R[None]) ** 2).sum(-1) / sigma**2
        U = D2 + kind_pen
        U[D2 > miss] = np.inf
        # Hungarian with one "unmatched" column per template node.
        big = 1e9
        C = np.full((N, M + N), big)
        C[:, :M] = np.where(np.isfinite(U), U, big)
        C[np.arange(N), M + np.arange(N)] = miss
        rows, cols = linear_sum_assignment(C)
        p = np.where(cols < M, cols, -1)[np.argsort(rows)]
        tlen = np.linalg.norm(At[tl[:, 0]] - At[tl[:, 1]], axis=1) if len(tl) else np.zeros(0)
        nbrs = [[] for _ in range(N)]
        for e, (i, k) in enumerate(tl):
            nbrs[i].append((k, e))
            nbrs[k].append((i, e))

        def local(i: int, j: int) -> float:
            if j < 0:
                e = miss
            else:
                e = U[i, j]
                if not np.isfinite(e):
                    return np.inf
            for k, ed in nbrs[i]:
                if j >= 0 and p[k] >= 0:
                    g = G[j, p[k]]
                    g = 3.0 if not np.isfinite(g) else g  # disconnected: a large, finite penalty
                    e += structure * (g - tlen[ed]) ** 2 / (sigma**2)
                elif structure > 0:
                    e += structure * 0.5 * miss / max(1, len(nbrs[i]))  # a missing neighbour costs
            return e

        # Iterated conditional modes over a few nearest candidates per node (one-to-one kept).
        cand = np.argsort(np.where(np.isfinite(U), U, np.inf), axis=1)[:, : min(M, 10)]
        for _sweep in range(10):
            changed = False
            for i in range(N):
                used = set(p[p >= 0].tolist()) - {int(p[i])}
                best_j, best_e = int(p[i]), local(i, int(p[i]))
                for j in list(cand[i]) + [-1]:
                    j = int(j)
                    if j >= 0 and (j in used or not np.isfinite(U[i, j])):
                        continue
                    e = local(i, j)
                    if e < best_e - 1e-12:
                        best_j, best_e = j, e
                if best_j != p[i]:
                    p[i] = best_j
                    changed = True
            if not changed:
                break
        # Refit the per-axis scale/offset to the matches (proportions differ between instances).
        ok = p >= 0
        if ok.sum() >= 4:
            for d in range(3):
                x, y = T[ok, d], R[p[ok], d]
                if np.ptp(x) > 1e-6:
                    s_, o_ = np.polyfit(x, y, 1)
                    scale[d], offset[d] = np.clip(s_, 0.6, 1.6), np.clip(o_, -0.25, 0.25)
                else:
                    offset[d] = np.clip(np.mean(y - x * scale[d]), -0.25, 0.25)
    At = T * scale + offset
    # A calibrated template (see calibrate_template) knows how far, on average, its node sits from
    # the raw skeleton node it is matched to (e.g. a rim node on the surface vs the medial curve).
    shift = np.asarray(template.meta.get("calibration", np.zeros((N, 3))), float).reshape(N, 3)
    out = np.where((p >= 0)[:, None], R[np.maximum(p, 0)] + shift * scale, At)
    total = float(sum(local(i, int(p[i])) for i in range(N)))
    meta = {
        "matched": (p >= 0).tolist(),
        "raw_index": p.tolist(),
        "cost": total,
        "scale": scale.tolist(),
        "offset": offset.tolist(),
        "bounds": b.tolist(),
    }
    for key in ("diameter", "category"):
        if key in raw.meta:
            meta[key] = raw.meta[key]
    return SkeletonGraph(denormalise(out, b), template.links.copy(), template.names, meta)


def calibrate_template(
    template: SkeletonGraph, raws: Sequence[SkeletonGraph], truths: Sequence[SkeletonGraph], bounds: Sequence, **kw
) -> SkeletonGraph:
    """Template with ``meta["calibration"]``: the mean normalised offset from each matched raw node
    to its ground-truth node, over training instances (``raws`` extracted, ``truths`` ground truth).

    Extraction gives medial curves, while a ground-truth convention may put a node on a surface
    (a toilet's rim, a mattress top); the offset is systematic per node, so it is learned once on
    training instances and added to every later match (its effect is measured on held-out ones).
    """
    if not (len(raws) == len(truths) == len(bounds)) or len(raws) == 0:
        raise InvalidValueError(f"raws, truths, bounds: need equal, non-zero lengths, got {len(raws)}, {len(truths)}, {len(bounds)}")
    base = SkeletonGraph(template.nodes, template.links, template.names, {k: v for k, v in template.meta.items() if k != "calibration"})
    acc = np.zeros_like(template.nodes)
    cnt = np.zeros(len(template.nodes))
    for raw, gt, b in zip(raws, truths, bounds):
        m = match_skeleton(raw, base, b, **kw)
        ok = np.array(m.meta["matched"])
        sc = np.asarray(m.meta["scale"])
        acc[ok] += (normalise(gt.nodes, b) - normalise(m.nodes, b))[ok] / sc
        cnt[ok] += 1
    cal = acc / np.maximum(cnt, 1)[:, None]
    return SkeletonGraph(template.nodes, template.links, template.names, {**base.meta, "calibration": cal.tolist()})


def template_from_instances(
    raws: Sequence[SkeletonGraph], bounds: Sequence | None = None, n_nodes: int = 19, rounds: int = 3
) -> SkeletonGraph:
    """Category template built from raw skeletons alone (no ground truth), with ``n_nodes`` nodes.

    Start from the junctions and ends of the instance with the most of them (up to ``n_nodes``,
    topped up with its farthest-point-sampled nodes), linked as on its skeleton (a link when the
    geodesic path between two chosen nodes passes no other chosen node); then alternate matching
    every instance to it and moving each node to the mean of its matches (a category mean).
    Names are ``node_00``..; deterministic.
    """
    if len(raws) == 0:
        raise InvalidValueError("raws: need at least one raw skeleton")
    if n_nodes < 2:
        raise InvalidValueError(f"n_nodes: need at least 2, got {n_nodes}")
    bs = [_graph_bounds(r, None if bounds is None else bounds[i]) for i, r in enumerate(raws)]
    qs = [normalise(r.nodes, b) for r, b in zip(raws, bs)]

    def key_nodes(r: SkeletonGraph) -> np.ndarray:
        k = np.asarray(r.meta.get("kind", []))
        return np.flatnonzero(k != "inner") if len(k) else np.arange(len(r.nodes))

    ref = int(np.argmax([min(len(key_nodes(r)), n_nodes) * 1000 + len(r.nodes) for r in raws]))
    r, q = raws[ref], qs[ref]
    chosen = list(key_nodes(r)[:n_nodes])
    G = _geodesic(q, r.links)
    while len(chosen) < min(n_nodes, len(q)):  # farthest-point top-up along the skeleton
        d = G[:, chosen].min(1) if chosen else np.zeros(len(q))
        d[~np.isfinite(d)] = -1
        chosen.append(int(np.argmax(d)))
    chosen = np.array(chosen[:n_nodes])
    # Link chosen nodes whose shortest path does not pass another chosen node.
    _, pred = shortest_path(
        coo_matrix(
            (np.ones(2 * len(r.links)), (np.r_[r.links[:, 0], r.links[:, 1]], np.r_[r.links[:, 1], r.links[:, 0]])),
            shape=(len(q), len(q)),
        ).tocsr(),
        directed=False,
        return_predecessors=True,
        indices=chosen,
    )
    cset = set(chosen.tolist())
    links = set()
    for a_i, a in enumerate(chosen):
        for b_i, bnode in enumerate(chosen):
            if b_i <= a_i or pred[a_i, bnode] < 0:
                continue
            x, clean = int(pred[a_i, bnode]), True
            while x != a:
                if x in cset:
                    clean = False
                    break
                x = int(pred[a_i, x])
            if clean:
                links.add((a_i, b_i))
    links_arr = np.array(sorted(links), np.int64).reshape(-1, 2)
    names = [f"node_{i:02d}" for i in range(len(chosen))]
    tmpl = SkeletonGraph(q[chosen], links_arr, names, {"frame": "normalised-box", "reference": ref})
    for _ in range(rounds):
        acc = np.zeros_like(tmpl.nodes)
        cnt = np.zeros(len(tmpl.nodes))
        for raw, b in zip(raws, bs):
            m = match_skeleton(raw, tmpl, b)
            ok = np.array(m.meta["matched"])
            acc[ok] += normalise(m.nodes, b)[ok]
            cnt[ok] += 1
        newn = np.where(cnt[:, None] > 0, acc / np.maximum(cnt, 1)[:, None], tmpl.nodes)
        tmpl = SkeletonGraph(newn, tmpl.links, names, {**tmpl.meta, "support": cnt.tolist()})
    return tmpl


def match_graphs_qap(
    A: np.ndarray, B: np.ndarray, seeds: np.ndarray | None = None, n_init: int = 8, seed: int = 0
) -> np.ndarray:
    """Match two same-size graphs by quadratic assignment (scipy FAQ, best of ``n_init`` starts).

    ``A``, ``B`` (n, n): adjacency or weighted adjacency. ``seeds`` (k, 2): known pairs
    (node of A, node of B). Returns ``perm`` with A's node i matched to B's node ``perm[i]``,
    maximising sum A[i, j] * B[perm[i], perm[j]]. The first start is the barycentre, the others
    random (seeded), so the result is reproducible.
    """
    A, B = np.asarray(A, float), np.asarray(B, float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape != B.shape:
        raise InvalidValueError(f"A, B: need two square matrices of the same shape, got {A.shape} and {B.shape}")
    if n_init < 1:
        raise InvalidValueError(f"n_init: need at least 1 start, got {n_init}")
    pm = np.zeros((0, 2), int) if seeds is None else np.asarray(seeds, int).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    best = None
    for s in range(n_init):
        opts = {"maximize": True, "partial_match": pm, "P0": "barycenter" if s == 0 else "randomized", "rng": rng}
        res = quadratic_assignment(A, B, method="faq", options=opts)
        if best is None or res.fun > best.fun:
            best = res
    return np.asarray(best.col_ind)

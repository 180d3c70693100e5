"""Graph matching: raw skeletons onto a category template, checked against procedural ground truth
(semantic node names), plus the plain quadratic-assignment matcher on permuted graphs."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from isa.data.procedural import generate
from isa.privileged.matching import (
    calibrate_template,
    match_graphs_qap,
    match_skeleton,
    normalise,
    template_from_ground_truth,
    template_from_instances,
)
from isa.privileged.skeleton import extract_skeleton
from isa.skeleton_graph import SkeletonGraph


@pytest.fixture(scope="module")
def chairs():
    objs = [generate("chair", s) for s in range(6)]
    return objs, [extract_skeleton(o.mesh) for o in objs]


@pytest.fixture(scope="module")
def tables():
    objs = [generate("table", s) for s in range(6)]
    return objs, [extract_skeleton(o.mesh) for o in objs]


def _gt_template(category: str, n: int = 12) -> SkeletonGraph:
    train = [generate(category, (7, i)) for i in range(n)]  # disjoint from the evaluated seeds
    return template_from_ground_truth([o.skeleton for o in train], [o.mesh.bounds for o in train])


def _semantic_accuracy(obj, matched: SkeletonGraph) -> float:
    """Fraction of template nodes placed nearest to the true node of the same name (or within 5%
    of the diameter of it, for true nodes that nearly coincide, e.g. a toilet's rim back and tank
    bottom)."""
    gt = obj.skeleton
    assert matched.names == gt.names
    D = np.linalg.norm(matched.nodes[:, None] - gt.nodes[None], axis=2)
    diam = np.linalg.norm(obj.mesh.extents)
    ok = (D.argmin(1) == np.arange(len(gt.nodes))) | (np.diag(D) < 0.05 * diam)
    return float(ok.mean())


@pytest.mark.parametrize("category", ["chair", "table"])
def test_semantic_matching_on_procedural_instances(category, chairs, tables):
    objs, raws = chairs if category == "chair" else tables
    T = _gt_template(category)
    acc = [_semantic_accuracy(o, match_skeleton(r, T)) for o, r in zip(objs, raws)]
    # Issue #3: >= 90% of template nodes on the right semantic node (measured 100% on seeds 0-11).
    assert np.mean(acc) >= 0.9, acc
    assert min(acc) >= 0.75, acc


def test_calibration_on_toilets_raises_accuracy():
    # Toilet ground truth marks surfaces (rim, lid); calibration learns the per-node offset from
    # the medial match on training instances. Measured on seeds 0-11: 87% plain -> 99% calibrated.
    train = [generate("toilet", (7, i)) for i in range(3)]
    T = template_from_ground_truth([o.skeleton for o in train], [o.mesh.bounds for o in train])
    Tc = calibrate_template(T, [extract_skeleton(o.mesh) for o in train], [o.skeleton for o in train], [o.mesh.bounds for o in train])
    test = [generate("toilet", s) for s in (0, 2)]
    raws = [extract_skeleton(o.mesh) for o in test]
    acc_c = np.mean([_semantic_accuracy(o, match_skeleton(r, Tc)) for o, r in zip(test, raws)])
    acc_p = np.mean([_semantic_accuracy(o, match_skeleton(r, T)) for o, r in zip(test, raws)])
    assert acc_c >= 0.9 and acc_c >= acc_p


def test_matching_ignores_raw_node_order(chairs):
    objs, raws = chairs
    raw = raws[0]
    T = _gt_template("chair")
    perm = np.random.default_rng(0).permutation(len(raw.nodes))
    inv = np.argsort(perm)
    shuffled = SkeletonGraph(
        raw.nodes[perm], inv[raw.links], None, {**raw.meta, "kind": [raw.meta["kind"][i] for i in perm]}
    )
    a, b = match_skeleton(raw, T), match_skeleton(shuffled, T)
    np.testing.assert_allclose(a.nodes, b.nodes)


def test_missing_part_is_flagged_and_completed(chairs):
    objs, raws = chairs
    obj, raw = objs[0], raws[0]
    T = _gt_template("chair")
    foot = obj.skeleton.names.index("foot_front_left")
    true_foot = obj.skeleton.nodes[foot]
    diam = np.linalg.norm(obj.mesh.extents)
    # Cut the lower half of that leg out of the raw skeleton.
    gone = np.linalg.norm(raw.nodes - true_foot, axis=1) < 0.25 * (obj.mesh.bounds[1, 2] - obj.mesh.bounds[0, 2])
    keep = np.flatnonzero(~gone)
    remap = -np.ones(len(raw.nodes), int)
    remap[keep] = np.arange(len(keep))
    links = remap[raw.links]
    cut = SkeletonGraph(raw.nodes[keep], links[(links >= 0).all(1)], None, {**raw.meta, "kind": [raw.meta["kind"][i] for i in keep]})
    m = match_skeleton(cut, T)
    assert m.meta["matched"][foot] is False
    # Placed by the fitted template map: still near the true foot.
    assert np.linalg.norm(m.nodes[foot] - true_foot) < 0.15 * diam
    full = match_skeleton(raw, T)
    # Nodes away from the cut leg keep their place (its seat corner may move along the seat).
    linked = set(T.links[(T.links == foot).any(1)].ravel().tolist())
    others = [i for i in range(len(T.nodes)) if i not in linked]
    assert _semantic_accuracy(obj, full) == 1.0
    np.testing.assert_allclose(m.nodes[others], full.nodes[others], atol=0.05 * diam)


def test_template_from_instances_is_consistent(chairs):
    # Without ground truth, node i of the learnt template must land on the same semantic place on
    # the instances (measured 91% on 8 chairs with 12 nodes).
    objs, raws = chairs
    T = template_from_instances(raws, n_nodes=12)
    assert len(T.nodes) == 12 and T.names[0] == "node_00"
    labels = []
    for o, r in zip(objs, raws):
        m = match_skeleton(r, T)
        labels.append(np.linalg.norm(m.nodes[:, None] - o.skeleton.nodes[None], axis=2).argmin(1))
    labels = np.array(labels)
    consistency = np.mean([Counter(labels[:, i]).most_common(1)[0][1] / len(objs) for i in range(12)])
    assert consistency >= 0.8


def test_qap_recovers_a_permuted_weighted_graph():
    gt = generate("chair", 3).skeleton
    A = gt.adjacency(weighted=True)
    n = len(A)
    rng = np.random.default_rng(1)
    perm = rng.permutation(n)  # B's node perm[i] is A's node i
    B = np.zeros_like(A)
    B[np.ix_(perm, perm)] = A
    found = match_graphs_qap(A, B, n_init=6)

    def score(p):
        return float((A * B[np.ix_(p, p)]).sum())

    # A chair is left/right symmetric, so without seeds any optimum is acceptable ...
    assert score(found) == pytest.approx(score(perm))
    # ... and two seed pairs on one side fix the symmetry: exact recovery.
    left = [gt.names.index("foot_front_left"), gt.names.index("back_top_left")]
    seeds = np.array([[i, perm[i]] for i in left])
    assert np.array_equal(match_graphs_qap(A, B, seeds=seeds), perm)


def test_normalise_and_errors():
    b = np.array([[-1.0, 0.0, 0.0], [1.0, 2.0, 4.0]])
    np.testing.assert_allclose(normalise([[1.0, 2.0, 4.0], [0, 1, 2]], b), [[0.5, 0.5, 0.5], [0, 0, 0]])
    with pytest.raises(ValueError, match="bounds"):
        normalise([[0, 0, 0]], [[0, 0, 0], [1, 0, 1]])
    raw = SkeletonGraph(np.zeros((2, 3)), [[0, 1]])
    T = _gt_template("chair", 2)
    with pytest.raises(ValueError, match="bounds"):
        match_skeleton(raw, T)
    with pytest.raises(ValueError, match="sigma"):
        match_skeleton(raw, T, b, sigma=0)
    with pytest.raises(ValueError, match="A, B"):
        match_graphs_qap(np.eye(3), np.eye(4))


def test_real_modelnet_chairs_match_sensibly(shared_data):
    # No ground truth on real meshes, so check what any person would: feet at the bottom, back top
    # at the top, seat in between, front corners in front of back corners (ModelNet front: -y).
    from isa.data.meshes import prepare_mesh
    from isa.data.modelnet import paper_instances

    T = _gt_template("chair")
    ix = {n: i for i, n in enumerate(T.names)}
    for i, inst in enumerate(paper_instances(shared_data / "modelnet10", "chair")[:8]):
        mesh = prepare_mesh(inst.path, "chair", seed=i)[0]
        m = match_skeleton(extract_skeleton(mesh), T)
        z = normalise(m.nodes, mesh.bounds)[:, 2] + 0.5  # 0 floor .. 1 top
        y = m.nodes[:, 1]
        feet = [ix[f"foot_{s}"] for s in ("front_left", "front_right", "back_left", "back_right")]
        seat = [ix[f"seat_{s}"] for s in ("front_left", "front_right", "back_left", "back_right")]
        tops = [ix["back_top_left"], ix["back_top_right"], ix["back_top_centre"]]
        assert z[feet].max() < 0.2 and z[tops].min() > 0.7, inst.name
        assert z[feet].max() < z[seat].min() and z[seat].max() < z[tops].min(), inst.name
        assert y[seat[:2]].max() < y[seat[2:]].min(), inst.name


def test_matched_grid_figure_shows_every_node(tmp_path):
    from PIL import Image

    from isa.report.figures.skeletons import _colours, matched_grid

    objs = [generate("chair", s) for s in range(2)]
    out = matched_grid([o.mesh for o in objs], [o.skeleton for o in objs], tmp_path / "grid.png")
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    # Every template node's colour is drawn (markers and legend), so all 12 colours are present.
    for c in _colours(12):
        rgb = np.round(np.array(c[:3]) * 255).astype(int)
        assert (np.abs(img - rgb).sum(-1) < 12).any(), rgb

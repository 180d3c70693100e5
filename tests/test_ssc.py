"""Semantically Selected Centers: the paper's vote on constructed cases, and the category origin on
procedural chairs (whose centre of mass sits in the seat)."""

from __future__ import annotations

import numpy as np
import pytest

from isa.data.procedural import generate
from isa.privileged.matching import template_from_ground_truth
from isa.privileged.ssc import SSC, CategorySSC, centre_of_mass, fit_category_ssc, select_ssc
from isa.skeleton_graph import SkeletonGraph


def _instances(nearest: list[int], n_nodes: int = 5, seed: int = 0, unmatched=None):
    """Matched skeletons whose node ``nearest[k]`` is the one closest to instance k's COM (0, 0, 0)."""
    rng = np.random.default_rng(seed)
    out = []
    for k, j in enumerate(nearest):
        nodes = rng.uniform(0.3, 1.0, (n_nodes, 3)) * rng.choice([-1, 1], (n_nodes, 3))
        nodes[j] = rng.uniform(-0.1, 0.1, 3)
        matched = [True] * n_nodes
        if unmatched is not None and unmatched[k] is not None:
            matched[unmatched[k]] = False
        out.append(SkeletonGraph(nodes, [[i, i + 1] for i in range(n_nodes - 1)], [f"n{i}" for i in range(n_nodes)], {"matched": matched}))
    return out, np.zeros((len(nearest), 3))


def test_most_repetitive_node_wins():
    sk, coms = _instances([2, 2, 3, 2, 1, 2])
    s = select_ssc(sk, coms)
    assert s.votes.tolist() == [0, 1, 4, 1, 0]
    assert s.nodes.tolist() == [2] and s.weights[2] == 1.0
    np.testing.assert_allclose(s.point(sk[0]), sk[0].nodes[2])


def test_tie_interpolates_between_repetitive_nodes():
    sk, coms = _instances([1, 3, 1, 3, 0])
    s = select_ssc(sk, coms)
    assert s.nodes.tolist() == [1, 3]
    np.testing.assert_allclose(s.weights, [0, 0.5, 0, 0.5, 0])
    np.testing.assert_allclose(s.point(sk[2]), (sk[2].nodes[1] + sk[2].nodes[3]) / 2)
    # A tolerance widens what counts as a tie.
    assert select_ssc(sk, coms, tie_tolerance=1).nodes.tolist() == [0, 1, 3]


def test_unmatched_nodes_do_not_vote():
    # Instance 0's nearest node (2) was not found on it (a missing part): it must not vote for 2.
    sk, coms = _instances([2, 4, 4, 2, 2], unmatched=[2, None, None, None, None])
    s = select_ssc(sk, coms)
    assert s.votes[2] == 2 and s.votes[4] == 2 and s.votes.sum() == 5


def test_ssc_round_trip_and_errors(tmp_path):
    sk, coms = _instances([0, 0, 1])
    s = select_ssc(sk, coms)
    s2 = SSC.from_dict(s.to_dict())
    np.testing.assert_array_equal(s.weights, s2.weights)
    with pytest.raises(ValueError, match="coms"):
        select_ssc(sk, coms[:2])
    with pytest.raises(ValueError, match="matched"):
        select_ssc([], [])
    with pytest.raises(ValueError, match="matched"):
        s.point(SkeletonGraph(np.zeros((3, 3)), []))
    with pytest.raises(ValueError, match="weights"):
        SSC([0.5, 0.2], [1, 1])


def test_category_ssc_on_procedural_chairs(tmp_path):
    train = [generate("chair", (7, i)) for i in range(8)]
    T = template_from_ground_truth([o.skeleton for o in train], [o.mesh.bounds for o in train])
    objs = [generate("chair", s) for s in range(6)]
    cat, matched, coms = fit_category_ssc([o.mesh for o in objs], T)
    # A chair's mass is in its seat and legs around it: the node nearest the COM is the seat centre
    # on most instances (independent check: nearest true node to each COM).
    truth_votes = [o.skeleton.names[int(np.argmin(np.linalg.norm(o.skeleton.nodes - c, axis=1)))] for o, c in zip(objs, coms)]
    assert truth_votes.count("seat_centre") >= 4
    assert [T.names[i] for i in cat.ssc.nodes] == ["seat_centre"]
    # The origin of an unseen chair is its seat centre (ground truth) to within a few centimetres.
    unseen = generate("chair", 100)
    origin = cat.origin(unseen.mesh)
    true_seat = unseen.skeleton.nodes[unseen.skeleton.names.index("seat_centre")]
    assert np.linalg.norm(origin - true_seat) < 0.05
    # Saved and loaded, it gives the same origin.
    cat.save(tmp_path / "chair_ssc.json")
    np.testing.assert_allclose(CategorySSC.load(tmp_path / "chair_ssc.json").origin(unseen.mesh), origin)
    # The COMs are those of the solids (within a couple of voxels of trimesh's exact volume COM
    # for the watertight pieces the procedural chair is built from).
    pieces = unseen.mesh.split(only_watertight=False)
    exact = np.array(sum(p.volume * p.center_mass for p in pieces) / sum(p.volume for p in pieces))
    assert np.linalg.norm(centre_of_mass(unseen.mesh) - exact) < 0.03


def test_box_centre_origin(tmp_path):
    """``centre="box"``: the origin is the mesh's bounding-box centre (independent: trimesh's
    bounds); the SSC is still fitted and kept, and the choice survives save/load."""
    objs = [generate("chair", s) for s in range(3)]
    T = template_from_ground_truth([o.skeleton for o in objs], [o.mesh.bounds for o in objs])
    cat, _, _ = fit_category_ssc([o.mesh for o in objs], T)
    box = CategorySSC(cat.template, cat.ssc, cat.extract_kw, centre="box")
    unseen = generate("chair", 101)
    shifted = unseen.mesh.copy()
    shifted.apply_translation([0.3, -0.2, 0.5])
    np.testing.assert_allclose(box.origin(shifted), shifted.bounds.mean(0), atol=1e-12)
    np.testing.assert_allclose(box.origin(shifted) - box.origin(unseen.mesh), [0.3, -0.2, 0.5], atol=1e-12)
    box.save(tmp_path / "box.json")
    loaded = CategorySSC.load(tmp_path / "box.json")
    assert loaded.centre == "box" and loaded.ssc.nodes.tolist() == cat.ssc.nodes.tolist()
    with pytest.raises(ValueError, match="centre"):
        CategorySSC(cat.template, cat.ssc, centre="middle")
    # ``centre="com"``: the solid's centre of mass, which moves with the mesh (to within a voxel:
    # the voxel grid is laid on the moved mesh afresh).
    com = CategorySSC(cat.template, cat.ssc, centre="com")
    np.testing.assert_allclose(com.origin(unseen.mesh), centre_of_mass(unseen.mesh), atol=1e-12)
    pitch = unseen.mesh.extents.max() / 80
    np.testing.assert_allclose(com.origin(shifted) - com.origin(unseen.mesh), [0.3, -0.2, 0.5], atol=pitch)


def test_prepare_category_moves_the_chosen_origin_to_zero():
    from isa.pipeline import prepare_category
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("toilet", 3, seed=5)
    for centre in ("ssc", "com", "box"):
        prep = prepare_category("toilet", objs, centre=centre, progress=False)
        assert prep.ssc.centre == centre
        for o, before in zip(prep.objects, objs):
            if centre == "box":
                np.testing.assert_allclose(o.mesh.bounds.mean(0), 0, atol=1e-9)
            elif centre == "com":
                np.testing.assert_allclose(centre_of_mass(o.mesh), 0, atol=o.mesh.extents.max() / 80)
            else:
                # The recentred skeleton's SSC is at the origin.
                np.testing.assert_allclose(prep.ssc.ssc.point(prep.skeletons[o.obj_id]), 0, atol=1e-9)
            # Only a translation: the shape is unchanged.
            np.testing.assert_allclose(o.mesh.extents, before.mesh.extents, atol=1e-9)

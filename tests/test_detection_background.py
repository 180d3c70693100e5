"""Background parts: leaf probabilities learned from parts on and off chairs in rendered rooms
lower the weight of floor and wall votes in an unseen room; without them the weighted path
gives the forest's own hypotheses."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isa.camera import KINECT_V1
from isa.evaluation.boxes3d import rot_z
from isa.render.views import look_at


def _room(mesh, x, y, yaw, eye, target, clutter=True):
    """Depth of ``mesh`` on a floor before a wall (and a box beside it), the object's visible
    pixels and its true (R, t)."""
    from isa.render.renderer import DepthRenderer

    T = np.eye(4)
    T[:3, :3] = rot_z(yaw)
    T[:3, 3] = (x, y, -mesh.bounds[0, 2])
    parts = [trimesh.creation.box((8, 8, 0.02), trimesh.transformations.translation_matrix((0, 0, -0.01))),
             trimesh.creation.box((8, 0.05, 2.6), trimesh.transformations.translation_matrix((0, 3.0, 1.3)))]
    if clutter:
        beside = trimesh.transformations.translation_matrix((x - 1.1, y, 0.3))
        parts.append(trimesh.creation.box((0.5, 0.4, 0.6), beside))
    obj = mesh.copy()
    obj.apply_transform(T)
    R_wc, t_wc = look_at(np.asarray(eye, float), np.asarray(target, float))
    R, t = R_wc @ T[:3, :3], R_wc @ T[:3, 3] + t_wc
    with DepthRenderer(KINECT_V1) as r:
        depth, _ = r.render(trimesh.util.concatenate([*parts, obj]), R_wc, t_wc)
        alone, mask = r.render(mesh, R, t)
    return depth, mask & (np.abs(depth - alone) < 0.01), (R, t)


def _labelled_parts(rooms, stride=4):
    """Parts of the rooms on the stride grid, labelled by the object's visible pixels
    (:func:`isa.detection.background.labelled_parts`)."""
    from types import SimpleNamespace

    from isa.detection.background import labelled_parts

    return labelled_parts([SimpleNamespace(depth=d, mask=m) for d, m, _ in rooms], stride)


@pytest.fixture(scope="module")
def trained():
    from isa.detection import train_detector
    from isa.forest import ForestParams
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("chair", 3, seed=7)
    params = ForestParams(n_trees=3, max_depth=12, n_candidates=30, quality="Q1")
    forest, prepared = train_detector("chair", objs, views=20, stride=6, use_ground_truth=True, forest_params=params)
    return forest, prepared


@pytest.mark.slow
def test_weighted_path_without_probabilities_gives_the_forests_hypotheses(trained):
    from isa.detection.background import weighted_predict

    forest, prepared = trained
    depth, _, _ = _room(prepared.objects[0].mesh, 0.2, 0.6, 0.5, (0.0, -1.8, 1.3), (0.2, 0.6, 0.4))
    ours = weighted_predict(forest, None, depth, KINECT_V1, stride=4, max_hypotheses=3)
    ref = forest.predict(depth, KINECT_V1, stride=4, max_hypotheses=3)
    assert ours and ref
    np.testing.assert_allclose(ours[0]["t"], ref[0]["t"], atol=0.01)
    # Scores agree to a few percent (the core rounds the float depth to mm its own way).
    assert ours[0]["score"] == pytest.approx(ref[0]["score"], rel=0.1)


@pytest.mark.slow
def test_background_parts_lower_floor_and_wall_votes_in_an_unseen_room(trained, tmp_path):
    from isa.detection.background import LeafForeground, fit_leaf_foreground
    from isa.pipeline import prepare_category
    from isa.render.dataset import procedural_objects

    forest, prepared = trained
    train_rooms = [_room(o.mesh, x, y, yaw, eye, (x, y, 0.4)) for o, (x, y, yaw, eye) in zip(
        prepared.objects, [(0.2, 0.6, 0.5, (0.0, -1.8, 1.3)), (-0.3, 1.0, 2.0, (0.5, -1.5, 1.6)),
                           (0.4, 0.8, -1.2, (-0.4, -2.0, 1.1))], strict=True)]
    images, parts, on = _labelled_parts(train_rooms)
    fg = fit_leaf_foreground(forest, images, parts, on, category="chair")
    assert fg.n_positive == on.sum() and fg.n_negative == (~on).sum()
    fg.save(tmp_path / "fg.npz")
    fg = LeafForeground.load(tmp_path / "fg.npz")

    unseen = prepare_category("chair", procedural_objects("chair", 1, seed=99), ssc=prepared.ssc,
                              use_ground_truth=True, progress=False).objects[0].mesh
    test = _room(unseen, -0.1, 0.9, 2.6, (0.3, -1.6, 1.5), (-0.1, 0.9, 0.3))
    images, parts, on = _labelled_parts([test])
    p = fg.of(forest.apply(images, parts)).mean(1)
    # Parts of the unseen chair reach leaves that mostly held chair parts; floor, wall and box
    # parts reach leaves that mostly held background.
    assert p[on].mean() > p[~on].mean() + 0.2, (p[on].mean(), p[~on].mean())
    # So the votes' weight moves onto the chair: its share of the total grows.
    v = forest.votes(images, parts)
    w_on = v["weight"] * on[v["part"]]
    pw = fg.of(forest.apply(images, parts))[v["part"], v["tree"]]
    assert (w_on * pw).sum() / (v["weight"] * pw).sum() > 1.5 * w_on.sum() / v["weight"].sum()


@pytest.mark.slow
def test_leaf_weights_in_the_model_file_vote_as_the_numpy_reference(trained, tmp_path):
    """The core weights each vote by its leaf's weight (model format 3) as the NumPy reference
    (:func:`isa.detection.background.weighted_predict`) does from every part's leaves; a side
    ``.foreground.npz`` gives the same model through ``load_model``."""
    from isa.detection import load_model
    from isa.detection.background import fit_leaf_foreground, weighted_predict
    from isa.forest.model import Forest

    forest, prepared = trained
    rooms = [_room(prepared.objects[0].mesh, 0.2, 0.6, 0.5, (0.0, -1.8, 1.3), (0.2, 0.6, 0.4))]
    fg = fit_leaf_foreground(forest, *_labelled_parts(rooms), category="chair")
    forest.save(tmp_path / "plain.isa")
    forest.with_leaf_weights(fg.leaf_weights(forest)).save(tmp_path / "weighted.isa")
    loaded = Forest.load(tmp_path / "weighted.isa")
    assert forest.leaf_weights is None and Forest.load(tmp_path / "plain.isa").leaf_weights is None
    for got, want, n in zip(loaded.leaf_weights, fg.probs, forest.n_leaves, strict=True):
        np.testing.assert_array_equal(got, want[:n])
    fg.save(tmp_path / "plain.foreground.npz")
    beside = load_model(tmp_path / "plain.isa")
    assert beside.forest.to_bytes() == loaded.to_bytes()

    depth, _, _ = _room(prepared.objects[1].mesh, -0.3, 1.0, 2.0, (0.5, -1.5, 1.6), (-0.3, 1.0, 0.4))
    kw = {"stride": 4, "max_hypotheses": 3}
    ref = weighted_predict(forest, fg, depth, KINECT_V1, **kw)
    ours = loaded.predict(depth, KINECT_V1, min_leaf_weight=0.0, **kw)
    plain = forest.predict(depth, KINECT_V1, min_leaf_weight=0.0, **kw)
    assert ref and ours and plain
    np.testing.assert_allclose(ours[0]["t"], ref[0]["t"], atol=0.01)
    assert ours[0]["score"] == pytest.approx(ref[0]["score"], rel=0.1)
    # The weights (at most 1, many near 0 off the chair) take weight away.
    assert ours[0]["score"] < 0.9 * plain[0]["score"]


def test_bad_leaf_weights_are_refused_by_name(trained):
    from isa.exceptions import InvalidInputError

    forest, _ = trained
    ok = [np.full(n, 0.5, np.float32) for n in forest.n_leaves]
    assert len(forest.with_leaf_weights(ok).leaf_weights) == forest.n_trees
    with pytest.raises(InvalidInputError, match="tree 1 leaf 3"):
        bad = [w.copy() for w in ok]
        bad[1][3] = -0.1
        forest.with_leaf_weights(bad)
    with pytest.raises(InvalidInputError, match="tree 0 has"):
        forest.with_leaf_weights([w[:-1] for w in ok])
    with pytest.raises(InvalidInputError, match=r"weights\[0\].* is not finite"):
        forest.with_leaf_weights([np.full(n, np.nan, np.float32) for n in forest.n_leaves])


def test_command_names_a_missing_model_and_writes_nothing(tmp_path, capsys):
    from isa.detection.background import main

    out = tmp_path / "chair.foreground.npz"
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path), "--category", "chair", "--model", str(tmp_path / "none.isa"), "--renders",
              str(tmp_path / "r"), "-o", str(out)])
    assert e.value.code == 2
    assert "none.isa" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "r").exists()

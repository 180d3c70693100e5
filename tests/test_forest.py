"""The Rust forest through Python: a toy problem with a known answer, determinism across
thread counts, model files (round trip, corruption), bad arrays, pickling."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from isa import _core
from isa.exceptions import (
    InvalidInputError,
    InvalidParameterError,
    IsaError,
    IsaIOError,
    ModelFormatError,
)
from isa.forest.model import Forest, ForestParams

TOY_PARAMS = dict(n_trees=3, max_depth=12, min_samples_split=4, min_samples_leaf=2, n_candidates=40,
                  max_offset=25.0, quality="Q1", vote_bandwidth_offset=0.02)


def toy(n_images=2, size=20):
    """Planes at 1 m; a part's SSC offset is the vector to the image centre (1 cm per pixel) and
    the rotation differs between the left and right half: learnable from the image borders."""
    images = [np.full((size, size), 1000, np.uint16) for _ in range(n_images)]
    parts = _core.sample_parts(images, stride=1)
    c = (size - 1) / 2
    off = np.stack([(c - parts[:, 1]) * 0.01, (c - parts[:, 2]) * 0.01, np.zeros(len(parts))], 1).astype(np.float32)
    ang = np.where(parts[:, 1] < size // 2, 0.0, 0.5)
    rot = np.stack([np.cos(ang / 2), 0 * ang, 0 * ang, np.sin(ang / 2)], 1).astype(np.float32)
    return images, parts, off, rot


def privileged(parts, n_links=3, n_nodes=2, seed=0):
    rng = np.random.default_rng(seed)
    la = (parts[:, 1:2] * 0.1 + rng.normal(0, 0.01, (len(parts), n_links))).astype(np.float32)
    no = (parts[:, 2:3] * 1.0 + rng.normal(0, 0.1, (len(parts), 3 * n_nodes))).astype(np.float32)
    return la, no


@pytest.fixture(scope="module")
def toy_forest():
    images, parts, off, rot = toy()
    f = Forest(**TOY_PARAMS).fit(images, parts, off, rot, metadata={"category": "toy", "ssc": [0, 0, 0]})
    return f, (images, parts, off, rot)


def test_toy_problem_is_recovered(toy_forest):
    f, (images, parts, off, rot) = toy_forest
    v = f.votes(images, parts)
    assert set(v) == {"part", "tree", "weight", "offset", "rotation"}
    assert v["offset"].shape == (len(v["part"]), 3) and v["rotation"].shape == (len(v["part"]), 4)
    assert np.all(np.diff(v["part"]) >= 0) and (v["weight"] > 0).all() and (v["weight"] <= 1).all()
    # The best vote of each (part, tree) recovers the offset within 3 cm and the rotation.
    first = np.ones(len(v["part"]), bool)
    first[1:] = (np.diff(v["part"]) != 0) | (np.diff(v["tree"]) != 0)
    p = v["part"][first]
    err = np.linalg.norm(v["offset"][first] - off[p], axis=1)
    dot = np.abs(np.sum(v["rotation"][first] * rot[p], axis=1))
    assert np.mean(err < 0.03) > 0.9, np.mean(err < 0.03)
    assert np.mean(dot > np.cos(0.05)) > 0.95
    # Averaged over trees (Eq. 13), the weighted offset is close everywhere.
    leaves = f.apply(images, parts)
    assert leaves.shape == (len(parts), 3) and leaves.dtype == np.int32
    w, o, r = f.leaf_votes(0, int(leaves[0, 0]))
    assert w.shape[0] == o.shape[0] == r.shape[0] >= 1


def test_privileged_terms_train_and_are_not_stored():
    images, parts, off, rot = toy()
    la, no = privileged(parts)
    f = Forest(**{**TOY_PARAMS, "quality": "Q1+Q2+Q3", "reduce_dims": 2}).fit(images, parts, off, rot, la, no)
    g = Forest(**{**TOY_PARAMS, "quality": "Q1+Q2+Q3", "reduce_dims": 2}).fit(images, parts, off, rot, la * 2, no + 1)
    # The privileged data changes the trees, but the model size does not grow with it.
    assert f.n_nodes and g.n_nodes
    q1 = Forest(**TOY_PARAMS).fit(images, parts, off, rot)
    bytes_per_node = len(f.to_bytes()) / sum(f.n_nodes)
    assert bytes_per_node < 2 * len(q1.to_bytes()) / sum(q1.n_nodes)
    with pytest.raises(InvalidInputError, match="link_angles"):
        Forest(**{**TOY_PARAMS, "quality": "Q1+Q2"}).fit(images, parts, off, rot)


def test_on_tree_reports_each_tree_and_its_errors_surface(toy_forest):
    _, (images, parts, off, rot) = toy_forest
    done = []
    f = Forest(**TOY_PARAMS)
    f.core.fit(_core.TrainSet(images, parts, off, rot), on_tree=done.append)
    assert done == [1, 2, 3]
    assert f.to_bytes() == Forest(**TOY_PARAMS).fit(images, parts, off, rot).to_bytes()  # the hook changes nothing

    def boom(k):
        raise RuntimeError(f"hook failed at tree {k}")

    with pytest.raises(RuntimeError, match="tree 1"):
        Forest(**TOY_PARAMS).core.fit(_core.TrainSet(images, parts, off, rot), on_tree=boom)
    Forest(**TOY_PARAMS).fit(images, parts, off, rot, progress=True)  # the tqdm bar drives the hook


def test_determinism_threads_in_process():
    images, parts, off, rot = toy()
    la, no = privileged(parts)
    kw = {**TOY_PARAMS, "quality": "Q1+Q2+Q3", "max_score_samples": 300, "bag_fraction": 0.8, "reduce_dims": 2}
    a = Forest(**kw, n_threads=1).fit(images, parts, off, rot, la, no).to_bytes()
    b = Forest(**kw, n_threads=2).fit(images, parts, off, rot, la, no).to_bytes()
    assert a == b
    c = Forest(**{**kw, "seed": 5}, n_threads=2).fit(images, parts, off, rot, la, no).to_bytes()
    assert a != c


def test_determinism_rayon_num_threads_subprocess(tmp_path):
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from test_forest import toy, privileged, TOY_PARAMS
        from isa.forest.model import Forest
        images, parts, off, rot = toy()
        la, no = privileged(parts)
        kw = {{**TOY_PARAMS, "quality": "Q1+Q2", "max_score_samples": 300}}
        Forest(**kw).fit(images, parts, off, rot, la, no).save(sys.argv[1])
        """
    )
    outs = []
    for threads in ("1", "2"):
        out = tmp_path / f"m{threads}.isa"
        env = {**os.environ, "RAYON_NUM_THREADS": threads}
        subprocess.run([sys.executable, "-c", script, str(out)], check=True, env=env)
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_save_load_roundtrip_and_metadata(toy_forest, tmp_path):
    f, (images, parts, _, _) = toy_forest
    path = tmp_path / "toy.isa"
    f.save(path)
    assert sorted(os.listdir(tmp_path)) == ["toy.isa"]  # atomic: no temporary left
    g = Forest.load(path)
    assert g == f and g.params == f.params
    meta = dict(g.metadata)
    # Training adds the counts of its data to what the trainer gave.
    assert meta.pop("training") == {"n_parts": len(parts), "n_images": len(images), "link_angle_dims": 0,
                                    "node_offset_dims": 0}
    assert meta == {"category": "toy", "ssc": [0, 0, 0]}
    np.testing.assert_array_equal(g.apply(images, parts), f.apply(images, parts))
    assert g.core.crate_version == _core.__version__


def test_pickled_forest_gives_the_same_votes(toy_forest):
    f, (images, parts, _, _) = toy_forest
    g = pickle.loads(pickle.dumps(f))
    a, b = f.votes(images, parts), g.votes(images, parts)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    core = pickle.loads(pickle.dumps(f.core))
    np.testing.assert_array_equal(core.votes(images, parts)["offset"], a["offset"])
    unfitted = pickle.loads(pickle.dumps(Forest(n_trees=3)))
    assert not unfitted.is_fitted and unfitted.params.n_trees == 3


def test_corrupt_model_files(toy_forest, tmp_path):
    f, _ = toy_forest
    good = f.to_bytes()
    cases = {
        "truncated": good[: len(good) // 2],
        "header_only": good[:20],
        "empty": b"",
        "flipped": good[:-5] + bytes([good[-5] ^ 0xFF]) + good[-4:],
        "foreign": b"\x89PNG\r\n\x1a\n" + b"\x00" * 64,
        "newer": good[:8] + (_core.MODEL_FORMAT_VERSION + 1).to_bytes(4, "little") + good[12:],
        "trailing": good + b"\x00",
    }
    for name, data in cases.items():
        p = tmp_path / f"{name}.isa"
        p.write_bytes(data)
        with pytest.raises(ModelFormatError) as e:
            Forest.load(p)
        assert str(p) in str(e.value)
        with pytest.raises(ModelFormatError):
            Forest.from_bytes(data)
    assert "newer" in str(pytest.raises(ModelFormatError, Forest.from_bytes, cases["newer"]).value)
    assert "magic" in str(pytest.raises(ModelFormatError, Forest.from_bytes, cases["foreign"]).value)
    with pytest.raises(IsaIOError):
        Forest.load(tmp_path / "missing.isa")
    with pytest.raises(FileNotFoundError):  # also the builtins
        Forest.load(tmp_path / "missing.isa")
    with pytest.raises(ValueError):
        Forest.from_bytes(b"")
    with pytest.raises(IsaIOError):
        f.save(tmp_path / "no" / "such" / "dir" / "m.isa")
    assert issubclass(ModelFormatError, IsaError) and issubclass(IsaIOError, IsaError)


def test_bad_arrays_raise_invalid_input():
    images, parts, off, rot = toy(n_images=1)
    f = Forest(**TOY_PARAMS)
    bad = {
        "dtype": (images, parts, off.astype(np.float64), rot),
        "shape": (images, parts, off[:, :2].copy(), rot),
        "rows": (images, parts, off[:-1].copy(), rot),
        "nan": (images, parts, np.where(np.arange(len(off))[:, None] == 3, np.nan, off).astype(np.float32), rot),
        "inf_rot": (images, parts, off, np.where(np.arange(len(rot))[:, None] == 2, np.inf, rot).astype(np.float32)),
        "noncontig": (images, parts, np.asfortranarray(off), rot),
        "strided": (images, parts, np.repeat(off, 2, axis=1)[:, ::2], rot),
        "parts_dtype": (images, parts.astype(np.int64), off, rot),
        "image_dtype": ([images[0].astype(np.float32)], parts, off, rot),
        "image_ndim": ([images[0][None]], parts, off, rot),
        "not_a_list": (images[0], parts, off, rot),
        "part_outside": (images, np.where(np.arange(len(parts))[:, None] == 0, [0, 99, 0], parts).astype(np.int32), off, rot),
        "part_no_depth": ([np.where(np.arange(400).reshape(20, 20) == 5, 0, images[0]).astype(np.uint16)], parts, off, rot),
        "zero_quat": (images, parts, off, np.zeros_like(rot)),
    }
    for name, args in bad.items():
        with pytest.raises(InvalidInputError) as e:
            f.fit(*args)
        assert str(e.value), name
    la = np.full((len(parts), 2), np.nan, np.float32)
    with pytest.raises(InvalidInputError, match="link_angles"):
        Forest(**{**TOY_PARAMS, "quality": "Q1+Q2"}).fit(images, parts, off, rot, la)
    with pytest.raises(InvalidInputError, match="not fitted"):
        f.votes(images, parts)


def test_bad_parameters():
    for kw in ({"n_trees": 0}, {"quality": "Q2"}, {"reg": -1.0}, {"bag_fraction": 1.5},
               {"min_samples_split": 2, "min_samples_leaf": 5}, {"n_thresholds": 0}, {"max_depth": 1.5}):
        with pytest.raises(InvalidParameterError):
            Forest(**kw)
    with pytest.raises(TypeError, match="bogus") as e:
        Forest(bogus=1)
    assert isinstance(e.value, IsaError)
    with pytest.raises(InvalidParameterError, match="bogus"):
        _core.Forest(bogus=1)
    with pytest.raises(InvalidParameterError, match="n_threads"):
        _core.Forest(n_threads=0)
    assert ForestParams(quality="q1 + q2").quality == "Q1+Q2"


def test_default_params_match_the_core():
    import json

    assert json.loads(_core.Forest().params_json) == ForestParams()._core_kwargs()


def test_errors_are_also_the_matching_builtins(tmp_path):
    from isa.exceptions import IsaFileNotFoundError, IsaIsADirectoryError

    missing = tmp_path / "missing.isa"
    e = pytest.raises(IsaFileNotFoundError, Forest.load, missing).value
    assert isinstance(e, FileNotFoundError) and isinstance(e, IsaIOError) and isinstance(e, IsaError)
    assert e.errno == 2 and e.filename == str(missing) and str(missing) in str(e)
    e = pytest.raises(IsaIsADirectoryError, Forest.load, tmp_path).value
    assert isinstance(e, IsADirectoryError) and e.filename == str(tmp_path)
    for cls in (InvalidInputError, InvalidParameterError, ModelFormatError):
        assert issubclass(cls, IsaError) and issubclass(cls, ValueError)
    with pytest.raises(ValueError, match="n_trees"):
        ForestParams(n_trees=0)


def test_forest_params_defaults_are_the_cores():
    import dataclasses

    fields = {f.name: f.default for f in dataclasses.fields(ForestParams)}
    assert fields == _core.FOREST_DEFAULTS
    with pytest.raises(InvalidParameterError, match="keyword arguments: n_trees: invalid type"):
        ForestParams(n_trees=2.5)
    with pytest.raises(InvalidParameterError, match="max_offset"):
        ForestParams(max_offset=float("nan"))


def test_inference_defaults_are_a_typed_field_of_the_model(toy_forest):
    f, (images, parts, off, rot) = toy_forest
    assert f.predict_defaults == _core.PREDICT_DEFAULTS
    g = Forest(**TOY_PARAMS).fit(images, parts, off, rot, metadata={"predict_defaults": {"stride": 3}},
                                 predict_defaults={"nms_radius": 0.5})
    assert g.predict_defaults == {**_core.PREDICT_DEFAULTS, "stride": 3, "nms_radius": 0.5}
    assert "predict_defaults" not in g.metadata
    assert Forest.from_bytes(g.to_bytes()).predict_defaults == g.predict_defaults
    # Format 2 holds the typed defaults; format 3 (leaf weights) is written only for weighted forests.
    assert g.to_bytes()[8:12] == (2).to_bytes(4, "little")
    assert _core.MODEL_FORMAT_VERSION == 3
    weighted = g.with_leaf_weights([np.ones(n, np.float32) for n in g.n_leaves])
    assert weighted.to_bytes()[8:12] == (3).to_bytes(4, "little")
    assert weighted.predict_defaults == g.predict_defaults
    with pytest.raises(InvalidParameterError, match="predict_defaults.*strid"):
        Forest(**TOY_PARAMS).fit(images, parts, off, rot, predict_defaults={"strid": 3})
    with pytest.raises(InvalidParameterError, match="metadata: predict_defaults"):
        Forest(**TOY_PARAMS).fit(images, parts, off, rot, metadata={"predict_defaults": {"stride": "a"}})


def test_a_format_1_model_loads_and_predicts_as_the_old_code_did():
    """``tests/data/model_v1.isa`` and what the code before format 2 predicted with it
    (``tests/data/make_model_v1.py``): its ``predict_defaults`` metadata is read into the typed
    field and applied by ``predict``."""
    import json
    import pathlib

    from test_vote import K, plate

    data = pathlib.Path(__file__).parent / "data"
    expected = json.loads((data / "model_v1.json").read_text())
    f = Forest.load(data / "model_v1.isa")
    assert f.metadata["category"] == "plate" and "predict_defaults" not in f.metadata
    assert {k: f.predict_defaults[k] for k in expected["predict_defaults"]} == expected["predict_defaults"]
    depth, _ = plate(centre=tuple(expected["centre"]))
    hyps = f.predict(depth, K)
    assert len(hyps) == len(expected["hypotheses"])
    for h, e in zip(hyps, expected["hypotheses"]):
        np.testing.assert_allclose(h.R, e["R"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(h["t"], e["t"], rtol=1e-9, atol=1e-12)
        assert h.score == pytest.approx(e["score"], rel=1e-9) and h["support"] == e["support"]


def test_hypotheses_are_typed_and_read_like_the_old_dicts(toy_forest):
    from collections.abc import Mapping

    from test_vote import K, plate

    f = Forest.load(__import__("pathlib").Path(__file__).parent / "data" / "model_v1.isa")
    depth, _ = plate(centre=(0.02, -0.01, 1.5))
    h = f.predict(depth, K)[0]
    assert isinstance(h, _core.Hypothesis) and isinstance(h, Mapping)
    d = dict(h)
    assert set(d) == {"R", "t", "pose", "quaternion", "score", "support", "position_score", "position_support"}
    assert h.to_dict()["support"] == d["support"] == h.support and list(h.keys()) == list(d)
    np.testing.assert_array_equal(h["R"], h.R)
    assert h.get("score") == h.score and h.get("nope", 7) == 7 and "t" in h and len(h) == 8
    with pytest.raises(KeyError):
        h["nope"]
    assert f.predict(depth, K, max_hypotheses=1)[0].score == h.score

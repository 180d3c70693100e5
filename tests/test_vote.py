"""Whole-image inference through Python: pose recovery on a synthetic plate, predict ==
find_modes(image_votes), parameter/argument errors, and the training-set file format."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest

from isa import _core
from isa.exceptions import InvalidInputError, InvalidParameterError

K = np.array([[200.0, 0.0, 63.5], [0.0, 200.0, 47.5], [0.0, 0.0, 1.0]])
FOREST_PARAMS = dict(n_trees=3, max_depth=14, min_samples_split=6, min_samples_leaf=3, n_candidates=60,
                     max_offset=60.0, quality="Q1")


def plate(width=128, height=96, K=K, centre=(0.0, 0.0, 1.5)):
    """A 0.4 m square plate facing the camera with a 0.1 m bump on its top-left quarter; its SSC
    is the plate centre. Returns uint16 depth (mm) and the SSC."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    z0 = centre[2]
    x, y = (u - cx) * z0 / fx - centre[0], (v - cy) * z0 / fy - centre[1]
    inside = (np.abs(x) < 0.2) & (np.abs(y) < 0.2)
    z = np.where(inside, z0, 0.0)
    bump = inside & (x < 0) & (y < 0)
    z = np.where(bump, z0 - 0.1, z)
    return np.round(z * 1000).astype(np.uint16), np.array(centre)


def backproject(depth, K):
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u, v = np.meshgrid(np.arange(depth.shape[1]), np.arange(depth.shape[0]))
    z = depth / 1000.0
    return np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], -1)


def plate_training_set(centres=((0.0, 0.0, 1.5), (0.05, -0.03, 1.4), (-0.04, 0.02, 1.6))):
    """Plates at ``centres``: images, parts (stride 2), SSC offsets and identity rotations."""
    images, ssc = [], []
    for c in centres:
        d, s = plate(centre=c)
        images.append(d)
        ssc.append(s)
    parts = _core.sample_parts(images, stride=2)
    offsets = np.stack([ssc[i] - backproject(images[i], K)[v, u] for i, u, v in parts]).astype(np.float32)
    rotations = np.tile(np.array([1, 0, 0, 0], np.float32), (len(parts), 1))
    return images, parts, offsets, rotations


@pytest.fixture(scope="module")
def trained():
    images, parts, offsets, rotations = plate_training_set()
    f = _core.Forest(**FOREST_PARAMS)
    f.fit(_core.TrainSet(images, parts, offsets, rotations))
    return f, images, parts, offsets, rotations


def test_recovers_the_plate_in_a_larger_frame(trained):
    f = trained[0]
    Kbig = K.copy()
    Kbig[0, 2], Kbig[1, 2] = 159.5, 119.5
    depth, ssc = plate(320, 240, Kbig, centre=(0.3, -0.1, 1.5))
    hyps = f.predict(depth, Kbig, stride=2)
    assert hyps, "no hypothesis"
    best = hyps[0]
    assert set(best) == {"R", "t", "pose", "quaternion", "score", "support", "position_score", "position_support"}
    assert best["R"].shape == (3, 3) and best["t"].shape == (3,) and best["quaternion"].shape == (4,)
    assert np.linalg.norm(best["t"] - ssc) < 0.03, best
    assert np.allclose(best["R"], np.eye(3), atol=0.05)
    assert [h["score"] for h in hyps] == sorted((h["score"] for h in hyps), reverse=True)
    # float metres give the same answer as uint16 mm; so do the three forms of K
    same = f.predict(depth.astype(np.float32) / 1000, (Kbig[0, 0], Kbig[1, 1], Kbig[0, 2], Kbig[1, 2]), stride=2)
    assert np.allclose(same[0]["t"], best["t"]) and same[0]["score"] == best["score"]
    from isa.camera import Intrinsics

    intr = Intrinsics.from_K(Kbig, 320, 240)
    assert f.predict(depth, intr, stride=2)[0]["score"] == best["score"]
    # deterministic across thread counts
    one = f.predict(depth, Kbig, stride=2, n_threads=1)
    assert all(np.array_equal(a["t"], b["t"]) and a["score"] == b["score"] for a, b in zip(one, hyps))


def test_predict_equals_find_modes_of_image_votes(trained):
    f = trained[0]
    depth, _ = plate()
    v = f.image_votes(depth, K, stride=3)
    n = len(v["weight"])
    assert v["position"].shape == (n, 3) and v["rotation"].shape == (n, 4) and v["pixel"].shape == (n, 2)
    assert v["position"].dtype == np.float32 and v["pixel"].dtype == np.int32 and v["tree"].dtype == np.int32
    assert (v["pixel"] % 3 == 0).all() and set(np.unique(v["tree"])) == {0, 1, 2}
    assert v["n_parts"] == int((depth[::3, ::3] > 0).sum())
    assert np.all(v["weight"] <= 1 / 3 + 1e-7)
    a = f.predict(depth, K, stride=3, max_hypotheses=3)
    b = _core.find_modes(v["position"], v["rotation"], v["weight"], max_hypotheses=3)
    assert len(a) == len(b) <= 3
    for x, y in zip(a, b):
        assert np.array_equal(x["t"], y["t"]) and x["score"] == y["score"]


def test_find_modes_sign_free_and_defaults():
    rng = np.random.default_rng(0)
    pos = (np.array([0.1, 0.2, 2.0]) + rng.normal(0, 0.01, (500, 3))).astype(np.float32)
    q = np.array([0.5, 0.5, 0.5, 0.5], np.float32)
    rot = np.tile(q, (500, 1)) * np.where(rng.random(500) < 0.5, -1, 1)[:, None].astype(np.float32)
    h = _core.find_modes(pos, rot)
    assert np.allclose(h[0]["t"], [0.1, 0.2, 2.0], atol=0.005)
    assert np.allclose(h[0]["quaternion"], q, atol=1e-5)
    d = _core.default_predict_params()
    assert d["stride"] == 4 and d["max_hypotheses"] == 5 and d["max_depth"] is None


def test_errors_name_the_argument(trained):
    f = trained[0]
    depth, _ = plate()
    with pytest.raises(InvalidParameterError, match="stride"):
        f.predict(depth, K, stride=0)
    with pytest.raises(InvalidParameterError, match="bandwdith"):
        f.predict(depth, K, position_bandwdith=0.1)
    with pytest.raises(InvalidParameterError, match="position_bandwidth"):
        _core.find_modes(np.zeros((1, 3), np.float32), np.ones((1, 4), np.float32), position_bandwidth=-1.0)
    with pytest.raises(InvalidInputError, match="depth"):
        f.predict(depth.astype(np.int32), K)
    with pytest.raises(InvalidInputError, match="depth"):
        f.predict(depth[None], K)
    with pytest.raises(InvalidInputError, match="K"):
        f.predict(depth, "K")
    with pytest.raises(InvalidInputError, match="focal"):
        f.predict(depth, (0.0, 1.0, 2.0, 3.0))
    with pytest.raises(InvalidInputError, match="not fitted"):
        _core.Forest().predict(depth, K)
    with pytest.raises(InvalidInputError, match="rotations"):
        _core.find_modes(np.zeros((2, 3), np.float32), np.ones((3, 4), np.float32))


def _entries(raw: bytes) -> dict[str, object]:
    """Reads a .isat file with struct + numpy only (the documented layout)."""
    assert raw[:8] == b"ISATRAIN"
    version, n = struct.unpack_from("<II", raw, 8)
    assert version == _core.TRAINSET_FORMAT_VERSION == 1
    at, out = 16, {}
    for _ in range(n):
        (nl,) = struct.unpack_from("<I", raw, at)
        name = raw[at + 4: at + 4 + nl].decode()
        at += 4 + nl
        kind, length = struct.unpack_from("<BQ", raw, at)
        at += 9
        blob = raw[at: at + length]
        at += length
        out[name] = np.lib.format.read_array(io.BytesIO(blob)) if kind == 0 else blob.decode()
    assert at == len(raw) - 8
    return out


def test_a_training_set_brings_its_metadata_to_fit_unless_fit_is_given_one(trained):
    _, images, parts, offsets, rotations = trained
    ts = _core.TrainSet(images, parts, offsets, rotations, metadata='{"category": "plate"}')
    assert len(ts) == len(parts) and ts.n_images == len(images)
    own, given, other = (_core.Forest(**FOREST_PARAMS) for _ in range(3))
    own.fit(ts)
    given.fit(_core.TrainSet(images, parts, offsets, rotations), metadata='{"category": "plate"}')
    other.fit(ts, metadata='{"category": "disc"}')
    assert own.to_bytes() == given.to_bytes()
    assert json.loads(own.metadata)["category"] == "plate"
    assert json.loads(other.metadata)["category"] == "disc"


def test_trainset_file_round_trip_and_numpy_readable(trained, tmp_path):
    _, images, parts, offsets, rotations = trained
    la = np.random.default_rng(1).normal(size=(len(parts), 2)).astype(np.float32)
    path = tmp_path / "t.isat"
    _core.TrainSet(images, parts, offsets, rotations, link_angles=la, metadata='{"category": "plate"}').write(path)
    back = _core.read_trainset(path)
    assert len(back["images"]) == 3 and all(np.array_equal(a, b) for a, b in zip(back["images"], images))
    for k, want in [("parts", parts), ("offsets", offsets), ("rotations", rotations), ("link_angles", la)]:
        assert np.array_equal(back[k], want), k
    assert back["node_offsets"] is None and back["metadata"] == '{"category": "plate"}'
    e = _entries(path.read_bytes())
    assert np.array_equal(e["image_sizes"], [[96, 128]] * 3)
    assert np.array_equal(e["depth"], np.concatenate([i.ravel() for i in images]))
    assert np.array_equal(e["offsets"], offsets) and e["metadata"] == '{"category": "plate"}'
    # corrupt / wrong files are named
    raw = bytearray(path.read_bytes())
    raw[100] ^= 0xFF
    bad = tmp_path / "bad.isat"
    bad.write_bytes(bytes(raw))
    with pytest.raises(InvalidInputError, match="bad.isat.*checksum"):
        _core.read_trainset(bad)
    with pytest.raises(InvalidInputError, match="parts\\[0\\]"):
        p2 = parts.copy()
        p2[0] = [0, 0, 0]  # a corner of the image: no depth there
        _core.TrainSet(images, p2, offsets, rotations)

"""The forest's criterion terms Q1, Q2, Q3 (paper Eq. 9-11) against an independent NumPy
reference, and the Eq. 5 features against a NumPy implementation.

The reference follows the documented pipeline of ``isa-core/src/criterion.rs``: 6D rotation
representation (first two columns of R), link angles as (cos, sin), per-dimension
standardisation over the parts (std < 1e-6 -> 1), optional PCA of the link/node blocks, targets
stored as float32, biased covariances + reg * I, Q1 entropy = log(|S_dx| + |S_theta|).
"""

from __future__ import annotations

import numpy as np
import pytest

from isa import _core
from isa._core import _testing

REL = 1e-6


# ---------------------------------------------------------------- NumPy reference -------------
def quat_to_6d(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    r00 = 1 - 2 * (y * y + z * z)
    r10 = 2 * (x * y + w * z)
    r20 = 2 * (x * z - w * y)
    r01 = 2 * (x * y - w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r21 = 2 * (y * z + w * x)
    return np.stack([r00, r10, r20, r01, r11, r21], axis=1)


def standardise(x: np.ndarray) -> np.ndarray:
    x = x - x.mean(axis=0)
    sd = x.std(axis=0)
    return x / np.where(sd < 1e-6, 1.0, sd)


def pca(x: np.ndarray, k: int) -> np.ndarray:
    cov = x.T @ x / len(x)
    _, vecs = np.linalg.eigh(cov)
    return x @ vecs[:, ::-1][:, :k]


def reference_blocks(off, rot, la=None, no=None, reduce_dims=0):
    blocks = {"off": off.astype(np.float64), "rot": quat_to_6d(rot)}
    if la is not None:
        a = la.astype(np.float64)
        e = np.empty((len(a), 2 * a.shape[1]))
        e[:, 0::2], e[:, 1::2] = np.cos(a), np.sin(a)
        blocks["links"] = e
    if no is not None:
        blocks["nodes"] = no.astype(np.float64)
    out = {}
    for k, x in blocks.items():
        x = standardise(x)
        if k in ("links", "nodes") and 0 < reduce_dims < x.shape[1]:
            x = pca(x, reduce_dims)
        out[k] = x.astype(np.float32).astype(np.float64)  # the core stores targets as float32
    return out


def logdet(x: np.ndarray, reg: float) -> float:
    c = np.cov(x, rowvar=False, bias=True).reshape(x.shape[1], x.shape[1]) if len(x) > 1 else np.zeros((x.shape[1],) * 2)
    sign, ld = np.linalg.slogdet(c + reg * np.eye(x.shape[1]))
    assert sign > 0
    return ld


def entropies(b: dict[str, np.ndarray], idx: np.ndarray, reg: float) -> dict[str, float]:
    h = {"Q1": np.logaddexp(logdet(b["off"][idx], reg), logdet(b["rot"][idx], reg))}
    if "links" in b:
        h["Q2"] = logdet(b["links"][idx], reg)
    if "nodes" in b:
        h["Q3"] = logdet(b["nodes"][idx], reg)
    return h


def reference_gains(off, rot, la, no, mask, reg=1e-4, reduce_dims=0) -> dict[str, float]:
    b = reference_blocks(off, rot, la, no, reduce_dims)
    n = len(off)
    all_idx = np.arange(n)
    left, right = all_idx[mask], all_idx[~mask]
    hp, hl, hr = entropies(b, all_idx, reg), entropies(b, left, reg), entropies(b, right, reg)
    return {k: hp[k] - len(left) / n * hl[k] - len(right) / n * hr[k] for k in hp}


# ---------------------------------------------------------------- data --------------------------
def random_targets(rng, n, n_links=18, n_nodes=11):
    off = rng.normal(0, 0.3, (n, 3)).astype(np.float32)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    la = rng.uniform(-np.pi, np.pi, (n, n_links)).astype(np.float32)
    no = np.concatenate(
        [rng.normal(0, 80, (n, n_nodes, 2)), rng.normal(0, 0.4, (n, n_nodes, 1))], axis=2
    ).reshape(n, 3 * n_nodes).astype(np.float32)
    return off, q, la, no


def assert_close(got: dict, want: dict) -> None:
    assert set(got) == set(want)
    for k in want:
        assert np.isfinite(got[k]), (k, got[k])
        assert abs(got[k] - want[k]) <= REL * max(abs(want[k]), 1e-3), (k, got[k], want[k])


# ---------------------------------------------------------------- tests -------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("terms", ["Q1", "Q1+Q2", "Q1+Q3", "Q1+Q2+Q3"])
def test_gains_match_numpy_on_random_data(seed, terms):
    rng = np.random.default_rng(seed)
    n = 500
    off, q, la, no = random_targets(rng, n)
    la = la if "Q2" in terms else None
    no = no if "Q3" in terms else None
    # A split correlated with the targets, so the gains are far from zero.
    mask = (off[:, 0] + rng.normal(0, 0.2, n) > 0)
    got = _testing.criterion_gains((off, q, la, no), mask)
    assert_close(got, reference_gains(off, q, la, no, mask))


@pytest.mark.parametrize("reg", [1e-6, 1e-4, 1e-2])
def test_gains_match_numpy_for_every_reg_and_random_masks(reg):
    rng = np.random.default_rng(7)
    off, q, la, no = random_targets(rng, 300, n_links=4, n_nodes=3)
    for _ in range(5):
        mask = rng.random(300) < rng.uniform(0.1, 0.9)
        got = _testing.criterion_gains((off, q, la, no), mask, reg=reg)
        assert_close(got, reference_gains(off, q, la, no, mask, reg=reg))


def test_gains_with_dimension_reduction_match_numpy():
    rng = np.random.default_rng(3)
    n = 800
    off, q, _, _ = random_targets(rng, n)
    # Well separated principal directions so the top-k subspaces are unambiguous.
    la = (rng.normal(size=(n, 10)) * np.linspace(1.5, 0.05, 10)).astype(np.float32)
    base = rng.normal(size=(n, 12)) * np.geomspace(50, 0.01, 12)
    no = (base @ np.linalg.qr(rng.normal(size=(12, 12)))[0]).astype(np.float32)
    mask = off[:, 1] > 0.1
    for k in (2, 4):
        got = _testing.criterion_gains((off, q, la, no), mask, reduce_dims=k)
        assert_close(got, reference_gains(off, q, la, no, mask, reduce_dims=k))


def test_degenerate_nodes_are_finite_and_match_numpy():
    rng = np.random.default_rng(5)
    n = 60
    off, q, la, no = random_targets(rng, n, n_links=3, n_nodes=2)
    # Identical rotations and link angles everywhere (one view), one-part left child.
    q[:] = q[0]
    la[:] = la[0]
    mask = np.zeros(n, bool)
    mask[7] = True
    got = _testing.criterion_gains((off, q, la, no), mask)
    assert_close(got, reference_gains(off, q, la, no, mask))
    # A left child whose targets are all identical.
    off2 = off.copy()
    off2[:30] = off2[0]
    no2 = no.copy()
    no2[:30] = no2[0]
    mask = np.arange(n) < 30
    got = _testing.criterion_gains((off2, q, la, no2), mask)
    assert_close(got, reference_gains(off2, q, la, no2, mask))
    # Two parts only.
    got = _testing.criterion_gains((off[:2], q[:2], la[:2], no[:2]), np.array([True, False]))
    assert_close(got, reference_gains(off[:2], q[:2], la[:2], no[:2], np.array([True, False])))


def test_rotation_representation_is_continuous():
    """Q1 sees q and -q as the same rotation (the 6D representation has no double cover)."""
    rng = np.random.default_rng(9)
    off, q, _, _ = random_targets(rng, 200)
    mask = rng.random(200) < 0.5
    flipped = np.where(rng.random((200, 1)) < 0.5, -q, q).astype(np.float32)
    a = _testing.criterion_gains((off, q, None, None), mask)["Q1"]
    b = _testing.criterion_gains((off, flipped, None, None), mask)["Q1"]
    assert abs(a - b) <= 1e-9 * max(1.0, abs(a))


def test_criterion_targets_layout():
    rng = np.random.default_rng(4)
    off, q, la, no = random_targets(rng, 50, n_links=5, n_nodes=2)
    t, dims = _testing.criterion_targets((off, q, la, no), reduce_dims=0)
    assert dims == [3, 6, 10, 6] and t.shape == (50, 25) and t.dtype == np.float32
    ref = reference_blocks(off, q, la, no)
    np.testing.assert_allclose(t, np.concatenate([ref[k] for k in ("off", "rot", "links", "nodes")], 1), atol=1e-6)
    t, dims = _testing.criterion_targets((off, q, la, no), reduce_dims=3)
    assert dims == [3, 6, 3, 3]


def test_bad_criterion_inputs():
    rng = np.random.default_rng(4)
    off, q, la, no = random_targets(rng, 20)
    with pytest.raises(_core.InvalidInputError, match="left_mask"):
        _testing.criterion_gains((off, q, None, None), np.zeros(20, bool))
    with pytest.raises(_core.InvalidInputError, match="left_mask"):
        _testing.criterion_gains((off, q, None, None), np.zeros(20, np.int8))
    with pytest.raises(_core.InvalidParameterError, match="reg"):
        _testing.criterion_gains((off, q, None, None), np.arange(20) < 5, reg=0.0)


# ---------------------------------------------------------------- features ----------------------
def reference_features(images, parts, u, v, background=10_000.0):
    out = np.empty((len(parts), len(u)), np.float32)
    for i, (k, x, y) in enumerate(parts):
        img = images[k]
        inv = np.float32(1000.0) / np.float32(img[y, x])

        def probe(off):
            px = x + np.floor(off[:, 0] * inv + np.float32(0.5)).astype(np.int64)
            py = y + np.floor(off[:, 1] * inv + np.float32(0.5)).astype(np.int64)
            inside = (px >= 0) & (px < img.shape[1]) & (py >= 0) & (py < img.shape[0])
            d = np.full(len(off), background, np.float32)
            d[inside] = img[py[inside], px[inside]]
            d[d == 0] = background
            return d

        out[i] = probe(u) - probe(v)
    return out


def test_depth_features_match_numpy():
    rng = np.random.default_rng(11)
    images = []
    for _ in range(3):
        h, w = rng.integers(20, 50, 2)
        img = rng.integers(500, 4000, (h, w)).astype(np.uint16)
        img[rng.random((h, w)) < 0.2] = 0
        images.append(img)
    parts = _core.sample_parts(images, stride=3)
    u = rng.uniform(-40, 40, (25, 2)).astype(np.float32)
    v = rng.uniform(-40, 40, (25, 2)).astype(np.float32)
    got = _core.depth_features(images, parts, u, v)
    np.testing.assert_array_equal(got, reference_features(images, parts, u, v))
    assert _core.BACKGROUND_MM == 10_000.0


def test_sample_parts_grid_and_cap():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 3, (13, 17)).astype(np.uint16)
    parts = _core.sample_parts([img, img], stride=2)
    vv, uu = np.nonzero(img[::2, ::2])
    one = np.stack([np.zeros_like(uu), uu * 2, vv * 2], 1)
    np.testing.assert_array_equal(parts, np.concatenate([one, one + [1, 0, 0]]).astype(np.int32))
    capped = _core.sample_parts([img, img], stride=1, max_per_image=10, seed=3)
    assert capped.shape == (20, 3)
    assert (img[capped[:, 2], capped[:, 1]] > 0).all()
    np.testing.assert_array_equal(capped, _core.sample_parts([img, img], stride=1, max_per_image=10, seed=3))

"""Every error that crosses into Python is an ``isa.IsaError`` that is also the matching builtin
(issue 20: bare OverflowError / TypeError / "RuntimeError: Already borrowed" before), values the
docs forbid are refused, and property tests (hypothesis) of the array checks: any array either
works or raises an isa error naming the argument."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from isa import _core
from isa.exceptions import InvalidInputError, InvalidParameterError, InvalidTypeError, IsaError
from isa.forest.model import Forest

PARAMS = dict(n_trees=2, max_depth=6, min_samples_split=4, min_samples_leaf=2, n_candidates=10, max_offset=25.0,
              quality="Q1", vote_bandwidth_offset=0.02)
K = (40.0, 40.0, 11.5, 11.5)


def _set(seed: int = 0, size: int = 24):
    rng = np.random.default_rng(seed)
    images = [(1000 + rng.integers(0, 300, (size, size))).astype(np.uint16) for _ in range(2)]
    parts = _core.sample_parts(images, stride=2)
    off = rng.normal(0, 0.05, (len(parts), 3)).astype(np.float32)
    q = rng.normal(size=(len(parts), 4))
    rot = (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)
    return images, parts, off, rot


@pytest.fixture(scope="module")
def fitted():
    data = _set()
    return Forest(**PARAMS).fit(*data), data


def _raises(builtin, call, *words):
    with pytest.raises(IsaError) as e:
        call()
    assert isinstance(e.value, builtin), f"{type(e.value).__mro__} is not a {builtin}"
    for w in words:
        assert w in str(e.value), str(e.value)
    return e.value


@pytest.mark.parametrize("bad", [-1, -2, 0, 2**70, -(2**70)])
def test_n_threads_out_of_range_is_an_isa_value_error(fitted, bad):
    f, (images, parts, *_) = fitted
    depth = images[0]
    _raises(ValueError, lambda: _core.Forest(n_threads=bad), "n_threads")
    _raises(ValueError, lambda: Forest(n_threads=bad, **PARAMS), "n_threads")
    _raises(ValueError, lambda: f.predict(depth, K, n_threads=bad), "n_threads")
    _raises(ValueError, lambda: _core.Forest.from_bytes(f.to_bytes()).__setattr__("n_threads", bad), "n_threads")
    _raises(ValueError, lambda: _core.find_modes(np.zeros((1, 3), np.float32), np.eye(1, 4, dtype=np.float32),
                                                 n_threads=bad), "n_threads")


def test_wrong_types_are_isa_type_errors(fitted):
    f, (images, *_) = fitted
    _raises(TypeError, lambda: _core.Forest(n_threads="2"), "n_threads")
    _raises(TypeError, lambda: _core.Forest(n_threads=1.5), "n_threads")
    e = _raises(TypeError, lambda: f.predict(images[0], SimpleNamespace(fx="a", fy=40.0, cx=11.5, cy=11.5)), "K.fx")
    assert isinstance(e, InvalidTypeError) and isinstance(e, InvalidInputError)
    _raises(TypeError, lambda: _core.Forest.from_bytes("abc"), "data")
    _raises(TypeError, lambda: _core.Forest.load(123), "path")
    _raises(TypeError, lambda: f._core.save(None), "path")
    _raises(TypeError, lambda: _core.Forest(**PARAMS).fit(_core.TrainSet(*_set()), metadata=3), "metadata")
    _raises(TypeError, lambda: _core.sample_parts(images, stride="4"), "stride")


def test_buffers_of_bytes_are_model_bytes(fitted):
    f, _ = fitted
    b = f.to_bytes()
    for buf in (memoryview(b), bytearray(b), np.frombuffer(b, np.uint8)):
        assert _core.Forest.from_bytes(buf).to_bytes() == b
    g = _core.Forest()
    g.__setstate__(memoryview(b))
    assert g.to_bytes() == b


def test_negative_counts_and_indices(fitted):
    f, (images, *_) = fitted
    for bad in (-1, 0, 2**70):
        _raises(ValueError, lambda: _core.sample_parts(images, stride=bad), "stride")
    _raises(ValueError, lambda: _core.sample_parts(images, seed=-1), "seed")
    _raises(ValueError, lambda: _core.sample_parts(images, max_per_image=-3), "max_per_image")
    _raises(ValueError, lambda: f.leaf_votes(-1, 0), "tree")
    _raises(ValueError, lambda: f.leaf_votes(0, 2**70), "leaf")
    _raises(ValueError, lambda: f.leaf_votes(0, 10**6), "no leaf")


def test_unknown_forest_parameter_is_an_isa_error():
    # TypeError like any unexpected keyword argument (the core's own Forest: a parameter error).
    _raises(TypeError, lambda: Forest(foo=1), "foo")
    _raises(ValueError, lambda: _core.Forest(foo=1), "foo")
    assert issubclass(InvalidParameterError, IsaError)


def test_values_the_docs_forbid_are_refused(fitted):
    f, (images, parts, off, rot) = fitted
    # Issue 20: Python predict took a principal point at -1e6 (the CLI refused it).
    _raises(ValueError, lambda: f.predict(images[0], (40.0, 40.0, -1e6, 11.5)), "principal point")
    _raises(ValueError, lambda: f.predict(images[0], (40.0, 40.0, 11.5, 24.0)), "principal point")
    # Issue 20: fit took quaternions of norm 5 or 1e30 (the docs say unit).
    for scale in (5.0, 1e30, 0.0):
        bad = rot.copy()
        bad[3] *= np.float32(scale)
        _raises(ValueError, lambda: Forest(**PARAMS).fit(images, parts, off, bad), "rotations[3]")
        _raises(ValueError, lambda: _core.TrainSet(images, parts, off, bad).write("/nonexistent/x.isat"), "rotations[3]")


def test_a_forest_shared_by_threads_predicts_while_another_changes_it():
    # Issue 20: setting n_threads or fitting while another thread predicted raised
    # "RuntimeError: Already borrowed".
    a, b = _set(1), _set(2)
    f = Forest(**PARAMS).fit(*a)
    depth = a[0][0]
    before = [h.t.tolist() for h in f.predict(depth, K)]
    after_forest = Forest(**PARAMS).fit(*b)
    after = [h.t.tolist() for h in after_forest.predict(depth, K)]
    errors: list[BaseException] = []
    seen: list[list] = []
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            try:
                seen.append([h.t.tolist() for h in f.predict(depth, K)])
                f.leaf_votes(0, 0)
            except BaseException as exc:  # noqa: BLE001 - every failure is the finding
                errors.append(exc)
                return

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    try:
        for k in range(20):
            f.n_threads = 1 + k % 2
            f._core.n_threads = None
        f.fit(*b)
        for _ in range(5):
            f.predict(depth, K)
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert errors == []
    assert seen and all(s in (before, after) for s in seen)
    assert [h.t.tolist() for h in f.predict(depth, K)] == after


# ---------------------------------------------------------------------------------------------
# Property tests of the array checks.

DTYPES = st.sampled_from([np.uint8, np.uint16, np.int32, np.int64, np.float16, np.float32, np.float64, np.bool_])
PROPS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROPS
@given(mm=hnp.arrays(np.uint16, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=30),
                     elements=st.integers(0, 3000)),
       dtype=DTYPES, transpose=st.booleans())
def test_predict_takes_any_array_or_names_it(fitted, mm, dtype, transpose):
    f, _ = fitted
    depth = mm.astype(dtype) / (1000 if np.dtype(dtype).kind == "f" else 1)
    depth = depth.astype(dtype)
    if transpose and depth.ndim == 2:
        depth = depth.T  # not C-contiguous
    ok_dtype = depth.dtype in (np.uint16, np.float32, np.float64)
    big = depth.ndim >= 2 and depth.shape[0] >= 12 and depth.shape[1] >= 12
    # An (H, W, 3) array is an organised point cloud, read as float whatever its dtype.
    cloud = depth.ndim == 3 and depth.shape[2] == 3
    ok = big and ((ok_dtype and depth.ndim == 2 and depth.flags.c_contiguous) or cloud)
    try:
        hyps = f.predict(depth, K)
    except IsaError as e:
        assert not ok, f"valid depth {depth.dtype} {depth.shape} refused: {e}"
        assert "depth" in str(e) or "principal point" in str(e), str(e)
        return
    assert ok, f"invalid depth {depth.dtype} {depth.shape} accepted"
    assert all(np.isfinite(h.t).all() and np.isfinite(h.quaternion).all() for h in hyps)


@pytest.mark.parametrize("shape", [(0, 0, 3), (0, 5, 3), (5, 0, 3)])
def test_empty_point_cloud_names_depth(fitted, shape):
    # An empty organised cloud is refused with the argument's name (a draw the property test
    # above can make, pinned here).
    f, _ = fitted
    with pytest.raises(IsaError, match="depth"):
        f.predict(np.zeros(shape, np.float32), K)


@PROPS
@given(parts=hnp.arrays(st.sampled_from([np.int32, np.int64, np.float32]),
                        st.tuples(st.integers(0, 6), st.integers(1, 4)), elements=st.integers(-30, 30)))
def test_apply_takes_any_parts_array_or_names_it(fitted, parts):
    f, (images, *_) = fitted
    inside = (parts.ndim == 2 and parts.shape[1] == 3 and parts.dtype == np.int32
              and bool(((parts[:, 0] >= 0) & (parts[:, 0] < 2) & (parts[:, 1] >= 0) & (parts[:, 1] < 24)
                        & (parts[:, 2] >= 0) & (parts[:, 2] < 24)).all()))
    try:
        leaves = f.apply(images, parts)
    except IsaError as e:
        assert not inside, f"valid parts refused: {e}"
        assert "parts" in str(e), str(e)
        return
    assert inside and leaves.shape == (len(parts), 2)


@PROPS
@given(rot=hnp.arrays(np.float32, st.tuples(st.just(5), st.integers(3, 5)),
                      elements=st.floats(-2, 2, width=32) | st.sampled_from([np.nan, np.inf, 1e30])))
def test_fit_takes_any_rotation_array_or_names_it(rot):
    images, parts, off, _ = _set(size=8)
    parts, off = parts[:5], off[:5]
    norms = np.linalg.norm(rot.astype(np.float64), axis=1) if rot.shape[1] == 4 else None
    ok = norms is not None and bool(np.all(np.abs(norms - 1) <= 1e-3))
    try:
        _core.Forest(**{**PARAMS, "min_samples_split": 2, "min_samples_leaf": 1}).fit(_core.TrainSet(images, parts, off, rot))
    except IsaError as e:
        assert not ok, f"valid rotations refused: {e}"
        assert "rotations" in str(e), str(e)
        return
    assert ok, f"invalid rotations accepted: {rot}"

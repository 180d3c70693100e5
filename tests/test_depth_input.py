"""Depth as users have it (issue 19, item 4): ``depth_scale`` (uint16 millimetres, TUM's 5000 per
metre, 0.1 mm, float metres, float millimetres), the image size against the intrinsics
(transposed images), point clouds as input, the 4x4 pose, and the readers of the sensor formats
in ``../shared/data/real_unannotated``. Every wrong-scale or transposed case must raise or warn:
none may return a silently wrong pose."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from isa import InputWarning, _core
from isa.camera import Intrinsics, depth_from_points
from isa.exceptions import InvalidInputError, InvalidParameterError
from test_vote import K, plate, trained  # noqa: F401  (trained: the module's fixture)

KBIG = K.copy()
KBIG[0, 2], KBIG[1, 2] = 159.5, 119.5
INTR = Intrinsics.from_K(KBIG, 320, 240)


@pytest.fixture(scope="module")
def scene(trained):  # noqa: F811
    """The trained plate forest, a 320x240 frame of the plate (uint16 mm), its SSC, and the best
    hypothesis on the millimetre image (the reference every other unit must reproduce)."""
    f = trained[0]
    depth, ssc = plate(320, 240, KBIG, centre=(0.3, -0.1, 1.5))
    best = f.predict(depth, INTR, stride=2)[0]
    assert np.linalg.norm(best.t - ssc) < 0.03
    return f, depth, ssc, best


def quiet(fn, *a, **kw):
    """``fn(*a, **kw)`` with every warning an error (no InputWarning allowed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*a, **kw)


@pytest.mark.parametrize("name, values, scale", [
    ("tum", lambda mm: mm.astype(np.uint32) * 5, 0.2),            # 5000 per metre
    ("0.1 mm", lambda mm: mm.astype(np.uint32) * 10, 0.1),
    ("float metres", lambda mm: mm / 1000.0, None),
    ("float mm", lambda mm: mm.astype(np.float32), 1.0),
])
def test_every_unit_with_its_depth_scale_gives_the_same_pose(scene, name, values, scale):
    f, depth, _, best = scene
    v = values(depth)
    if v.dtype == np.uint32:
        v = v.astype(np.uint16)  # the plate at 1.5 m: 7500 / 15000 units fit in 16 bits
    got = quiet(f.predict, np.ascontiguousarray(v), INTR, stride=2, depth_scale=scale)[0]
    np.testing.assert_allclose(got.t, best.t, atol=1e-9)
    assert got.score == pytest.approx(best.score, rel=1e-9)


@pytest.mark.parametrize("name, values", [
    ("float mm read as metres", lambda mm: mm.astype(np.float32)),
    ("0.1 mm read as mm", lambda mm: (mm.astype(np.uint32) * 10).astype(np.uint16)),
    ("metres read as mm", lambda mm: (mm / 1000.0).astype(np.float32)),
])
def test_a_wrong_scale_warns_naming_depth_scale(scene, name, values):
    f, depth, ssc, _ = scene
    kw = {"depth_scale": 1.0} if name == "metres read as mm" else {}
    with pytest.warns(InputWarning, match="depth_scale") as rec:
        hyps = f.predict(values(depth), INTR, stride=2, **kw)
    assert "median" in str(rec[0].message)
    # Whatever comes back is not the plate's pose passed off as right: the warning said so.
    assert not hyps or np.linalg.norm(hyps[0].t - ssc) > 0.1


def test_bad_depth_scale_and_keywords_are_parameter_errors(scene):
    f, depth, _, _ = scene
    for bad in (0, -1.0, 1e9):
        with pytest.raises(InvalidParameterError, match="depth_scale"):
            f.predict(depth, INTR, depth_scale=bad)
    with pytest.raises(InvalidParameterError, match="depth_scal"):
        f.predict(depth, INTR, depth_scal=1.0)


def test_a_transposed_image_is_an_error_with_a_sized_camera_and_a_warning_without(scene):
    f, depth, _, _ = scene
    t = np.ascontiguousarray(depth.T)
    with pytest.raises(InvalidInputError, match="transposed"):
        f.predict(t, INTR)
    with pytest.raises(InvalidInputError, match="transposed"):
        _core.depth_to_metres(t, INTR)
    with pytest.raises(InvalidInputError, match="wrong-size"):
        f.predict(depth[:200], INTR)
    with pytest.warns(InputWarning, match="transposed"):
        f.predict(t, KBIG)  # a bare 3x3 matrix carries no size
    quiet(f.predict, depth, KBIG)  # the right way round: no warning


def test_point_clouds_organised_or_not_give_the_depth_images_pose(scene):
    f, depth, _, best = scene
    pts = INTR.backproject(depth / 1000.0)  # (H, W, 3), metres
    got = quiet(f.predict, pts, INTR, stride=2)[0]
    np.testing.assert_allclose(got.t, best.t, atol=1e-6)
    flat = pts.reshape(-1, 3)
    flat = flat[flat[:, 2] > 0][np.random.default_rng(0).permutation(int((depth > 0).sum()))]
    d = depth_from_points(flat, INTR)
    np.testing.assert_allclose(d, depth / 1000.0, atol=1e-6)
    got = quiet(f.predict, d, INTR, stride=2)[0]
    np.testing.assert_allclose(got.t, best.t, atol=1e-6)
    # A cloud in millimetres: its depth_scale, as for images.
    got = quiet(f.predict, pts * 1000.0, INTR, stride=2, depth_scale=1.0)[0]
    np.testing.assert_allclose(got.t, best.t, atol=1e-6)
    with pytest.raises(InvalidInputError):
        depth_from_points(flat, KBIG)  # no size anywhere
    assert depth_from_points(flat, KBIG, size=(320, 240)).shape == (240, 320)


def test_the_pose_matrix_is_r_and_t(scene):
    best = scene[3]
    T = best.pose
    assert T.shape == (4, 4)
    np.testing.assert_array_equal(T[:3, :3], best.R)
    np.testing.assert_array_equal(T[:3, 3], best.t)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(dict(best)["pose"], T)
    x = np.array([0.1, -0.2, 0.3])
    np.testing.assert_allclose((T @ np.append(x, 1))[:3], best.R @ x + best.t)


def test_depth_to_metres_is_predicts_conversion():
    depth, _ = plate(320, 240, KBIG, centre=(0.3, -0.1, 1.5))
    m = quiet(_core.depth_to_metres, depth, INTR)
    np.testing.assert_array_equal(m, depth.astype(np.float32) / np.float32(1000))
    tum = quiet(_core.depth_to_metres, (depth.astype(np.uint32) * 5).astype(np.uint16), INTR, 0.2)
    np.testing.assert_allclose(tum, m, atol=1e-7)
    with pytest.warns(InputWarning, match="median 1500"):
        _core.depth_to_metres(depth.astype(np.float32), INTR)

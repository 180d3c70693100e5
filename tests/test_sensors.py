"""Readers of real sensors' depth formats (``isa.data.sensors``): the NYU raw-disparity formula
on a PGM written here (analytic), and on the real frames of ``../shared/data/real_unannotated``
each reader's depth is plausible for the sensor (no ``InputWarning`` from the core's check) while
the raw values read with the wrong unit draw one."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from isa import InputWarning, _core
from isa.camera import KINECT_V1
from isa.data import sensors
from isa.data.sunrgbd import decode_sun_depth
from isa.exceptions import DataError


def test_nyu_pgm_follows_the_nyu_toolbox(tmp_path):
    raw = np.array([[839, 1000, 2047], [0, 1092, 700]], dtype="<u2")
    p = tmp_path / "f.pgm"
    p.write_bytes(b"P5\n3 2\n65535\n" + raw.tobytes())
    want = 351.3 / (1092.5 - raw.astype(float))
    want[0, 2] = 0.0                       # 2047: no reading
    want = np.minimum(want, 10.0)           # the toolbox's far clip (1092 -> 702 m)
    np.testing.assert_allclose(sensors.read_nyu_pgm(p), want.astype(np.float32), rtol=1e-6)
    p.write_bytes(b"P5\n3 2\n65535\n" + raw.tobytes()[:5])
    with pytest.raises(DataError, match="truncated"):
        sensors.read_nyu_pgm(p)
    with pytest.raises(DataError, match="unknown kind"):
        sensors.read_depth(p, "kinect")


def _plausible(depth, K=KINECT_V1, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = _core.depth_to_metres(np.ascontiguousarray(depth), K, **kw)
    v = m[m > 0]
    assert v.size > 0.5 * m.size and 0.5 < np.median(v) < 6.0, np.median(v)
    return m


def test_real_frames_read_plausibly_and_raw_units_warn(shared_data):
    root = shared_data / "real_unannotated"
    o3d = root / "open3d_rgbd"
    tum = sensors.read_tum_depth(o3d / "TUM_depth.png")
    _plausible(tum)
    raw = sensors._read_png16(o3d / "TUM_depth.png")
    np.testing.assert_allclose(_plausible(raw, depth_scale=0.2), tum, atol=1e-6)
    with pytest.warns(InputWarning, match="depth_scale"):
        _core.depth_to_metres(raw, KINECT_V1)   # 5000 per metre read as millimetres: ~12 m
    _plausible(sensors.read_depth(o3d / "NYU_depth.pgm", "nyu-pgm"))
    sun = sensors.read_depth(o3d / "SUN_depth.png", "sun")
    np.testing.assert_array_equal(sun, decode_sun_depth(sensors._read_png16(o3d / "SUN_depth.png")))
    _plausible(sun)
    frames = sensors.read_nyu_annotated(root / "nyu_depth_v2")
    assert len(frames) == 3
    for path, depth, K in frames:
        assert (K.width, K.height) == (640, 480) and K.fx == pytest.approx(518.8579)
        np.testing.assert_array_equal(depth, sensors.read_depth(path, "mm"))
        _plausible(depth, K)


def test_real_sun_frames_in_both_layouts_read_plausibly(shared_data):
    from isa.data.sunrgbd import read_native, read_processed

    root = shared_data / "real_unannotated"
    native = read_native(root / "sunrgbd_kv2_office", annotations=False)
    side = read_processed(root / "sunrgbd_000005", 5)  # one frame's files side by side
    for f in (native, side):
        assert f.depth.shape == (f.intrinsics.height, f.intrinsics.width)
        _plausible(f.depth, f.intrinsics)
    assert side.boxes == ()

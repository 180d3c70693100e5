"""SUN RGB-D readers: synthetic round trips, the two real shared frames, and malformed inputs."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.io import loadmat, savemat

from isa.data.sunrgbd import (
    UPRIGHT_FROM_CAMERA_AXES,
    decode_sun_depth,
    list_native,
    list_processed,
    read_native,
    read_processed,
)
from isa.evaluation.boxes3d import Box3D
from isa.exceptions import DataError

NATIVE = Path("sunrgbd/SUNRGBD/kv1/b3dodata/img_0063")
PROCESSED = Path("sunrgbd/sunrgbd_trainval")


def encode_sun_depth(mm: np.ndarray) -> np.ndarray:
    """SUN RGB-D's storage: millimetres rotated left by 3 bits on 16 bits (inverse of the reader)."""
    mm = mm.astype(np.uint16)
    return (mm << 3) | (mm >> 13)


def rot_x(a):
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def footprint_fraction(box: Box3D, pts: np.ndarray) -> float:
    """Share of the points above/below the box's footprint that lie inside the box."""
    in_fp = box.contains(np.column_stack([pts[:, :2], np.full(len(pts), box.centre[2])]))
    return float(box.contains(pts).sum() / in_fp.sum())


def floor_tilt_deg(pts: np.ndarray) -> float:
    """Angle between z and the normal of a plane fitted to the lowest points (the floor)."""
    z0 = np.percentile(pts[:, 2], 1)
    sel = pts[np.abs(pts[:, 2] - z0) < 0.05]
    _, _, vt = np.linalg.svd(sel - sel.mean(0), full_matrices=False)
    return math.degrees(math.acos(abs(vt[2, 2])))


# ---------------------------------------------------------------------------------------------- depth codec


def test_decode_sun_depth_inverts_the_bit_rotation():
    mm = np.array([[0, 1, 1000], [4321, 8000, 8191]], dtype=np.uint16)
    raw = encode_sun_depth(mm)
    assert raw[0, 2] == 8000  # 1000 mm is stored as 8000
    d = decode_sun_depth(raw)
    assert d.dtype == np.float32
    np.testing.assert_array_equal(d, mm.astype(np.float32) / np.float32(1000))


def test_decode_rejects_plain_millimetres_and_wrong_types():
    rng = np.random.default_rng(1)
    plain_mm = rng.integers(500, 4000, size=(20, 30)).astype(np.uint16)
    with pytest.raises(DataError, match="bit-rotated"):
        decode_sun_depth(plain_mm, "x.png")
    with pytest.raises(DataError, match="uint16"):
        decode_sun_depth(plain_mm.astype(np.uint8), "x.png")


# ---------------------------------------------------------------------------------------------- processed: synthetic


def write_processed(root: Path, depth: np.ndarray, K1: np.ndarray, Rtilt: np.ndarray, labels: str, fid="000007"):
    """A processed-layout frame made the way VoteNet's MATLAB export makes it: 1-based pixel grid,
    depth-frame axes (x, z, -y), Rtilt, column-major order, invalid pixels dropped."""
    h, w = depth.shape
    x, y = np.meshgrid(np.arange(1, w + 1), np.arange(1, h + 1))
    x3 = (x - K1[0, 2]) * depth / K1[0, 0]
    y3 = (y - K1[1, 2]) * depth / K1[1, 1]
    pts = np.stack([x3.T.ravel(), depth.T.ravel(), -y3.T.ravel()], 1)[depth.T.ravel() > 0]
    up = pts @ Rtilt.T
    inst = np.column_stack([up, np.full((len(up), 3), 0.5)]).astype(np.float32)
    for sub in ("depth", "calib", "label", "image"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    savemat(root / "depth" / f"{fid}.mat", {"instance": inst})
    (root / "calib" / f"{fid}.txt").write_text(
        " ".join(f"{v:.17g}" for v in Rtilt.ravel(order="F")) + "\n" + " ".join(f"{v:.17g}" for v in K1.ravel(order="F")) + "\n"
    )
    (root / "label" / f"{fid}.txt").write_text(labels)
    Image.new("RGB", (w, h)).save(root / "image" / f"{fid}.jpg")
    return inst


def test_processed_synthetic_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    h, w = 24, 32
    depth = rng.uniform(0.8, 6.0, size=(h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.2] = 0
    K1 = np.array([[40.0, 0, 16.5], [0, 41.0, 12.5], [0, 0, 1]])
    Rtilt = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]) @ rot_x(-0.3) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    labels = "bed 1 2 3 4 0.5 3.0 -0.7 0.9 1.1 0.5 0.6 -0.8\nnight stand 0 0 1 1 1 2 -1 0.2 0.3 0.25 1 0\n\n"
    write_processed(tmp_path, depth, K1, Rtilt, labels)
    f = read_processed(tmp_path, 7)
    assert f.name == "000007" and f.depth.shape == (h, w)
    np.testing.assert_allclose(f.depth, depth, rtol=1e-6, atol=0)  # float32 storage only
    assert np.array_equal(f.depth > 0, depth > 0)
    # 0-based intrinsics: back-projecting pixel (u, v) is SUN's 1-based (u + 1, v + 1).
    assert (f.intrinsics.cx, f.intrinsics.cy) == (15.5, 11.5)
    # The gravity rotation levels the camera: its optical axis (0, 0, 1) points 0.3 rad downwards.
    axis_up = f.R_gravity @ [0, 0, 1.0]
    assert math.degrees(math.asin(-axis_up[2])) == pytest.approx(math.degrees(0.3))
    bed, stand = f.boxes
    assert bed.category == "bed" and stand.category == "night stand"
    np.testing.assert_allclose(bed.centre, [0.5, 3.0, -0.7])
    np.testing.assert_allclose(bed.size, [2.2, 1.8, 1.0])  # (2 hl, 2 hw, 2 hh): length along heading
    assert bed.yaw == pytest.approx(math.atan2(-0.8, 0.6))


def test_processed_size_fallback_without_image(tmp_path):
    depth = np.full((10, 14), 2.0, np.float32)
    write_processed(tmp_path, depth, np.array([[20.0, 0, 7.5], [0, 20.0, 5.5], [0, 0, 1]]), np.eye(3), "")
    (tmp_path / "image" / "000007.jpg").unlink()
    f = read_processed(tmp_path, "000007")
    assert f.depth.shape == (10, 14) and f.boxes == ()


# ---------------------------------------------------------------------------------------------- real frames


def test_native_real_frame(shared_data):
    f = read_native(shared_data / NATIVE)
    assert f.depth.shape == (427, 561) and f.depth.dtype == np.float32
    valid = f.depth[f.depth > 0]
    assert valid.size > 0.5 * f.depth.size
    # An office seen by a Kinect v1 from ~1.2 m: everything between 1 and 3 m.
    assert 1.0 < valid.min() and valid.max() < 3.0
    assert f.intrinsics.width == 561 and f.intrinsics.fx == pytest.approx(520.532)
    np.testing.assert_allclose(f.R_gravity @ f.R_gravity.T, np.eye(3), atol=1e-5)
    # Gravity: the floor is level in the upright frame (it is ~11 deg off without the tilt).
    assert floor_tilt_deg(f.points_upright()) < 3.0
    assert floor_tilt_deg(f.points_camera() @ UPRIGHT_FROM_CAMERA_AXES.T) > 8.0
    # 10 annotated objects, 3 of them null (deleted in SUN's tool): skipped.
    assert sorted(b.category for b in f.boxes) == sorted(
        ["bookshelf", "bookshelf", "chair", "projector", "books", "books", "switch"])
    pts = f.points_upright()
    floor = np.percentile(pts[:, 2], 1)
    (chair,) = f.boxes_of("chair")
    # The stacked chairs lean on a wall that rises above the box inside its footprint (~62 %).
    assert footprint_fraction(chair, pts) > 0.55
    assert chair.z_range[0] == pytest.approx(floor, abs=0.06)  # stands on the floor
    for shelf in f.boxes_of("bookshelf"):
        assert footprint_fraction(shelf, pts) > 0.93
        swapped = shelf.replace(size=shelf.size[[1, 0, 2]])
        assert shelf.contains(pts).sum() > 1.4 * swapped.contains(pts).sum()


def test_native_filled_depth_has_fewer_holes(shared_data):
    raw = read_native(shared_data / NATIVE, annotations=False)
    filled = read_native(shared_data / NATIVE, filled=True, annotations=False)
    assert raw.boxes == () and np.count_nonzero(filled.depth) > np.count_nonzero(raw.depth)
    both = (raw.depth > 0) & (filled.depth > 0)
    assert np.median(np.abs(raw.depth[both] - filled.depth[both])) < 0.01


def test_processed_real_frame_reprojects_to_the_cloud(shared_data):
    root = shared_data / PROCESSED
    f = read_processed(root, 1)
    cloud = loadmat(root / "depth" / "000001.mat")["instance"][:, :3].astype(np.float64)
    assert f.depth.shape == (530, 730)
    assert np.count_nonzero(f.depth) == len(cloud)
    valid = f.depth[f.depth > 0]
    assert 1.0 < valid.min() and valid.max() <= 8.0 + 1e-4  # SUN clips depth at 8 m
    # MATLAB wrote the valid pixels column by column: pixel k (column-major) is point k.
    X = f.intrinsics.backproject(f.depth).transpose(1, 0, 2)[(f.depth > 0).T]
    err = np.linalg.norm(np.einsum("ij,nj->ni", f.R_gravity, X) - cloud, axis=1)
    assert err.max() < 1e-4  # measured 2.5e-5 m: the calib rounds Rtilt to 5 digits
    assert floor_tilt_deg(f.points_upright()) < 3.0
    assert [b.category for b in f.boxes] == ["bed", "night_stand", "ottoman", "dresser_mirror", "dresser", "lamp"]
    pts = f.points_upright()
    (bed,) = f.boxes_of("bed")
    assert footprint_fraction(bed, pts) > 0.95  # measured 0.999
    assert bed.z_range[0] == pytest.approx(np.percentile(pts[:, 2], 1), abs=0.05)
    # Length runs along the heading: exchanging length and width loses most of the bed.
    assert bed.contains(pts).sum() > 2 * bed.replace(size=bed.size[[1, 0, 2]]).contains(pts).sum()
    # Heading mirrored (VoteNet's clockwise angle read as counter-clockwise) fits worse.
    assert footprint_fraction(bed.replace(yaw=-bed.yaw), pts) < 0.9
    assert list_processed(root) == ["000001"]
    assert shared_data / NATIVE in list_native(shared_data / "sunrgbd")


# ---------------------------------------------------------------------------------------------- malformed


def _copy_without_images(src, dst):
    """A copy of a shared SUN RGB-D folder (no RGB images) that a test may break."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("image"))
    return dst


@pytest.fixture
def native_copy(shared_data, tmp_path):
    return _copy_without_images(shared_data / NATIVE, tmp_path / "img_0063")


def test_native_missing_files(native_copy):
    (native_copy / "intrinsics.txt").unlink()
    with pytest.raises(DataError, match="intrinsics.txt: missing"):
        read_native(native_copy)


def test_native_missing_extrinsics(native_copy):
    shutil.rmtree(native_copy / "extrinsics")
    with pytest.raises(DataError, match="no extrinsics"):
        read_native(native_copy)


def test_native_wrong_bit_layout(native_copy):
    # The same depth saved as plain millimetres (a common mistake when converting the data).
    png = native_copy / "depth" / "img_0063_abs.png"
    mm = np.rint(read_native(native_copy, annotations=False).depth * 1000).astype(np.uint16)
    Image.fromarray(mm).save(png)
    with pytest.raises(DataError, match=r"img_0063_abs\.png.*bit-rotated"):
        read_native(native_copy)
    Image.fromarray((mm // 256).astype(np.uint8)).save(png)
    with pytest.raises(DataError, match="16-bit"):
        read_native(native_copy)


def _edit_annotation(folder: Path, edit) -> Path:
    path = folder / "annotation3Dfinal" / "index.json"
    data = json.loads(path.read_text())
    data = edit(data)
    path.write_text(json.dumps(data))
    return path


def test_native_null_annotation_entries(native_copy):
    def null_x(d):
        chair = next(o for o in d["objects"] if o and o["name"] == "chair")
        chair["polygon"][0]["X"] = None
        return d

    _edit_annotation(native_copy, null_x)
    with pytest.raises(DataError, match=r"index\.json: object 4 \(chair\): null"):
        read_native(native_copy)

    _edit_annotation(native_copy, lambda d: (d["objects"][0]["polygon"][0].update(Ymax=None), d)[1])
    with pytest.raises(DataError, match=r"object 0 \(bookshelf\): null polygon coordinates in Ymax"):
        read_native(native_copy)

    _edit_annotation(native_copy, lambda d: None)
    with pytest.raises(DataError, match="'objects' list"):
        read_native(native_copy)


def test_native_polygon_less_objects_are_skipped(native_copy):
    # Objects labelled in 2D only (no 3D polygon) are not ground truth, as in the SUN toolbox.
    _edit_annotation(native_copy, lambda d: (d["objects"][4].update(polygon=[]), d)[1])
    assert "chair" not in {b.category for b in read_native(native_copy).boxes}


def test_native_missing_annotation(native_copy):
    (native_copy / "annotation3Dfinal" / "index.json").unlink()
    with pytest.raises(DataError, match="annotation3Dfinal/index.json"):
        read_native(native_copy)
    assert read_native(native_copy, annotations=False).boxes == ()


@pytest.fixture
def processed_copy(shared_data, tmp_path):
    return _copy_without_images(shared_data / PROCESSED, tmp_path / "sunrgbd_trainval")


def test_processed_missing_calib(processed_copy):
    (processed_copy / "calib" / "000001.txt").unlink()
    with pytest.raises(DataError, match=r"calib/000001\.txt: missing calibration"):
        read_processed(processed_copy, 1)


def test_processed_wrong_calib_or_subsampled_cloud(processed_copy):
    calib = processed_copy / "calib" / "000001.txt"
    lines = calib.read_text().splitlines()
    calib.write_text("1 0 0 0 1 0 0 0 1\n" + lines[1] + "\n")  # Rtilt dropped
    with pytest.raises(DataError, match="integer pixels"):
        read_processed(processed_copy, 1)
    calib.write_text("1 2 3\n")
    with pytest.raises(DataError, match="two lines of 9"):
        read_processed(processed_copy, 1)


def test_processed_bad_label_and_mat(processed_copy):
    (processed_copy / "label" / "000001.txt").write_text("bed 1 2 3 4 0 3 0 0.5 0.5 nan 1 0\n")
    with pytest.raises(DataError, match=r"000001\.txt:1: invalid box"):
        read_processed(processed_copy, 1)
    (processed_copy / "label" / "000001.txt").write_text("bed 1 2\n")
    with pytest.raises(DataError, match=r"000001\.txt:1: expected"):
        read_processed(processed_copy, 1)
    mat = processed_copy / "depth" / "000001.mat"
    mat.write_bytes(b"MATLAB 7.3 MAT-file".ljust(116) + bytes(8) + b"\x00\x02IM" + bytes(400))
    with pytest.raises(DataError, match="v7.3"):
        read_processed(processed_copy, 1)
    savemat(mat, {"points": np.zeros((3, 6), np.float32)})
    with pytest.raises(DataError, match="no 'instance'"):
        read_processed(processed_copy, 1)

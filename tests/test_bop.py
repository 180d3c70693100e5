"""BOP scenewise format: exact write -> read round trip, BOP field conventions, models, errors,
atomic writes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from isa.camera import Intrinsics
from isa.data import bop
from isa.exceptions import DataError

K = Intrinsics(fx=575.8, fy=576.3, cx=319.5, cy=239.5, width=64, height=48)


def _frames(n=3, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        mm = rng.integers(0, 4000, size=(K.height, K.width)).astype(np.uint16)
        mm[rng.random(mm.shape) < 0.3] = 0
        depth = bop.png_to_depth(mm)  # float32 metres on the millimetre grid
        R = Rotation.random(random_state=seed + i).as_matrix()
        t = rng.uniform(-1, 1, 3) + [0, 0, 3]
        out.append((depth, mm > 0, R, t, mm))
    return out


def test_round_trip_is_exact(tmp_path):
    frames = _frames()
    with bop.SceneWriter(tmp_path, "train", 7) as w:
        for i, (depth, mask, R, t, _) in enumerate(frames):
            w.write_frame(i * 5, depth, mask, K, R, t, obj_id=3)
    assert bop.list_scenes(tmp_path, "train") == [7]
    assert bop.list_frames(tmp_path, "train", 7) == [0, 5, 10]
    back = bop.read_scene(tmp_path, "train", 7)
    for (depth, mask, R, t, _), f in zip(frames, back):
        np.testing.assert_array_equal(f.depth, depth)  # bit-exact float32
        np.testing.assert_array_equal(f.mask, mask)
        np.testing.assert_array_equal(f.R, R)  # JSON keeps a float's exact repr
        np.testing.assert_allclose(f.t, t, rtol=0, atol=1e-12)  # stored in mm
        assert f.intrinsics == K and f.obj_id == 3 and f.scene_id == 7 and f.depth_scale == 1.0
    # Raw files follow the BOP conventions, checked without isa's reader.
    d = tmp_path / "train" / "000007"
    raw = np.asarray(Image.open(d / "depth" / "000005.png"))
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw, frames[1][4])
    m = np.asarray(Image.open(d / "mask" / "000005_000000.png"))
    assert m.dtype == np.uint8 and set(np.unique(m)) <= {0, 255}
    gt = json.loads((d / "scene_gt.json").read_text())["5"][0]
    assert gt["cam_t_m2c"] == [float(x) * 1000.0 for x in frames[1][3]] and gt["obj_id"] == 3
    assert len(gt["cam_R_m2c"]) == 9
    cam = json.loads((d / "scene_camera.json").read_text())["5"]
    assert cam["cam_K"] == K.K.reshape(-1).tolist() and cam["depth_scale"] == 1.0
    info = json.loads((d / "scene_gt_info.json").read_text())["5"][0]
    ys, xs = np.nonzero(frames[1][1])
    assert info["bbox_obj"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
    assert info["px_count_visib"] == frames[1][1].sum()


def test_frame_sequence_reads_the_eager_frames_on_access(tmp_path):
    frames = _frames(5)
    for sid, (ids, obj) in {4: ([0, 3], 2), 9: ([1, 2, 7], 5)}.items():
        with bop.SceneWriter(tmp_path, "train", sid) as w:
            for k, im in enumerate(ids):
                depth, mask, R, t, _ = frames[k + (sid == 9) * 2]
                w.write_frame(im, depth, mask, K, R, t, obj_id=obj)
    eager = bop.read_scene(tmp_path, "train", 4) + bop.read_scene(tmp_path, "train", 9)
    lazy = bop.FrameSequence(tmp_path, "train")
    assert len(lazy) == 5 and lazy.obj_ids == [2, 2, 5, 5, 5]
    assert [(f.scene_id, f.im_id) for f in lazy] == [(4, 0), (4, 3), (9, 1), (9, 2), (9, 7)]
    for a, b in zip(eager, lazy):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
    assert [f.im_id for f in lazy[1:4]] == [3, 1, 2] and lazy[-1].im_id == 7
    with pytest.raises(IndexError):
        lazy[5]
    # Mapped copies follow their base item by item; obj_ids need no image.
    mapped = bop.MappedFrames(lazy, [(4, None), (0, lambda f: f.im_id)])
    assert mapped.obj_ids == [5, 2] and mapped[0].im_id == 7 and mapped[1] == 0 and len(mapped) == 2


def test_depth_scale_tenth_mm(tmp_path):
    depth = np.full((K.height, K.width), 1.23456, np.float32)
    with bop.SceneWriter(tmp_path, "test", 1, depth_scale=0.1) as w:
        w.write_frame(0, depth, depth > 0, K, np.eye(3), [0, 0, 1.2], 1)
    f = bop.read_frame(tmp_path, "test", 1, 0)
    assert np.abs(f.depth - depth).max() <= 0.05e-3 + 1e-7  # half a 0.1 mm step
    assert np.asarray(Image.open(tmp_path / "test" / "000001" / "depth" / "000000.png"))[0, 0] == 12346


def test_depth_too_far_for_uint16():
    with pytest.raises(ValueError, match="exceeds uint16"):
        bop.depth_to_png(np.array([[70.0]]))


def test_models_round_trip_and_info(tmp_path):
    box = trimesh.creation.box(extents=(0.4, 0.6, 1.2))
    bop.write_model(tmp_path, 2, box)
    back = bop.read_model(tmp_path, 2)
    np.testing.assert_allclose(np.sort(back.vertices, 0), np.sort(box.vertices, 0), atol=1e-9)
    raw = trimesh.load(tmp_path / "models" / "obj_000002.ply", process=False)
    np.testing.assert_allclose(raw.extents, [400, 600, 1200], atol=1e-6)  # millimetres on disk
    info = bop.model_info(box)
    assert info["diameter"] == pytest.approx(np.sqrt(400**2 + 600**2 + 1200**2))
    assert (info["min_x"], info["size_z"]) == pytest.approx((-200, 1200))
    bop.write_models_info(tmp_path, {2: info})
    assert bop.read_models_info(tmp_path) == {2: info}


def test_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="scene_gt.json"):
        bop.list_frames(tmp_path, "train", 1)
    with pytest.raises(DataError, match="nosplit"):
        bop.list_scenes(tmp_path, "nosplit")
    with bop.SceneWriter(tmp_path, "train", 1) as w:
        w.write_frame(0, np.ones((K.height, K.width), np.float32), np.ones((K.height, K.width), bool), K, np.eye(3), [0, 0, 1], 1)
    d = tmp_path / "train" / "000001"
    with pytest.raises(DataError, match="image 3"):
        bop.read_frame(tmp_path, "train", 1, 3)
    (d / "depth" / "000000.png").unlink()
    with pytest.raises(DataError, match="000000.png"):
        bop.read_frame(tmp_path, "train", 1, 0)
    (d / "scene_gt.json").write_text("{ broken")
    with pytest.raises(DataError, match="scene_gt.json.*JSON"):
        bop.read_frame(tmp_path, "train", 1, 0)


def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    w = bop.SceneWriter(tmp_path, "train", 1)
    depth = np.ones((K.height, K.width), np.float32)

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", boom)
    with pytest.raises(OSError, match="disk full"):
        w.write_frame(0, depth, depth > 0, K, np.eye(3), [0, 0, 1], 1)
    monkeypatch.undo()
    w.close()
    files = [p for p in (tmp_path / "train" / "000001").rglob("*") if p.is_file()]
    assert files == []  # no temp file, no half frame, no JSON entry
    assert not w.has_frame(0)

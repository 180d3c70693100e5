"""Synthetic rooms in BOP: the ground truth lands on the right mesh, visibility matches an
analytic occlusion, bop_toolkit's parsing reads the files, runs are reproducible and resumable.

The tests sharing the ``clean_root`` room are marked slow: preparing the procedural chairs (the
skeleton template) and searching their turn symmetry take seconds before anything renders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from isa.data import bop
from isa.camera import Intrinsics
from isa.scenes import read_scene_dataset
from isa.scenes.cameras import Camera, CameraRig, camera_pose
from isa.scenes.sources import procedural
from isa.scenes.writer import Placement, SceneFolder, SceneSpec, make_scenes, ray_factor, render_frame, _Renderers

SMALL = Intrinsics(fx=291.3, fy=291.3, cx=159.77, cy=119.62, width=320, height=240)
RIG = CameraRig(intrinsics=SMALL, distance=(1.5, 3.0))


@pytest.fixture(scope="module")
def source():
    return procedural(["chair"], seed=7, n=2)


def _make(root, source, **kw):
    kw = {"n_scenes": 1, "views_per_scene": 2, "seed": 3, "noise": False, "n_instances": (3, 3), "rig": RIG,
          "progress": False, **kw}
    return make_scenes(root, "test", source, **kw)


@pytest.fixture(scope="module")
def clean_root(tmp_path_factory, source):
    root = tmp_path_factory.mktemp("rooms")
    _make(root, source)
    return root


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_visible_pixels_lie_on_their_own_mesh(clean_root):
    frames = read_scene_dataset(clean_root, "test")
    assert len(frames) == 2
    meshes = {}
    checked = 0
    for f in frames:
        P = f.intrinsics.backproject(f.depth)
        d = bop.scene_dir(clean_root, "test", f.scene_id)
        for k, g in enumerate(f.gt):
            visib = bop.read_png(d / "mask_visib" / f"{f.im_id:06d}_{k:06d}.png") > 0
            if visib.sum() < 200:
                continue
            if g.obj_id not in meshes:
                m = bop.read_model(clean_root, g.obj_id)
                meshes[g.obj_id] = cKDTree(trimesh.sample.sample_surface(m, 300000, seed=0)[0])
            X = P[visib]
            own = meshes[g.obj_id].query((X - g.t) @ g.R)[0]  # R^T (X - t), row-wise
            assert np.median(own) < 0.002 and np.percentile(own, 95) < 0.004, (f.im_id, k, np.median(own))
            for j, h in enumerate(f.gt):  # mapped by another instance's pose, they miss that mesh
                if j != k and h.obj_id in meshes:
                    other = meshes[h.obj_id].query((X - h.t) @ h.R)[0]
                    assert np.median(other) > 0.03
            checked += 1
    assert checked >= 2


def test_visib_fract_of_a_box_half_behind_another():
    # Level camera at height 0.5 looking along +y. Box B (1 m cube) stands 3.5-4.5 m ahead,
    # centred; box A (1 x 0.2 x 1.4 m) 2.9-3.1 m ahead covers x < 0 (its right edge is on the
    # optical axis' plane x = 0). B shows only its front face, and its left half is behind A:
    # the visible pixels are the columns whose centres fall in [cx, cx + f * 0.5 / 3.5].
    K = SMALL
    R, t = camera_pose((0.0, 0.0, 0.5), np.pi / 2, 0.0)
    cam = Camera(R, t, K)
    B = trimesh.creation.box(extents=(1, 1, 1), transform=trimesh.transformations.translation_matrix((0, 4, 0.5)))
    A = trimesh.creation.box(extents=(1, 0.2, 1.4), transform=trimesh.transformations.translation_matrix((-0.5, 3, 0.5)))
    spec = SceneSpec(trimesh.util.concatenate([A, B]), [Placement(1, np.eye(3), np.zeros(3), B),
                                                        Placement(2, np.eye(3), np.zeros(3), A)], [cam])
    r = _Renderers(K)
    try:
        _, found = render_frame(spec, cam, r, None, 0)
    finally:
        r.close()
    info_b = found[0][1]
    half_u = K.fx * 0.5 / 3.5
    half_v = K.fy * 0.5 / 3.5
    u = np.arange(K.width)
    v = np.arange(K.height)
    cols_all = np.sum(np.abs(u - K.cx) <= half_u)
    cols_vis = np.sum((u >= K.cx) & (u - K.cx <= half_u))
    rows = np.sum(np.abs(v - K.cy) <= half_v)
    assert abs(info_b["px_count_all"] - cols_all * rows) <= cols_all + rows  # a pixel of rasterisation
    assert abs(info_b["px_count_visib"] - cols_vis * rows) <= cols_vis + rows
    assert info_b["visib_fract"] == pytest.approx(cols_vis / cols_all, abs=0.02)
    assert found[1][1]["visib_fract"] == 1.0  # nothing hides A


def _load_json_keys_to_int(path):
    # bop_toolkit_lib.inout.load_json(path, keys_to_int=True), as written there.
    def convert(x):
        return {int(k) if k.lstrip("-").isdigit() else k: v for k, v in x.items()}

    with open(path) as f:
        return json.load(f, object_hook=convert)


@pytest.mark.slow
def test_bop_toolkit_parsing_reads_the_files(clean_root):
    d = bop.scene_dir(clean_root, "test", 0)
    gt = _load_json_keys_to_int(d / "scene_gt.json")
    cam = _load_json_keys_to_int(d / "scene_camera.json")
    info = _load_json_keys_to_int(d / "scene_gt_info.json")
    models = _load_json_keys_to_int(clean_root / "models" / "models_info.json")
    camera = json.loads((clean_root / "camera.json").read_text())
    assert sorted(gt) == sorted(cam) == sorted(info) == [0, 1]
    for im_id, gts in gt.items():
        K = np.array(cam[im_id]["cam_K"], np.float64).reshape((3, 3))
        assert K[0, 0] == camera["fx"] and K[1, 2] == camera["cy"]
        depth = np.asarray(Image.open(d / "depth" / f"{im_id:06d}.png")).astype(np.float32) * cam[im_id]["depth_scale"]
        assert depth.shape == (camera["height"], camera["width"])
        assert len(gts) == len(info[im_id]) > 0
        fac = ray_factor(SMALL)
        for k, g in enumerate(gts):
            R = np.array(g["cam_R_m2c"], np.float64).reshape((3, 3))
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
            assert np.array(g["cam_t_m2c"], np.float64).reshape((3, 1))[2, 0] > 0
            assert g["obj_id"] in models and models[g["obj_id"]]["isa_category"] == "chair"
            mask = np.asarray(Image.open(d / "mask" / f"{im_id:06d}_{k:06d}.png")) > 0
            visib = np.asarray(Image.open(d / "mask_visib" / f"{im_id:06d}_{k:06d}.png")) > 0
            e = info[im_id][k]
            # bop_toolkit's counts from our masks and stored depth (noise off: clean depth).
            assert e["px_count_visib"] == visib.sum() and e["px_count_valid"] == int((depth[mask] > 0).sum())
            assert e["px_count_all"] >= mask.sum() and set(e) >= {"bbox_obj", "bbox_visib", "visib_fract"}
            if visib.any():
                ys, xs = visib.nonzero()
                assert e["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
            # The bop19 rule on the stored (mm) depth gives the same visible mask within a few
            # pixels whose depth rounding straddles the 15 mm tolerance.
            dist_im = depth * fac
            assert not (visib & ~mask).any()
            along = dist_im[mask]
            assert (along > 0).all()


@pytest.mark.slow
def test_bop_toolkit_loaders_read_the_files(clean_root):
    pytest.importorskip("bop_toolkit_lib")
    from bop_toolkit_lib import inout

    d = bop.scene_dir(clean_root, "test", 0)

    assert sorted(inout.load_scene_gt(str(d / "scene_gt.json"))) == [0, 1]
    assert inout.load_scene_camera(str(d / "scene_camera.json"))[0]["cam_K"].shape == (3, 3)
    inout.load_json(str(clean_root / "models" / "models_info.json"), keys_to_int=True)


@pytest.mark.slow
def test_same_seed_same_bytes_and_resume_after_a_kill(tmp_path, clean_root, source, monkeypatch):
    _make(tmp_path / "again", source)
    assert _files(tmp_path / "again") == _files(clean_root)

    real = bop.write_json
    calls = {"gt": 0}

    def dying(path, data):
        if Path(path).name == "scene_gt.json":
            calls["gt"] += 1
            if calls["gt"] == 2:  # killed while committing the second frame
                raise KeyboardInterrupt
        real(path, data)

    monkeypatch.setattr(bop, "write_json", dying)
    with pytest.raises(KeyboardInterrupt):
        _make(tmp_path / "killed", source)
    monkeypatch.setattr(bop, "write_json", real)
    folder = SceneFolder(tmp_path / "killed", "test", 0)
    assert folder.has_frame(0) and not folder.has_frame(1)
    s = _make(tmp_path / "killed", source)
    assert (s.rendered, s.skipped) == (1, 1)
    assert _files(tmp_path / "killed") == _files(clean_root)


@pytest.mark.slow
def test_resuming_with_other_settings_is_refused(tmp_path, clean_root, source):
    from isa.exceptions import DataError

    with pytest.raises(DataError, match="other settings"):
        _make(clean_root, source, seed=4)


@pytest.mark.slow
def test_cameras_stand_and_look_as_people_hold_them(clean_root):
    for f in read_scene_dataset(clean_root, "test"):
        cam = bop.read_json(bop.scene_dir(clean_root, "test", f.scene_id) / "scene_camera.json")[str(f.im_id)]
        R = np.array(cam["cam_R_w2c"]).reshape(3, 3)
        c = Camera(R, np.array(cam["cam_t_w2c"]) / 1000.0, SMALL)
        assert 0.9 <= c.eye[2] <= 1.8 and 0.0 <= c.pitch_deg() <= 45.0 + 1e-9 and abs(c.roll_deg()) <= 3.0 + 1e-9
        # gravity: the upright frame's z is world up, its y the levelled optical axis
        up = f.gravity @ R @ np.array([0.0, 0.0, 1.0])
        np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
        fwd = f.gravity @ np.array([0.0, 0.0, 1.0])
        assert abs(fwd[0]) < 1e-9 and fwd[1] > 0


@pytest.mark.slow
def test_modelnet_sources_test_and_validation_split(shared_data, tmp_path):
    from isa.data.modelnet import paper_instances, validation_instances
    from isa.scenes.sources import modelnet_test, modelnet_validation
    from isa.privileged.ssc import centre_of_mass

    mn = shared_data / "modelnet10"
    test = modelnet_test(mn, ["chair"], n=2)
    o = test.instance("chair", 1)
    assert o.obj_id == 2 and "/test/chair_" in o.source
    # centred on its centre of mass (chair's CENTRE), at a real chair's height
    np.testing.assert_allclose(centre_of_mass(o.mesh), 0.0, atol=0.01)
    assert 0.75 <= o.mesh.extents[2] <= 1.10
    val = modelnet_validation(mn, ["chair"], n=3)
    names = {str(i.path) for i in validation_instances(mn, "chair", 3)}
    protocol = {str(i.path) for i in paper_instances(mn, "chair")}
    srcs = set(val.sources("chair"))
    assert srcs == names and not srcs & protocol
    s = make_scenes(tmp_path, "test", test, 1, 1, seed=0, noise=False, n_instances=(2, 2), rig=RIG, progress=False)
    assert s.rendered == 1
    f = read_scene_dataset(tmp_path, "test")[0]
    assert {g.category for g in f.gt} <= {"chair"} and all(len(g.points) > 4096 for g in f.gt)

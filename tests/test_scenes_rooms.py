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
from shapely.geometry import MultiPoint

from isa.camera import Intrinsics
from isa.data import bop
from isa.scenes import read_scene_dataset
from isa.scenes.cameras import Camera, CameraRig, camera_pose
from isa.scenes.sources import procedural
from isa.scenes.writer import Placement, SceneFolder, SceneSpec, _Renderers, make_scenes, ray_factor, render_frame

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
                meshes[g.obj_id] = cKDTree(trimesh.sample.sample_surface(m, 120000, seed=0)[0])
            X = P[visib]
            own = meshes[g.obj_id].query((X - g.t) @ g.R)[0]  # R^T (X - t), row-wise
            assert np.median(own) < 0.0025 and np.percentile(own, 95) < 0.005, (f.im_id, k, np.median(own))
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
    from isa.privileged.ssc import centre_of_mass
    from isa.scenes.sources import modelnet_test, modelnet_validation

    mn = shared_data / "modelnet10"
    test = modelnet_test(mn, ["chair"], n=2)
    o = test.instance("chair", 1)
    assert o.obj_id == 2 and o.source.startswith("modelnet:test/chair_")
    # centred on its centre of mass (chair's CENTRE), at a real chair's height
    np.testing.assert_allclose(centre_of_mass(o.mesh), 0.0, atol=0.01)
    assert 0.75 <= o.mesh.extents[2] <= 1.10
    val = modelnet_validation(mn, ["chair"], n=3)
    names = {f"modelnet:train/{i.path.name}" for i in validation_instances(mn, "chair", 3)}
    protocol = {f"modelnet:train/{i.path.name}" for i in paper_instances(mn, "chair")}
    srcs = set(val.sources("chair"))
    assert srcs == names and not srcs & protocol
    held_out = set(modelnet_validation(mn, ["chair"], n=3, skip=3).sources("chair"))  # rooms to fit rankers on
    everything = [f"modelnet:train/{i.path.name}" for i in validation_instances(mn, "chair", 6)]
    assert held_out == set(everything[:3]) and not held_out & srcs
    s = make_scenes(tmp_path, "test", test, 1, 1, seed=0, noise=False, n_instances=(2, 2), rig=RIG, progress=False)
    assert s.rendered == 1
    f = read_scene_dataset(tmp_path, "test")[0]
    assert {g.category for g in f.gt} <= {"chair"} and all(len(g.points) > 4096 for g in f.gt)


def test_bad_output_folder_and_category_are_named(tmp_path):
    from isa.exceptions import DataError
    from isa.scenes import make_scan2cad_scenes

    (tmp_path / "file").write_text("x")
    with pytest.raises(DataError, match="file exists and is not a folder"):
        make_scenes(tmp_path / "file", "test", procedural(["chair"], n=1), 1, 1, progress=False)
    with pytest.raises(DataError, match="unknown category 'sofa'"):
        procedural(["sofa"])
    with pytest.raises(DataError, match="example_annotation.json"):
        make_scan2cad_scenes(tmp_path / "out", tmp_path / "no-scan", 1)
    assert not (tmp_path / "out").exists()  # nothing written on bad input


@pytest.mark.slow
def test_lazy_reading_gives_the_same_frames(clean_root):
    eager = read_scene_dataset(clean_root, "test")
    lazy = read_scene_dataset(clean_root, "test", lazy=True)
    assert len(lazy) == len(eager)
    for a, b in zip(eager, lazy):
        np.testing.assert_array_equal(a.depth, b.depth)
        assert [(g.obj_id, g.visib_fract) for g in a.gt] == [(g.obj_id, g.visib_fract) for g in b.gt]
        np.testing.assert_array_equal(a.gt[0].t, b.gt[0].t)


def test_camera_sampler_ranges_and_gravity_analytic():
    from isa.scenes.cameras import gravity_rotation, sample_camera

    rng = np.random.default_rng(0)
    targets = np.array([[0.0, 0.0, 0.4], [1.0, 0.5, 0.3]])
    for _ in range(100):
        c = sample_camera(rng, targets, lambda eye: True, RIG)
        assert 0.9 <= c.eye[2] <= 1.8 and 0.0 <= c.pitch_deg() <= 45.0 + 1e-9 and abs(c.roll_deg()) <= 3.0 + 1e-9
        uv = [SMALL.project((c.R @ p + c.t)[None])[0] for p in targets]
        assert any(0 <= u < SMALL.width and 0 <= v < SMALL.height for u, v in uv)
    # A camera pitched down by p, no roll: its optical axis is (0, cos p, -sin p) upright, and
    # gravity @ R maps world vectors to the upright frame turned so that the view is along +y.
    p, yaw = np.radians(30.0), np.radians(70.0)
    R, _ = camera_pose((0.0, 0.0, 1.5), yaw, p)
    G = gravity_rotation(R)
    np.testing.assert_allclose(G @ [0.0, 0.0, 1.0], [0.0, np.cos(p), -np.sin(p)], atol=1e-12)
    np.testing.assert_allclose(G @ R @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(G @ G.T, np.eye(3), atol=1e-12)
    with pytest.raises(Exception, match="no free view"):
        sample_camera(rng, targets, lambda eye: False, RIG, attempts=5)


def test_symmetries_round_trip_through_bop_fields():
    from isa.privileged.symmetry import YawSymmetry
    from isa.scenes.io import CONTINUOUS_Z, symmetries_of
    from isa.scenes.writer import symmetries_entry

    c = np.array([0.1, -0.2, 0.0])
    e = symmetries_entry(YawSymmetry(c, 4, 0.0))
    assert len(e["symmetries_discrete"]) == 3  # BOP leaves the identity out
    T = np.array(e["symmetries_discrete"][1]).reshape(4, 4)  # the half turn: x -> 2c - x in xy, mm
    X = np.array([0.3, 0.4, 0.5])
    np.testing.assert_allclose((T[:3, :3] @ (1000 * X) + T[:3, 3]) / 1000, [2 * c[0] - X[0], 2 * c[1] - X[1], X[2]], atol=1e-12)
    group, centre = symmetries_of(e, "test")
    assert len(group) == 4 and np.allclose(group[0], np.eye(3)) and np.allclose(centre, c)
    e = symmetries_entry(YawSymmetry(c, 0, 0.0))
    assert e == {"symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [100.0, -200.0, 0.0]}]}
    assert symmetries_of(e, "test")[0] == CONTINUOUS_Z and np.allclose(symmetries_of(e, "test")[1], c)
    assert symmetries_entry(YawSymmetry(c, 1, 0.0)) == {} and len(symmetries_of({}, "test")[0]) == 1


@pytest.mark.slow
def test_noise_changes_the_depth_not_the_visibility(tmp_path, clean_root, source):
    # Visibility is tested against the clean scene (docs/scenes.md), so the noisy run's masks and
    # counts equal the clean run's; only the depth and px_count_valid (its holes) differ.
    _make(tmp_path, source, noise=True)
    for name in ("scene_gt.json", "scene_camera.json"):
        assert (bop.scene_dir(tmp_path, "test", 0) / name).read_bytes() == (bop.scene_dir(clean_root, "test", 0) / name).read_bytes()
    noisy = bop.read_json(bop.scene_dir(tmp_path, "test", 0) / "scene_gt_info.json")
    clean = bop.read_json(bop.scene_dir(clean_root, "test", 0) / "scene_gt_info.json")
    fewer = 0
    for k in clean:
        for a, b in zip(clean[k], noisy[k]):
            assert {x: a[x] for x in a if x != "px_count_valid"} == {x: b[x] for x in b if x != "px_count_valid"}
            assert b["px_count_valid"] <= a["px_count_valid"]  # the sensor's holes
            fewer += b["px_count_valid"] < a["px_count_valid"]
    assert fewer > 0
    d0 = bop.read_png(bop.scene_dir(tmp_path, "test", 0) / "depth" / "000000.png")
    d1 = bop.read_png(bop.scene_dir(clean_root, "test", 0) / "depth" / "000000.png")
    assert (d0 == 0).sum() > (d1 == 0).sum() and np.abs(d0.astype(int) - d1)[(d0 > 0) & (d1 > 0)].mean() > 1


@pytest.mark.slow
def test_things_on_a_table_rest_on_its_top():
    # Procedural tables have a flat top slab: an item placed on the top stands at its height,
    # inside its footprint, and floor clutter and instances never share floor area.
    from isa.scenes.rooms import RoomParams, make_room

    src = procedural(["table"], seed=5, n=2)
    params = RoomParams(table_clutter=(3, 3), floor_clutter=(3, 3), shelves=(1, 1))
    placed = 0
    for s in range(3):
        room = make_room(np.random.default_rng([9, s]), src, (2, 2), params)
        tops = [(i.footprint, i.world_mesh.bounds[1, 2]) for i in room.instances]
        for kind, m in zip(room.clutter, room.clutter_meshes):
            if kind != "table-top":
                continue
            lo = m.bounds[0]
            on = [(fp, z) for fp, z in tops if fp.contains(MultiPoint([tuple(p) for p in m.vertices[:, :2]]).convex_hull)]
            assert on and abs(lo[2] - on[0][1]) < 0.01, (lo, [z for _, z in tops])
            placed += 1
        fps = room.footprints
        assert all(not a.intersects(b) for i, a in enumerate(fps) for b in fps[i + 1:])
    assert placed >= 3


def test_make_refuses_validation_skip_for_another_source(tmp_path):
    from isa.scenes.__main__ import main

    out = tmp_path / "rooms"
    with pytest.raises(SystemExit, match="--validation-skip applies to --source modelnet-validation, not procedural"):
        main(["make", "--out", str(out), "--source", "procedural", "--validation-skip", "3"])
    assert not out.exists()  # refused before anything is written

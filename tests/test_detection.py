"""Detection on depth frames: category box from meshes, hypothesis -> box on analytic poses,
plane removal on an analytic floor + wall + box image, end to end on a rendered chair standing on
a floor (tiny forest trained here on procedural renders), and on the shared real SUN RGB-D frames."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from isa import detection as D
from isa.camera import KINECT_V1, Intrinsics
from isa.data.sunrgbd import UPRIGHT_FROM_CAMERA_AXES
from isa.evaluation.boxes3d import Box3D, iou_3d
from isa.exceptions import DataError


def rot_z(a):
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])


def rot_x(a):
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def pitched_gravity(pitch_deg: float) -> np.ndarray:
    """Camera -> upright rotation of a camera pitched down by ``pitch_deg`` (no roll): the level
    camera's axis swap, then a rotation about the upright x axis."""
    return rot_x(-math.radians(pitch_deg)) @ UPRIGHT_FROM_CAMERA_AXES


# ---------------------------------------------------------------------------------------------- category box


def test_category_box_is_the_median_of_the_instances():
    meshes = []
    for ext, centre in [((0.4, 0.5, 0.9), (0.0, -0.02, 0.10)), ((0.5, 0.6, 1.0), (0.0, 0.04, 0.05)),
                        ((0.9, 0.5, 0.8), (0.01, 0.0, 0.30))]:
        m = trimesh.creation.box(extents=ext)
        m.apply_translation(centre)  # the object frame's origin (the SSC) is off the box centre
        meshes.append(m)
    box = D.category_box(meshes, category="chair")
    np.testing.assert_allclose(box.size, [0.5, 0.5, 0.9], atol=1e-12)
    np.testing.assert_allclose(box.ssc_offset, [-0.0, -0.0, -0.10], atol=1e-12)
    assert box.n_instances == 3 and box.category == "chair"
    back = D.model_box({"category": "chair", **D.box_metadata(box)})
    np.testing.assert_array_equal(back.size, box.size)
    np.testing.assert_array_equal(back.ssc_offset, box.ssc_offset)


def test_model_box_errors_name_the_model():
    with pytest.raises(DataError, match="old.isa.*no 'box'"):
        D.model_box({"category": "chair"}, "old.isa")
    with pytest.raises(DataError, match="size"):
        D.model_box({"box": {"size": [1, 1, 1]}})
    with pytest.raises(ValueError, match="positive"):
        D.CategoryBox("chair", [0.5, 0.0, 1.0], [0, 0, 0])
    with pytest.raises(ValueError, match="category="):
        D.category_box([trimesh.creation.box()])


# ---------------------------------------------------------------------------------------------- hypothesis -> box


@pytest.mark.parametrize("pitch", [0.0, 25.0])
@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_hypothesis_box_on_an_analytic_pose(pitch, yaw):
    Rg = pitched_gravity(pitch)
    box = D.CategoryBox("chair", [0.5, 0.6, 0.9], [0.02, -0.05, 0.1])
    ssc_up = np.array([0.4, 2.5, -0.6])  # where the SSC is, upright frame
    # An upright object turned by `yaw`: object -> upright is rot_z(yaw), so object -> camera is Rg^T rot_z.
    R = Rg.T @ rot_z(yaw)
    h = {"R": R, "t": Rg.T @ ssc_up, "score": 3.5, "support": 40}
    b = D.hypothesis_box(h, box, Rg, max_tilt_deg=5.0)
    # Truth by hand: the box centre is the SSC minus the offset turned by the yaw.
    np.testing.assert_allclose(b.centre, ssc_up - rot_z(yaw) @ box.ssc_offset, atol=1e-9)
    np.testing.assert_allclose(b.size, box.size)
    assert math.isclose(math.remainder(b.yaw - yaw, 2 * math.pi), 0.0, abs_tol=1e-9)
    assert b.score == 3.5 and b.category == "chair" and b.meta["support"] == 40
    assert b.meta["tilt_deg"] == pytest.approx(0.0, abs=1e-6)


def test_tilted_hypothesis_is_snapped_or_rejected():
    Rg = pitched_gravity(20.0)
    box = D.CategoryBox("table", [1.2, 0.8, 0.75], [0.0, 0.0, 0.2])
    ssc_up = np.array([-0.3, 2.0, -0.8])
    # Tipped 12 deg about the object's x axis: the yaw of rot_z(a) rot_x(b) is exactly a.
    R = Rg.T @ rot_z(1.1) @ rot_x(math.radians(12))
    h = {"R": R, "t": Rg.T @ ssc_up, "score": 1.0}
    assert D.hypothesis_box(h, box, Rg, max_tilt_deg=10.0) is None
    b = D.hypothesis_box(h, box, Rg, max_tilt_deg=15.0)
    assert b.meta["tilt_deg"] == pytest.approx(12.0, abs=1e-6)
    assert b.yaw == pytest.approx(1.1, abs=1e-9)
    # Snapped upright before placing the box: the SSC offset is turned by the yaw only.
    np.testing.assert_allclose(b.centre, ssc_up - rot_z(1.1) @ box.ssc_offset, atol=1e-9)
    R_up, yaw, tilt = D.upright_rotation(R, Rg)
    np.testing.assert_allclose(Rg @ R_up, rot_z(1.1), atol=1e-12)


# ---------------------------------------------------------------------------------------------- planes

K_SMALL = Intrinsics(fx=300.0, fy=300.0, cx=159.5, cy=119.5, width=320, height=240)


def analytic_room(pitch_deg=15.0, height=1.2, noise=0.004, seed=0):
    """Depth of a camera ``height`` m above a floor, pitched down, facing a wall 4.5 m ahead, with
    a 0.5 m cube on the floor 2.3 m ahead (exact ray casting). Returns depth, R_gravity and a
    label image: 0 floor, 1 wall, 2 cube, -1 nothing."""
    Rg = pitched_gravity(pitch_deg)
    v, u = np.mgrid[0:K_SMALL.height, 0:K_SMALL.width]
    rays_cam = np.stack([(u - K_SMALL.cx) / K_SMALL.fx, (v - K_SMALL.cy) / K_SMALL.fy, np.ones(u.shape)], -1)
    d = rays_cam @ Rg.T  # upright ray directions per unit camera depth
    o = np.array([0.0, 0.0, height])  # camera centre, world = upright + floor at z = 0
    inf = np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        s_floor = np.where(d[..., 2] < 0, -o[2] / d[..., 2], inf)
        s_wall = np.where(d[..., 1] > 0, (4.5 - o[1]) / d[..., 1], inf)
        lo, hi = np.array([-0.25, 2.05, 0.0]), np.array([0.25, 2.55, 0.5])
        t0 = (lo - o) / d
        t1 = (hi - o) / d
        tn = np.nanmax(np.minimum(t0, t1), -1)
        tf = np.nanmin(np.maximum(t0, t1), -1)
    s_cube = np.where((tn <= tf) & (tn > 0), tn, inf)
    s = np.stack([s_floor, s_wall, s_cube], -1)
    label = np.argmin(s, -1)
    depth = np.take_along_axis(s, label[..., None], -1)[..., 0]  # camera depth = s (rays have z = 1)
    label = np.where(np.isfinite(depth), label, -1)
    depth = np.where(np.isfinite(depth) & (depth < 8), depth, 0.0)
    depth = depth + np.random.default_rng(seed).normal(0, noise, depth.shape) * (depth > 0)
    return depth.astype(np.float32), Rg, label


def test_remove_planes_on_floor_wall_and_cube():
    depth, Rg, label = analytic_room()
    assert (label == 0).sum() > 5000 and (label == 1).sum() > 5000 and (label == 2).sum() > 1000
    r = D.remove_planes(depth, K_SMALL, Rg)
    kinds = [p.kind for p in r.planes]
    assert kinds[0] == "floor" and kinds.count("wall") == 1, kinds
    assert r.floor.height == pytest.approx(-1.2, abs=0.01)  # the camera is 1.2 m above the floor
    wall = r.planes[1]
    assert abs(wall.normal[1]) == pytest.approx(1.0, abs=1e-3) and abs(wall.offset) == pytest.approx(4.5, abs=0.02)
    assert r.removed[label == 0].mean() > 0.98
    assert r.removed[label == 1].mean() > 0.98
    # The cube (horizontal top, 0.5 m vertical faces) stays, bar the sliver touching the floor.
    assert r.removed[label == 2].mean() < 0.1
    assert np.all(r.depth[r.removed] == 0) and np.array_equal(r.depth[~r.removed], depth[~r.removed])
    none = D.remove_planes(depth, K_SMALL, Rg, floor=False, walls=False)
    assert none.planes == [] and not none.removed.any()


def test_remove_planes_finds_no_floor_when_none_is_seen():
    depth, Rg, label = analytic_room(pitch_deg=-20.0)  # looking up: wall only
    assert (label == 0).sum() == 0
    r = D.remove_planes(depth, K_SMALL, Rg)
    assert [p.kind for p in r.planes] == ["wall"]


def test_remove_planes_checks_its_arguments():
    depth, Rg, _ = analytic_room()
    with pytest.raises(ValueError, match="intrinsics"):
        D.remove_planes(depth[:, :100], K_SMALL, Rg)


# ---------------------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def chair_model():
    """A tiny chair forest trained on renders of 3 procedural chairs (20 views each)."""
    from isa.forest.model import ForestParams
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("chair", 3, seed=7)
    forest, prepared = D.train_detector(
        "chair", objs, views=20, stride=6, use_ground_truth=True,
        forest_params=ForestParams(n_trees=3, max_depth=12, n_candidates=30, quality="Q1", seed=0))
    return forest, prepared


def test_end_to_end_on_a_rendered_chair_on_a_floor(chair_model):
    from isa.pipeline import prepare_category
    from isa.render.dataset import procedural_objects
    from isa.render.renderer import DepthRenderer
    from isa.render.views import look_at

    forest, prepared = chair_model
    assert D.model_box(forest).category == "chair"
    # An unseen chair, SSC-centred with the category's SSC, standing on a floor at a known pose.
    test = prepare_category("chair", procedural_objects("chair", 1, seed=99), ssc=prepared.ssc,
                            use_ground_truth=True, progress=False).objects[0].mesh
    yaw, pos = 0.6, np.array([0.3, 0.4, -test.bounds[0, 2]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot_z(yaw), pos
    chair = test.copy()
    chair.apply_transform(T)
    floor = trimesh.creation.box(extents=[8, 8, 0.02])
    floor.apply_translation([0, 0, -0.01])
    eye = np.array([0.3 - 2.2 * math.sin(0.3), 0.4 - 2.2 * math.cos(0.3), 1.4])
    R, t = look_at(eye, target=[0.3, 0.4, 0.4])
    with DepthRenderer(KINECT_V1) as r:
        depth, _ = r.render(trimesh.util.concatenate([chair, floor]), R, t)
    Rg = R.T  # camera -> world axes; the upright frame is the world's, centred at the camera
    # Truth: the chair mesh's own box at the known pose (not through hypothesis_box).
    truth = Box3D("chair", rot_z(yaw) @ test.bounds.mean(0) + pos - eye, test.bounds[1] - test.bounds[0], yaw)

    det = D.detect_category(forest, depth, KINECT_V1, Rg)
    assert det.planes.floor.height == pytest.approx(-1.4, abs=0.01)
    assert det.boxes, det.rejected
    best = det.boxes[0]
    assert iou_3d(best, truth) > 0.25, (best, truth)
    assert best.z_range[0] == pytest.approx(-1.4, abs=0.01)  # set down on the floor
    # Without plane removal the floor's votes are not filtered out: still a valid call.
    raw = D.detect_category(forest, depth, KINECT_V1, Rg, params=D.DetectionParams(remove_floor=False, remove_walls=False))
    assert raw.planes is None and all(b.category == "chair" for b in raw.boxes)


def test_evaluate_real_names_models_without_a_box(tmp_path):
    from isa import _core

    # A one-tree model of a flat patch, saved without the category box in its metadata.
    img = np.full((20, 20), 1500, np.uint16)
    parts = _core.sample_parts([img], stride=4)
    f = _core.Forest(n_trees=1, max_depth=2, min_samples_split=2, min_samples_leaf=1, n_candidates=2, quality="Q1")
    f.fit(_core.TrainSet([img], parts, np.zeros((len(parts), 3), np.float32),
                         np.tile(np.float32([1, 0, 0, 0]), (len(parts), 1))), metadata=json.dumps({"category": "chair"}))
    path = tmp_path / "nobox.isa"
    f.save(str(path))
    with pytest.raises(DataError, match="nobox.isa: the model's metadata has no 'box'"):
        D.evaluate_real({"chair": path}, [None])
    with pytest.raises(DataError, match="missing.isa: model file not found"):
        D.evaluate_real({"chair": tmp_path / "missing.isa"}, [None])
    with pytest.raises(ValueError, match="no frames"):
        D.evaluate_real({"chair": path}, [])


# ---------------------------------------------------------------------------------------------- real frames


def test_detection_on_the_shared_real_frames(shared_data, chair_model, tmp_path):
    from isa.report.report import Report

    frames = D.load_real_frames(shared_data / "sunrgbd")
    assert {f.name for f in frames} == {"img_0063", "000001"}
    forest, _ = chair_model
    model = tmp_path / "chair.isa"
    forest.save(model)
    res = D.evaluate_real({"chair": model}, frames)
    assert res.ap["chair"].n_ground_truth == 1  # the chair of img_0063
    assert 0.0 <= res.ap["chair"].ap <= 1.0
    for f, dets, planes, secs in zip(frames, res.detections, res.planes, res.seconds):
        floor = next(p for p in planes if p.kind == "floor")
        z = f.points_upright()[:, 2]
        # The floor is the bottom of the upright cloud (SUN's frames: camera 1.1-1.3 m up).
        assert floor.height == pytest.approx(np.percentile(z, 1), abs=0.05)
        assert secs["total"] > 0
        for b in dets:
            assert b.category == "chair" and np.isfinite(b.score)
            assert b.z_range[0] == pytest.approx(floor.height, abs=1e-9)
            # Upright frame, not camera frame: mapped back, the box centre is in front of the
            # camera and inside the image.
            cam = np.linalg.solve(f.R_gravity, b.centre)
            u, v = f.intrinsics.project(cam[None])[0]
            assert cam[2] > 0 and -50 < u < f.intrinsics.width + 50 and -50 < v < f.intrinsics.height + 50
    # The report section: the paper's table with our row, one figure per frame, numbers in results.
    report = Report(tmp_path / "report", "real")
    data = D.real_section(report, res, frames)
    text = "\n".join(report.blocks)
    assert "Deep Sliding Shapes" in text and "not a benchmark" in text and "ISA (ours), 2 frame(s)" in text
    assert (tmp_path / "report" / "figures" / "real-img_0063.png").is_file()
    assert report.results["real"] is data and data["n_ground_truth"] == {"chair": 1}
    json.dumps(data)  # JSON-ready


def test_cli_on_the_shared_real_frames(shared_data, chair_model, tmp_path):
    forest, _ = chair_model
    model = tmp_path / "chair.isa"
    forest.save(model)
    D.main(["--model", f"chair={model}", "--data", str(shared_data / "sunrgbd"), "--out", str(tmp_path / "out")])
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(results["real"]["ap_percent"]) == {"chair"}
    assert "Table 2, right" in (tmp_path / "out" / "report.md").read_text()
    with pytest.raises(SystemExit, match="CATEGORY=PATH"):
        D.main(["--model", "chair", "--data", str(shared_data / "sunrgbd"), "--out", str(tmp_path / "x")])

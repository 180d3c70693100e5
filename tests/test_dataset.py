"""Viewpoints and dataset rendering into BOP: poses, resumability, atomicity, settings guard, noise
switch, contact sheet."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from isa.camera import KINECT_V1
from isa.data import bop
from isa.exceptions import DataError
from isa.render.dataset import ObjectSpec, default_test_views, default_views, hull_points, main, procedural_objects, render_dataset
from isa.render.noise import KinectNoise
from isa.render.renderer import DepthRenderer
from isa.render.views import fit_distance, look_at, sample_test_views, training_views
from isa.report.figures.renders import bop_contact_sheet


def _dirs(views):
    return views.eye / np.linalg.norm(views.eye, axis=1, keepdims=True)


def test_training_views_protocol():
    v = training_views()
    assert len(v) == 89
    np.testing.assert_array_equal(v.R, training_views(seed=0).R)
    assert not np.allclose(v.R, training_views(seed=1).R)
    d = np.linalg.norm(v.eye, axis=1)
    assert d.min() >= 1.5 and d.max() <= 4.0
    elev = np.degrees(np.arcsin(_dirs(v)[:, 2]))
    assert elev.min() >= 10 - 1e-9 and elev.max() <= 80 + 1e-9
    # Even spread: the closest pair of 89 lattice directions is far apart (random: ~2 deg).
    cos = _dirs(v) @ _dirs(v).T
    np.fill_diagonal(cos, -1)
    assert np.degrees(np.arccos(cos.max())) > 8
    for R, t, eye in zip(v.R, v.t, v.eye):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R @ eye + t, 0, atol=1e-12)  # t = -R eye


def test_look_at_projects_target_to_centre_upright():
    R, t = look_at([1.0, -2.0, 1.5])
    K = KINECT_V1
    uv = K.project((np.array([[0, 0, 0], [0, 0, 0.3], [0.3, 0, 0]]) @ R.T) + t)
    np.testing.assert_allclose(uv[0], [K.cx, K.cy], atol=1e-9)
    assert uv[1, 1] < uv[0, 1]  # object up is image up
    assert abs(uv[1, 0] - uv[0, 0]) < 1e-9  # no roll: the vertical stays vertical
    assert uv[2, 0] > uv[0, 0]  # seen from -y, +x is on the right
    R2, _ = look_at([0, 0, 3.0])  # straight down: defined, not NaN
    assert np.all(np.isfinite(R2))


def test_test_views_are_not_training_views():
    train = training_views(seed=3)
    test = sample_test_views(200, seed=4, exclude=train, min_separation_deg=3.0)
    assert len(test) == 200
    ang = np.degrees(np.arccos(np.clip(_dirs(test) @ _dirs(train).T, -1, 1)))
    assert ang.min() >= 3.0
    np.testing.assert_array_equal(test.R, sample_test_views(200, seed=4, exclude=train).R)


def test_fit_distance_keeps_object_in_image():
    obj = procedural_objects("bed", 1, seed=2)[0]
    pts = hull_points(obj.mesh)
    v = default_views(obj, 30)
    K = KINECT_V1
    for R, t in zip(v.R, v.t):
        uv = K.project(pts @ R.T + t)
        assert uv.min() >= 0 and uv[:, 0].max() <= K.width - 1 and uv[:, 1].max() <= K.height - 1
    # fit_distance is the smallest such distance: slightly closer, a point leaves the margin.
    R = v.R[0]
    d = fit_distance(R, pts, [0, 0, 0], K, margin_px=8)
    uv = K.project(pts @ R.T + [0, 0, d * 0.98])
    assert uv[:, 0].min() < 8 or uv[:, 1].min() < 8 or uv[:, 0].max() > K.width - 9 or uv[:, 1].max() > K.height - 9


@pytest.fixture(scope="module")
def objects():
    return procedural_objects("chair", 2, seed=1) + procedural_objects("table", 1, seed=1, first_obj_id=3)


def test_render_dataset_writes_bop_with_exact_poses(tmp_path, objects, capsys):
    s = render_dataset(tmp_path, objects, n_views=3, progress=True)
    assert (s.rendered, s.skipped) == (9, 0)
    assert "render train" in capsys.readouterr().err  # the progress bar
    assert bop.list_scenes(tmp_path, "train") == [1, 2, 3]
    info = bop.read_models_info(tmp_path)
    assert sorted(info) == [1, 2, 3]
    extras = bop.read_json(tmp_path / "models" / "models_isa.json")
    assert extras["1"]["category"] == "chair" and extras["1"]["skeleton"]["names"][0] == "seat_centre"
    r = DepthRenderer(KINECT_V1)
    for o in objects:
        v = default_views(o, 3)
        for f in bop.read_scene(tmp_path, "train", o.obj_id):
            R, t = v[f.im_id]
            np.testing.assert_array_equal(f.R, R)
            np.testing.assert_allclose(f.t, t, atol=1e-12)
            depth, mask = r.render(o.mesh, R, t)  # noise is off by default: clean depth
            np.testing.assert_array_equal(bop.depth_to_png(f.depth), bop.depth_to_png(depth))
            np.testing.assert_array_equal(f.mask, mask)
            assert f.mask.sum() > 100
    r.close()


def test_resume_skips_written_frames(tmp_path, objects):
    render_dataset(tmp_path, objects, n_views=3, progress=False)
    before = (tmp_path / "train" / "000002" / "depth" / "000001.png").stat().st_mtime_ns
    s = render_dataset(tmp_path, objects, n_views=3, progress=False)
    assert (s.rendered, s.skipped) == (0, 9)
    assert (tmp_path / "train" / "000002" / "depth" / "000001.png").stat().st_mtime_ns == before
    (tmp_path / "train" / "000001" / "mask" / "000002_000000.png").unlink()
    s = render_dataset(tmp_path, objects, n_views=3, progress=False)
    assert (s.rendered, s.skipped) == (1, 8)


def test_interrupted_run_resumes_without_half_frames(tmp_path, objects, monkeypatch):
    real = bop.SceneWriter.write_frame
    calls = {"n": 0}

    def crash_on_fifth(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt  # like Ctrl-C in the middle of the run
        return real(self, *a, **k)

    monkeypatch.setattr(bop.SceneWriter, "write_frame", crash_on_fifth)
    with pytest.raises(KeyboardInterrupt):
        render_dataset(tmp_path, objects, n_views=3, progress=False, io_threads=1)
    monkeypatch.undo()
    assert not list(tmp_path.rglob("*.tmp"))
    s = render_dataset(tmp_path, objects, n_views=3, progress=False)
    assert s.rendered + s.skipped == 9 and s.rendered >= 1
    for sid in (1, 2, 3):
        assert bop.list_frames(tmp_path, "train", sid) == [0, 1, 2]
        for f in bop.read_scene(tmp_path, "train", sid):
            assert f.mask.sum() > 100


def test_other_settings_refused(tmp_path, objects):
    render_dataset(tmp_path, objects[:1], n_views=2, progress=False)
    with pytest.raises(DataError, match="isa_render.json"):
        render_dataset(tmp_path, objects[:1], n_views=2, progress=False, depth_scale=0.1)


def test_noise_switch(tmp_path, objects):
    clean = tmp_path / "clean"
    noisy = tmp_path / "noisy"
    render_dataset(clean, objects[:1], n_views=1, progress=False)
    render_dataset(noisy, objects[:1], n_views=1, progress=False, noise=KinectNoise())
    a = bop.read_frame(clean, "train", 1, 0)
    b = bop.read_frame(noisy, "train", 1, 0)
    np.testing.assert_array_equal(a.mask, b.mask)  # masks stay the true silhouette
    both = (a.depth > 0) & (b.depth > 0)
    diff = np.abs(a.depth[both] - b.depth[both])
    assert diff.mean() > 1e-3 and np.median(diff) < 0.05


def test_bad_inputs(tmp_path, objects):
    with pytest.raises(DataError, match="no objects"):
        render_dataset(tmp_path, [], progress=False)
    dup = [objects[0], ObjectSpec(objects[0].obj_id, "chair", objects[1].mesh, "x")]
    with pytest.raises(DataError, match="duplicate obj_id"):
        render_dataset(tmp_path, dup, progress=False)


def test_contact_sheet(tmp_path, objects):
    render_dataset(tmp_path, objects, n_views=2, progress=False)
    out = bop_contact_sheet(tmp_path, "train", tmp_path / "sheet.png", per_scene=2)
    im = np.asarray(Image.open(out))
    assert im.shape[0] > 200 and im.shape[1] > 400
    assert im[..., :3].std() > 10  # not a blank page


def test_modelnet_chair_dataset(tmp_path, shared_data):
    from isa.render.dataset import modelnet_objects

    objs = modelnet_objects(shared_data / "modelnet10", "chair", n=2)
    assert [o.source.rsplit("/", 1)[-1] for o in objs] == ["chair_0001.off", "chair_0002.off"]
    s = render_dataset(tmp_path, objs, n_views=2, progress=False)
    assert s.rendered == 4
    f = bop.read_frame(tmp_path, "train", 2, 1)
    assert 1.4 < np.median(f.depth[f.mask]) < 4.6


def test_default_test_views_avoid_the_training_views(objects):
    o = objects[0]
    test, train = default_test_views(o, 40, seed=2), default_views(o, 89, seed=2)
    ang = np.degrees(np.arccos(np.clip(_dirs(test) @ _dirs(train).T, -1, 1)))
    assert ang.min() >= 3.0


def test_command_line(tmp_path, capsys):
    main(["--procedural", "1", "--category", "toilet", "--views", "2", "--split", "test", "--out", str(tmp_path)])
    assert "2 frames rendered" in capsys.readouterr().out
    assert bop.list_frames(tmp_path, "test", 1) == [0, 1]
    with pytest.raises(SystemExit):
        main(["--procedural", "1", "--category", "sofa", "--out", str(tmp_path)])
    assert "unknown category 'sofa'" in capsys.readouterr().err


def test_view_band_places_training_and_test_cameras():
    from isa.render.views import ViewBand

    band = ViewBand(distance=(2.0, 2.0), elevation_deg=(30.0, 40.0), target=(0.0, 0.0, 0.5))
    for v in (training_views(20, seed=0, band=band), sample_test_views(20, seed=1, band=band)):
        rel = v.eye - np.array(band.target)
        np.testing.assert_allclose(np.linalg.norm(rel, axis=1), 2.0)  # on the band's sphere
        el = np.degrees(np.arcsin(rel[:, 2] / 2.0))
        assert el.min() >= 30.0 - 1e-9 and el.max() <= 40.0 + 1e-9  # inside its elevations

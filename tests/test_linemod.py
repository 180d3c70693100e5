"""Linemod baseline (isa.evaluation.linemod): pose recovery, refused templates, the paper's protocol, errors.

The truth is the pose each depth image was rendered with (isa.render.renderer, tested against ray casting
in test_render.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

pytest.importorskip("cv2")

from isa.camera import KINECT_V1 as K  # noqa: E402
from isa.evaluation.linemod import LinemodDetector, LinemodRecall, depth_to_mm, linemod_recall  # noqa: E402
from isa.render.views import look_at  # noqa: E402


# ---------------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def renderer():
    from isa.render.renderer import DepthRenderer

    with DepthRenderer(K) as r:
        yield r


def _blocky_chair():
    """An asymmetric seat + back + pedestal (origin at the seat centre), 0.9 m tall."""
    seat = trimesh.creation.box((0.45, 0.45, 0.08))
    back = trimesh.creation.box((0.45, 0.06, 0.5))
    back.apply_translation((0, 0.2, 0.29))
    base = trimesh.creation.box((0.3, 0.3, 0.4))
    base.apply_translation((0, 0, -0.24))
    return trimesh.util.concatenate([seat, back, base])


CHAIR = _blocky_chair()
TINY = trimesh.creation.box((0.03, 0.03, 0.03))  # ~50 pixels at 2.6 m: too few features
ROD = trimesh.creation.cylinder(0.01, 0.8)  # 2 px wide
SPHERE = trimesh.creation.icosphere(3, 0.35)


def rotation_deg(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


AZIMUTHS = np.arange(10, 360, 45)  # 8 views, 45 degrees apart, 2.5 m away, 27 degrees up


def view_poses(distance=2.5):
    return [look_at(distance * np.array([np.cos(a), np.sin(a), 0.5])) for a in np.radians(AZIMUTHS)]


@pytest.fixture(scope="module")
def chair_views(renderer):
    return [(renderer.render(CHAIR, R, t)[0], R, t) for R, t in view_poses()]


@pytest.fixture(scope="module")
def chair_detector(chair_views):
    return LinemodDetector.from_views(
        [d for d, _, _ in chair_views], None, [R for _, R, _ in chair_views], [t for _, _, t in chair_views]
    )


# ---------------------------------------------------------------------------------- pose recovery
def test_every_template_view_recovers_its_own_pose(chair_views, chair_detector):
    assert chair_detector.n_templates == 8 and chair_detector.refused == ()
    for i, (depth, R, t) in enumerate(chair_views):
        m = chair_detector.match(depth)
        assert m.view == i and m.similarity == pytest.approx(100.0)
        np.testing.assert_allclose(m.R, R)
        # Linemod places templates on a T=5 px grid at level 0: ~2 cm at 2.5 m.
        assert np.linalg.norm(m.t - t) < 0.03, (i, m.t - t)
        assert m.anchors > 100


@pytest.mark.parametrize("shift", [(0.15, -0.05, 0.2), (-0.2, 0.1, -0.3)])
def test_moved_object_gets_template_rotation_and_its_own_translation(renderer, chair_views, chair_detector, shift):
    _, R, t = chair_views[1]
    t_true = t + np.array(shift)
    m = chair_detector.match(renderer.render(CHAIR, R, t_true)[0])
    assert m.view == 1
    np.testing.assert_allclose(m.R, R)
    # The template's translation would be off by |shift| >= 0.27 m; the estimate follows the object.
    assert np.linalg.norm(m.t - t_true) < 0.06, m.t - t_true


def test_translation_falls_back_when_no_anchor_lands_on_depth(chair_views, chair_detector):
    # Matched position with all anchors off the object: the template origin moved in the image.
    depth, R, t = chair_views[2]
    tp = chair_detector._templates[2]
    empty = np.zeros_like(depth, dtype=np.float64)
    t_est, n = chair_detector._pose(tp, tp.box_xy[0] + 10, tp.box_xy[1], empty)
    assert n == 0
    uv = K.project((t_est)[None])[0]
    np.testing.assert_allclose(uv, K.project(t[None])[0] + (10, 0), atol=1e-6)
    assert t_est[2] == pytest.approx(t[2])


def test_matches_are_sorted_and_thresholded(chair_views, chair_detector):
    depth = chair_views[0][0]
    for threshold in (0, 50):
        sims = [m.similarity for m in chair_detector.matches(depth, threshold)]
        assert sims and sims == sorted(sims, reverse=True) and min(sims) >= threshold
    assert len(chair_detector.matches(depth, 0)) > 2 and len(chair_detector.matches(depth, 0, top=2)) == 2
    # An empty image matches nothing.
    assert chair_detector.match(np.zeros_like(depth), threshold=50) is None


# ---------------------------------------------------------------------------------- refused views
def test_feature_poor_views_are_refused_and_counted(renderer):
    R, t = look_at((2.5, 0.0, 0.8))
    det = LinemodDetector()
    assert det.add_view(*renderer.render(TINY, R, t), R, t) is False
    assert det.add_view(*renderer.render(CHAIR, R, t), R, t) is True
    assert det.add_view(*renderer.render(ROD, R, t), R, t) is False
    assert det.refused == (0, 2) and det.accepted == (1,)
    assert det.n_views == 3 and det.n_templates == 1
    # The accepted view keeps its own index even though a refused one came first.
    assert det.match(renderer.render(CHAIR, R, t)[0]).view == 1


def test_detector_with_only_refused_views_matches_nothing(renderer):
    R, t = look_at((2.5, 0.0, 0.8))
    d = renderer.render(TINY, R, t)[0]
    det = LinemodDetector.from_views([d], [d > 0], [R], [t])
    assert det.n_templates == 0 and det.refused == (0,)
    assert det.match(d) is None and det.matches(d) == []


def test_distance_threshold_below_the_scene_refuses_everything(chair_views):
    # OpenCV ignores pixels beyond distance_threshold (mm): a 2 m threshold sees nothing at 2.5 m.
    depth, R, t = chair_views[0]
    det = LinemodDetector(distance_threshold_mm=2000)
    assert det.add_view(depth, None, R, t) is False


# ---------------------------------------------------------------------------------- protocol
def test_protocol_recall_per_instance_and_min_max_mean(renderer, chair_views, chair_detector):
    frames = [{"depth": d, "R": R, "t": t} for d, R, t in chair_views]

    def is_correct(R_est, t_est, frame):
        return rotation_deg(R_est, frame["R"]) < 5 and np.linalg.norm(t_est - frame["t"]) < 0.05

    # A detector of another object: a sphere matches (rotation is then arbitrary) but rarely right.
    built = []

    def build_sphere():
        built.append(True)
        poses = view_poses()[:2]
        return LinemodDetector.from_views([renderer.render(SPHERE, R, t)[0] for R, t in poses], None, *zip(*poses))

    res = linemod_recall([("chair", chair_detector), ("sphere", build_sphere)], frames, is_correct)
    assert built == [True]
    assert isinstance(res, LinemodRecall) and res.names == ["chair", "sphere"]
    assert res.recall["chair"] == 1.0
    # The sphere's two templates carry rotations of views 0 and 1; at most those frames are right.
    assert res.recall["sphere"] <= 2 / 8
    assert res.max == 1.0 and res.min == res.recall["sphere"]
    assert res.mean == pytest.approx((1.0 + res.recall["sphere"]) / 2)
    assert res.templates == {"chair": 8, "sphere": 2} and res.refused == {"chair": 0, "sphere": 0}
    assert res.match_seconds["chair"].shape == (8,) and (res.match_seconds["chair"] > 0).all()
    # Re-scoring with a criterion that ignores translation reuses the matches.
    rot_only = res.rescore(lambda R_est, t_est, f: rotation_deg(R_est, f["R"]) < 5)
    assert rot_only.recall["chair"] == 1.0 and rot_only.matches is res.matches


def test_protocol_counts_frames_without_match_as_wrong(chair_views, chair_detector):
    frames = [chair_views[0][0], np.zeros((K.height, K.width), np.float32)]
    res = linemod_recall([("c", chair_detector)], frames, lambda R, t, f: True, threshold=50, depth_of=lambda f: f)
    assert res.correct["c"].tolist() == [True, False] and res.matches["c"][1] is None


# ---------------------------------------------------------------------------------- errors
def test_depth_to_mm_converts_and_validates():
    d = np.array([[0.0, 1.2344, np.nan], [np.inf, 2.0, 0.0005]], np.float32)
    np.testing.assert_array_equal(depth_to_mm(d), [[0, 1234, 0], [0, 2000, 0]])
    with pytest.raises(ValueError, match="depth: expected a 2D"):
        depth_to_mm(np.zeros((2, 2, 1), np.float32))
    with pytest.raises(ValueError, match="float depth in metres"):
        depth_to_mm(np.zeros((2, 2), np.uint16))
    with pytest.raises(ValueError, match="negative"):
        depth_to_mm(np.full((2, 2), -1.0))
    with pytest.raises(ValueError, match="millimetres"):
        depth_to_mm(np.full((2, 2), 2500.0))


def test_bad_views_and_queries_raise_naming_the_argument(chair_views, chair_detector):
    depth, R, t = chair_views[0]
    det = LinemodDetector()
    with pytest.raises(ValueError, match="depth: shape"):
        det.add_view(depth[:240], None, R, t)
    with pytest.raises(ValueError, match="mask: shape"):
        det.add_view(depth, np.ones((10, 10), bool), R, t)
    with pytest.raises(ValueError, match="mask: no object pixel"):
        det.add_view(depth, np.zeros(depth.shape, bool), R, t)
    with pytest.raises(ValueError, match="R: not a rotation"):
        det.add_view(depth, None, 2 * R, t)
    with pytest.raises(ValueError, match="R: expected"):
        det.add_view(depth, None, R[:2], t)
    with pytest.raises(ValueError, match="t: the object origin"):
        det.add_view(depth, None, R, -t)
    with pytest.raises(ValueError, match="t: expected"):
        det.add_view(depth, None, R, [1.0, 2.0])
    assert det.n_views == 0  # nothing half-added
    with pytest.raises(ValueError, match="threshold"):
        chair_detector.match(depth, threshold=120)
    with pytest.raises(ValueError, match="top"):
        chair_detector.matches(depth, top=0)
    with pytest.raises(ValueError, match="from_views: .* differ in length"):
        LinemodDetector.from_views([depth], None, [R, R], [t])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"distance_threshold_mm": 0}, "distance_threshold_mm"),
        ({"num_features": 2.5}, "num_features"),
        ({"pyramid": ()}, "pyramid"),
        ({"pyramid": (5, 0)}, "pyramid"),
        ({"anchor_points": -1}, "anchor_points"),
    ],
)
def test_bad_parameters_raise_naming_them(kwargs, name):
    with pytest.raises(ValueError, match=name):
        LinemodDetector(**kwargs)


def test_bad_protocol_inputs_raise(chair_detector):
    frame = {"depth": np.zeros((K.height, K.width), np.float32)}
    ok = lambda R, t, f: True  # noqa: E731
    with pytest.raises(ValueError, match="test_frames: empty"):
        linemod_recall([("c", chair_detector)], [], ok)
    with pytest.raises(ValueError, match="instances: empty"):
        linemod_recall([], [frame], ok)
    with pytest.raises(TypeError, match="is_correct"):
        linemod_recall([("c", chair_detector)], [frame], None)
    with pytest.raises(TypeError, match="pass depth_of"):
        linemod_recall([("c", chair_detector)], [object()], ok)
    with pytest.raises(ValueError, match="duplicate instance name 'c'"):
        linemod_recall([("c", chair_detector), ("c", chair_detector)], [frame], ok)
    with pytest.raises(TypeError, match=r"instances\['x'\]"):
        linemod_recall([("x", 3)], [frame], ok)
    with pytest.raises(TypeError, match="intrinsics"):
        LinemodDetector(intrinsics=(1, 2))


def test_bench_timing_function_reports_every_threshold(chair_views, chair_detector):
    # benches/bench_linemod.py's linemod_timings is what the lead's ISA-vs-Linemod bench imports.
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benches" / "bench_linemod.py"
    spec = importlib.util.spec_from_file_location("bench_linemod", path)
    bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = bench  # its dataclasses look their module up there
    spec.loader.exec_module(bench)
    depths = [chair_views[0][0], np.zeros_like(chair_views[0][0])]
    out = bench.linemod_timings(chair_detector, depths, thresholds=(0, 80), repeats=2)
    assert set(out) == {0, 80}
    for r in out.values():
        assert r["match_ms"].shape == (2,) and (r["match_ms"] > 0).all() and (r["opencv_ms"] > 0).all()
    assert out[80]["matched"] == 0.5  # the empty frame matches nothing at 80 %

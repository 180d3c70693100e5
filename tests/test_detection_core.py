"""The core's detection path (``isa._core.detect`` behind ``isa.detection.detect``) against the
numpy path it replaced (tests/detect_reference, the same rules in numpy), on rendered rooms:
the same planes within the RANSAC samples' difference, and, given the same planes, the same
detections; the shape library's ``.isl`` file and the parameters mirrored from the core."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from isa import _core
from isa.camera import KINECT_V1
from isa.detection.planes import PlaneParams, remove_planes
from isa.detection.shapes import ShapeLibrary, shape_library
from isa.render.noise import DEPTH_TOLERANCE
from test_detection_scene import EYE, _room


@pytest.fixture(scope="module")
def chairs():
    from isa.render.dataset import procedural_objects

    return [o.mesh for o in procedural_objects("chair", 3, seed=5)]


def test_planes_match_the_numpy_path(chairs):
    import detect_reference.planes as ref

    depth, _, Rg = _room(chairs[0], 0.3, 0.5, 0.7)
    new = remove_planes(depth, KINECT_V1, Rg)
    old = ref.remove_planes(depth, KINECT_V1, Rg)
    assert [p.kind for p in new.planes] == [p.kind for p in old.planes] == ["floor", "wall"]
    assert new.floor.height == pytest.approx(old.floor.height, abs=2e-3)
    assert new.floor.height == pytest.approx(-EYE[2], abs=0.01)
    nw, ow = new.planes[1], old.planes[1]
    assert abs(float(nw.normal @ ow.normal)) > math.cos(math.radians(0.5))
    assert abs(nw.offset) == pytest.approx(abs(ow.offset), abs=0.01)
    valid = depth > 0
    assert np.mean(new.removed[valid] == old.removed[valid]) > 0.995


def test_parameters_are_the_cores():
    from isa.detection import DetectParams, ProposalParams, RefineParams, VerifyParams

    d = _core.DETECT_DEFAULTS
    assert json.loads(json.dumps(DetectParams().to_dict())) == d  # every default, nested ones included
    assert VerifyParams().lateral == d["verify"]["lateral"] and RefineParams().to_dict() == d["refine"]
    assert ProposalParams().to_dict() == d["proposals"]
    assert PlaneParams().to_dict()["tolerance"] == tuple(d["planes"]["tolerance"])
    assert tuple(d["verify"]["tolerance"]) == DEPTH_TOLERANCE  # the sensor's tolerance, as the renderer's noise
    with pytest.raises(ValueError, match="nms_iou"):
        _core.detect(np.zeros((4, 4), np.float32), (1.0, 1.0, 2.0, 2.0), [], None, None, {"nms_iou": 2.0})
    with pytest.raises(ValueError, match="verfy"):
        _core.detect(np.zeros((4, 4), np.float32), (1.0, 1.0, 2.0, 2.0), [], None, None, {"verfy": {}})


def test_parameter_classes_are_made_from_the_core_sections():
    import dataclasses

    from isa.detection import DetectParams, RefineParams
    from isa.detection.stage_params import core_params

    d = _core.DETECT_DEFAULTS
    for cls, section in ((PlaneParams, d["planes"]), (RefineParams, d["refine"]), (DetectParams, d)):
        assert {f.name for f in dataclasses.fields(cls)} == set(section)  # one field per core key, no more
    assert DetectParams(stride=6).to_dict() == {**DetectParams().to_dict(), "stride": 6}
    with pytest.raises(TypeError):
        RefineParams(8)  # keyword-only: the field order is the core's, not a documented one
    with pytest.raises(dataclasses.FrozenInstanceError):
        RefineParams().iterations = 3  # type: ignore[misc]
    with pytest.raises(TypeError, match="itrations"):  # a declared field the core lacks is refused at class creation

        @core_params("refine")
        class Bad:
            itrations: int = 3


def test_settings_overlay_top_level_and_nested_keys_and_the_core_checks_them():
    from isa.detection import DetectParams
    from isa.detection.evaluate import with_settings

    p = with_settings(DetectParams(), "max_hypotheses=10,proposals.cell=0.04,refine.fix_height=true")
    want = DetectParams().to_dict()
    want["max_hypotheses"] = 10
    want["proposals"]["cell"] = 0.04
    want["refine"]["fix_height"] = True
    assert p.to_dict() == want
    # A list value keeps its commas; a value that is not JSON is refused naming its setting.
    p = with_settings(DetectParams(), "size_steps=[0.7,0.85,1.15,1.4],max_hypotheses=12")
    assert (p.size_steps, p.max_hypotheses) == ([0.7, 0.85, 1.15, 1.4], 12)
    with pytest.raises(ValueError, match="'turns=two'"):
        with_settings(DetectParams(), "max_hypotheses=10,turns=two")
    # The core validates the overlay when it is used (a negative cell is refused by name).
    depth = np.full((48, 64), 2.0, np.float32)
    with pytest.raises(ValueError, match="proposals.cell"):
        _core.detect(depth, KINECT_V1.K, [], params=with_settings(DetectParams(), "proposals.cell=-1").to_dict())
    # NMS orders: names the core knows, and ranking everything first only with one joint NMS.
    with pytest.raises(ValueError, match="nms_order"):
        _core.detect(depth, KINECT_V1.K, [], params=DetectParams(nms_order="sideways").to_dict())
    with pytest.raises(ValueError, match="nms_order"):
        _core.detect(depth, KINECT_V1.K, [], params=DetectParams(rank_before_nms=True, nms_order="ranked").to_dict())


def test_shape_library_isl_roundtrip_and_errors(tmp_path, chairs):
    from isa.exceptions import DataError

    lib = shape_library("chair", chairs, n_points=500)
    assert lib.size_range is not None  # the category's real-world sizes
    lib.save(tmp_path / "chair.shapes.isl")
    back = ShapeLibrary.load(tmp_path / "chair.shapes.isl")
    for k in ("points", "normals", "spacing", "bounds"):
        np.testing.assert_array_equal(getattr(back, k), getattr(lib, k))
    assert (back.category, back.names, back.size_range) == (lib.category, lib.names, lib.size_range)
    raw = (tmp_path / "chair.shapes.isl").read_bytes()
    (tmp_path / "cut.isl").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataError, match="cut.isl"):
        ShapeLibrary.load(tmp_path / "cut.isl")
    assert not list(tmp_path.glob("*.tmp*"))


@pytest.mark.slow
def test_core_detect_matches_the_numpy_path_on_a_rendered_room(monkeypatch):
    """A tiny chair forest registered as chair and toilet over a room with two chairs: the core
    and the numpy path, given the same planes, give the same ranked detections."""
    import detect_reference.multi as ref_multi
    import detect_reference.planes as ref_planes
    from isa.detection import DetectParams, detect, train_detector
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel
    from isa.forest import ForestParams
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("chair", 3, seed=7)
    params = ForestParams(n_trees=3, max_depth=12, n_candidates=30, quality="Q1")
    forest, prepared = train_detector("chair", objs, views=20, stride=6, use_ground_truth=True, forest_params=params)
    lib = shape_library("chair", prepared.objects)
    depth, _, Rg = _room(prepared.objects[1].mesh, 0.3, 0.5, 0.6)
    box = model_box(forest)
    models = [CategoryModel("chair", forest, box, lib), CategoryModel("toilet", forest, box, lib)]
    # The numpy path has no footprint proposals: compare the forests' hypotheses alone.
    new = detect(depth, KINECT_V1, models, gravity=Rg, params=DetectParams(proposals=None))
    core_planes = remove_planes(depth, KINECT_V1, Rg)
    monkeypatch.setattr(ref_planes, "remove_planes", lambda *a, **k: core_planes)
    old = ref_multi.detect(depth, KINECT_V1, models, gravity=Rg)
    assert new.floor_height == pytest.approx(old.floor_height, abs=1e-9)
    assert len(new.detections) == len(old.detections) >= 2
    for n, o in zip(new.detections, old.detections):
        assert n.category == o.category and n.meta["shape"] == o.meta["shape"] and n.support == o.support
        assert n.score == pytest.approx(o.score, abs=0.01)
        np.testing.assert_allclose(n.t, o.t, atol=5e-3)
        assert math.degrees(math.acos(min(1.0, (np.trace(n.R.T @ o.R) - 1) / 2))) < 0.5
        np.testing.assert_allclose(n.size, o.size, atol=5e-3)


@pytest.mark.slow
def test_footprint_proposals_find_an_object_the_forest_gives_no_hypothesis_for():
    """With the forest's hypotheses withheld (an empty list), the footprint of a chair standing
    in a rendered room still proposes its box, and verification with the chairs' shapes puts it
    within 10 cm of the chair's true box centre; without proposals, or without verification to
    judge them, nothing is detected."""
    from isa.detection import DetectParams, train_detector
    from isa.detection.category_boxes import model_box
    from isa.forest import ForestParams
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("chair", 3, seed=7)
    params = ForestParams(n_trees=2, max_depth=8, n_candidates=20, quality="Q1")
    forest, prepared = train_detector("chair", objs, views=8, stride=8, use_ground_truth=True, forest_params=params)
    lib = shape_library("chair", prepared.objects)
    mesh = prepared.objects[1].mesh
    depth, (R, t), Rg = _room(mesh, 0.3, 0.5, 0.6)
    box = model_box(forest)
    spec = {"category": "chair", "forest": forest, "size": box.size, "ssc_offset": box.ssc_offset,
            "shapes": lib.core, "size_range": lib.size_range, "hypotheses": []}
    truth = Rg @ (R @ mesh.bounds.mean(axis=0) + t)  # the chair's box centre, upright frame
    frame = np.ascontiguousarray(depth, np.float32)
    none = _core.detect(frame, KINECT_V1, [spec], Rg, params=DetectParams(proposals=None).to_dict())
    assert none["detections"] == []
    # Without verification a proposal has nothing to be judged by: none are made.
    unverified = _core.detect(frame, KINECT_V1, [spec], Rg, params=DetectParams(verify=None).to_dict())
    assert unverified["detections"] == []
    best = _core.detect(frame, KINECT_V1, [spec], Rg, params=DetectParams().to_dict())["detections"][0]
    centre = Rg @ (np.asarray(best["R"]) @ np.asarray(best["box_centre"]) + np.asarray(best["t"]))
    assert np.linalg.norm(centre[:2] - truth[:2]) < 0.10, (centre, truth)

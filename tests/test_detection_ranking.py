"""Ranking (``isa.detection.ranking``, ``isa_core::scene::ranking``): the logistic fit against its
own optimality condition, the ranker file's checks, and the core's scores against the Python
formula on a rendered room."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from isa import _core
from isa.camera import KINECT_V1
from isa.detection.ranking import FEATURES, Ranker, fit_boosted_ranker, fit_ranker
from isa.exceptions import DataError, InputWarning, IsaError
from test_detection_scene import _room


def test_fit_is_the_penalised_likelihood_optimum():
    """Labels drawn from a known logistic model: the fit's weights have the true signs, and the
    objective's gradient (written out here on the raw features) vanishes at them."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(600, 3)) * [1.0, 2.0, 0.5] + [0.0, 1.0, 3.0]
    y = rng.random(600) < 1 / (1 + np.exp(-(2.0 * X[:, 0] - 1.0 * X[:, 1] + 0.5)))
    names = ("agree", "violate", "depth")
    r = fit_ranker("chair", X, y, names, c=1.0)
    w, mean = np.array(r.weights), np.array(r.mean)
    assert w[0] > 0 > w[1] and abs(w[2]) < 0.3 * min(abs(w[0]), abs(w[1]))
    # Objective: sum log(1 + exp(-s (Z w + b))) + |w|^2 / 2, Z the standardised features.
    Z = (X - X.mean(0)) / X.std(0)
    s = np.where(y, 1.0, -1.0)
    m = s * (Z @ w + r.bias)
    g = -s / (1 + np.exp(m))
    np.testing.assert_allclose(np.append(Z.T @ g + w, g.sum()), 0.0, atol=1e-3)
    np.testing.assert_allclose(mean, X.mean(0))
    # The probability is the logistic of the linear score.
    p = [r.probability(dict(zip(names, x))) for x in X[:5]]
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-(Z[:5] @ w + r.bias))), rtol=1e-12)


def test_boosted_ranker_is_scikit_learns_gradient_boosting():
    """Labels from a rule no linear score can follow (true inside a band of depth): the exported
    trees give scikit-learn's own probabilities, the file round-trips, and the boosted ranker
    orders the band above the rest where the logistic one cannot."""
    from sklearn.ensemble import GradientBoostingClassifier

    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(0.5, 5.0, 800), rng.normal(size=800)])
    y = (np.abs(X[:, 0] - 2.5) < 0.7) ^ (rng.random(800) < 0.1)
    names = ("depth", "agree")
    r = fit_boosted_ranker("chair", X, y, names, n_trees=30, depth=2, seed=3)
    ref = GradientBoostingClassifier(n_estimators=30, max_depth=2, learning_rate=0.05, min_samples_leaf=20,
                                     random_state=3).fit(X, y)
    p = np.array([r.probability(dict(zip(names, x))) for x in X])
    np.testing.assert_allclose(p, ref.predict_proba(X)[:, 1], rtol=1e-9, atol=1e-12)
    assert Ranker.from_json(r.to_json()) == r and len(r.trees) == 30

    def ap(score):  # average precision of the ordering
        hit = y[np.argsort(-score, kind="stable")]
        return float(np.mean(np.cumsum(hit)[hit] / (np.flatnonzero(hit) + 1)))

    lin = fit_ranker("chair", X, y, names)
    p_lin = np.array([lin.probability(dict(zip(names, x))) for x in X])
    assert ap(p) > 0.8 > 0.6 > ap(p_lin)


def test_fit_needs_both_outcomes():
    with pytest.raises(IsaError, match="true and false"):
        fit_ranker("chair", np.zeros((4, 1)), np.ones(4, bool), ("agree",))


@pytest.mark.parametrize("kw, needle", [({"n_trees": 0}, "n_trees"), ({"depth": 1.5}, "depth"),
                                        ({"min_leaf": -1}, "min_leaf"), ({"learning_rate": 0.0}, "learning_rate")])
def test_boosted_fit_refuses_bad_settings_by_name(kw, needle):
    X, y = np.arange(8.0)[:, None], np.arange(8) % 2 == 0
    with pytest.raises(ValueError, match=needle) as e:
        fit_boosted_ranker("chair", X, y, ("agree",), **kw)
    assert isinstance(e.value, IsaError)
    with pytest.raises(IsaError, match="c must be positive"):
        fit_ranker("chair", X, y, ("agree",), c=0.0)


def test_ranker_file_roundtrip_and_errors(tmp_path):
    r = Ranker("chair", ("agree", "log_forest_score"), (0.5, -1.0), (0.2, 1.5), (2.0, 0.3), -1.0, "test")
    r.save(tmp_path / "chair.ranker.json")
    assert Ranker.load(tmp_path / "chair.ranker.json") == r
    with pytest.raises(DataError, match="nothere.ranker.json"):
        Ranker.load(tmp_path / "nothere.ranker.json")
    doc = json.loads(r.to_json())
    for key, value, needle in [("features", ["agree", "agreement"], "unknown feature"),
                               ("scale", [0.2, 0.0], "scales positive"),
                               ("weights", [1.0], "2 features"),
                               ("format", 99, "format 99")]:
        (tmp_path / "bad.json").write_text(json.dumps(dict(doc, **{key: value})))
        with pytest.raises(ValueError, match=needle) as e:
            Ranker.load(tmp_path / "bad.json")
        assert "bad.json" in str(e.value) and isinstance(e.value, IsaError)
    # The NMS order it was fitted under round-trips; an unknown one is refused, naming the file.
    ordered = replace(r, nms_order="ranked")
    ordered.save(tmp_path / "ordered.ranker.json")
    assert Ranker.load(tmp_path / "ordered.ranker.json") == ordered and r.nms_order is None
    (tmp_path / "bad.json").write_text(json.dumps(dict(doc, nms_order="sideways")))
    with pytest.raises(ValueError, match="bad.json.*sideways"):
        Ranker.load(tmp_path / "bad.json")


@pytest.fixture(scope="module")
def chair_room():
    """A small chair forest and shape library trained on 3 procedural chairs, and a rendered
    room with two of them: (forest, library, depth, gravity)."""
    from isa.detection import train_detector
    from isa.detection.shapes import shape_library
    from isa.forest import ForestParams
    from isa.render.dataset import procedural_objects

    objs = procedural_objects("chair", 3, seed=7)
    params = ForestParams(n_trees=2, max_depth=10, n_candidates=20, quality="Q1")
    forest, prepared = train_detector("chair", objs, views=12, stride=8, use_ground_truth=True, forest_params=params)
    lib = shape_library("chair", prepared.objects)
    depth, _, Rg = _room(prepared.objects[1].mesh, 0.3, 0.5, 0.6)
    return forest, lib, depth, Rg


@pytest.mark.slow
def test_core_scores_are_the_rankers_probabilities_on_a_rendered_room(chair_room):
    """Two chairs in a rendered room. Without a ranker every detection carries its features, and
    a refined one (verified with all its shape's points, as ranking does) scores the
    `verify_score` feature plus the forest term; with a ranker, each score is
    the ranker's probability of its features (computed here in Python) and the list is sorted by
    it."""
    from isa.detection import DetectParams
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel, detect

    forest, lib, depth, Rg = chair_room
    model = CategoryModel("chair", forest, model_box(forest), lib)
    p = DetectParams()
    plain = detect(depth, KINECT_V1, [model], gravity=Rg, params=p).detections
    assert len(plain) >= 2 and any(d.meta["refined"] for d in plain)
    for d in plain:
        f = d.meta["features"]
        assert set(f) == set(FEATURES)
        if d.meta["refined"]:
            assert d.score == pytest.approx(f["verify_score"] + p.forest_weight * f["log_forest_score"], abs=1e-9)
        cells = f["agree"] + f["violate"] + f["occluded"] + f["outside"]
        assert cells == pytest.approx(1.0) and f["log_agree"] > 0
    ranker = Ranker("chair", ("agree", "violate", "log_support"), (0.5, 0.1, 3.0), (0.2, 0.1, 1.0), (2.0, -1.0, 0.5),
                    0.1, nms_order=p.nms_order)
    ranked = detect(depth, KINECT_V1, [CategoryModel("chair", forest, model_box(forest), lib, ranker)], gravity=Rg,
                    params=p).detections
    assert len(ranked) == len(plain)
    for d in ranked:
        assert d.score == pytest.approx(ranker.probability(d.meta["features"]), rel=1e-12)
    scores = [d.score for d in ranked]
    assert scores == sorted(scores, reverse=True)
    # The same detections (NMS ran before ranking), in the ranker's order.
    key = lambda d: tuple(np.round(d.t, 9))  # noqa: E731
    assert sorted(map(key, ranked)) == sorted(map(key, plain))
    # Ranked before NMS: every candidate scored by the ranker, then suppressed; what stays is
    # still the ranker's probability of its features, best first, and no two kept boxes
    # overlap beyond the NMS threshold.
    from dataclasses import replace

    from isa.evaluation.boxes3d import iou_3d

    joint_ranker = replace(ranker, nms_order="joint")
    pre = detect(depth, KINECT_V1, [CategoryModel("chair", forest, model_box(forest), lib, joint_ranker)], gravity=Rg,
                 params=replace(p, rank_before_nms=True, nms_order="joint")).detections
    assert pre and [d.score for d in pre] == sorted((d.score for d in pre), reverse=True)
    for d in pre:
        assert d.score == pytest.approx(ranker.probability(d.meta["features"]), rel=1e-12)
    boxes = [d.box(Rg) for d in pre]
    assert all(iou_3d(a, b) <= p.nms_iou + 1e-9 for i, a in enumerate(boxes) for b in boxes[i + 1:])
    # A boosted ranker (two stumps on the agreement and the depth, and a linear term): the core's
    # scores are its probabilities too.
    stump = lambda k, thr, lo, hi: {"feature": (k, -1, -1), "threshold": (thr, 0.0, 0.0),  # noqa: E731
                                    "left": (1, 0, 0), "right": (2, 0, 0), "value": (0.0, lo, hi)}
    med = np.median([d.meta["features"]["agree"] for d in plain])
    boosted = replace(ranker, trees=(stump(0, float(med), -1.0, 1.5), stump(0, 0.3, -0.5, 0.2)))
    got = detect(depth, KINECT_V1, [CategoryModel("chair", forest, model_box(forest), lib, boosted)], gravity=Rg,
                 params=p).detections
    assert len(got) == len(plain)
    for d in got:
        assert d.score == pytest.approx(boosted.probability(d.meta["features"]), rel=1e-12)
    # A ranker passed as its JSON to the core directly, with a bad one refused by name.
    spec = {"category": "chair", "forest": forest, "size": model.box.size, "ssc_offset": model.box.ssc_offset,
            "shapes": lib.core, "size_range": lib.size_range, "ranker": '{"format": 1}'}
    with pytest.raises(IsaError, match=r"models\[0\].ranker"):
        _core.detect(np.ascontiguousarray(depth, np.float32), KINECT_V1, [spec], Rg, params=p.to_dict())


@pytest.mark.slow
def test_nms_orders_per_category_is_each_category_alone_and_ranked_lets_the_probability_decide(chair_room):
    """Two chairs in a rendered room and one chair model entered twice, as "chair" and as
    "toilet": every box has a twin of the other category. ``per_category`` gives, per category,
    exactly what that model alone gives (one category: NMS within it); ``joint`` leaves no two
    overlapping boxes, ``ranked`` none overlapping beyond ``cross_iou`` across categories; and
    ``ranked``, with a ranker sure of chairs and one doubting toilets, keeps the chairs of the
    chair model alone, each with its probability, and no toilet on them; a ranker fitted
    under another order than detection's warns, and so does one that does not record its order
    under any but "joint"."""
    from isa.detection import DetectParams
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel, detect
    from isa.evaluation.boxes3d import iou_3d

    forest, lib, depth, Rg = chair_room
    box = model_box(forest)
    sure = Ranker("chair", ("agree",), (0.0,), (1.0,), (0.0,), 5.0)
    doubt = Ranker("toilet", ("agree",), (0.0,), (1.0,), (0.0,), -5.0)
    chair, toilet = CategoryModel("chair", forest, box, lib, sure), CategoryModel("toilet", forest, box, lib, doubt)
    p = DetectParams(nms_order="joint")
    pose = lambda d: tuple(np.round(np.r_[np.ravel(d.R), d.t], 9))  # noqa: E731
    alone = {m.category: detect(depth, KINECT_V1, [m], gravity=Rg, params=p).detections for m in (chair, toilet)}
    assert len(alone["chair"]) >= 2
    # Rankers that do not record their order are taken for "joint" ones: the other orders warn.
    unrecorded = "its ranker does not record the NMS order"
    with pytest.warns(InputWarning, match=unrecorded) as caught:
        per = detect(depth, KINECT_V1, [chair, toilet], gravity=Rg, params=replace(p, nms_order="per_category")).detections
    assert sorted(str(w.message).split(":")[0] for w in caught) == ["chair", "toilet"]
    for c in ("chair", "toilet"):
        assert sorted(pose(d) for d in per if d.category == c) == sorted(map(pose, alone[c]))
    joint = detect(depth, KINECT_V1, [chair, toilet], gravity=Rg, params=p).detections
    with pytest.warns(InputWarning, match=unrecorded):
        ranked = detect(depth, KINECT_V1, [chair, toilet], gravity=Rg, params=replace(p, nms_order="ranked")).detections
    for dets, across in ((joint, p.nms_iou), (ranked, p.cross_iou)):
        boxes = [(d.category, d.box(Rg)) for d in dets]
        assert all(iou_3d(a, b) <= (p.nms_iou if ca == cb else across) + 1e-9
                   for i, (ca, a) in enumerate(boxes) for cb, b in boxes[i + 1:])
    assert sorted(pose(d) for d in ranked if d.category == "chair") == sorted(map(pose, alone["chair"]))
    for d in ranked:
        assert d.score == pytest.approx((sure if d.category == "chair" else doubt).probability(d.meta["features"]))
    assert [d.score for d in ranked] == sorted((d.score for d in ranked), reverse=True)
    # A ranker fitted under "ranked" warns, naming its category, when detection runs "joint"
    # (it would see other detections than it learnt from), and is silent under "ranked".
    chair_r = replace(chair, ranker=replace(sure, nms_order="ranked"))
    toilet_r = replace(toilet, ranker=replace(doubt, nms_order="ranked"))
    with pytest.warns(InputWarning, match="chair: its ranker was fitted under nms_order='ranked'"):
        detect(depth, KINECT_V1, [chair_r, toilet], gravity=Rg, params=p)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        detect(depth, KINECT_V1, [chair_r, toilet_r], gravity=Rg, params=replace(p, nms_order="ranked"))


def test_rival_margins_are_the_score_gaps_to_the_best_overlapping_holding_and_held_boxes_of_another_category(chair_room):
    """A chair model and a "toilet" model with the same forest and two of the chair shapes, in a
    rendered room with two chairs; NMS off (nothing exceeds IoU or overlap 1) and no rankers, so
    every candidate is a detection with its score before ranking. Each one's ``rival_margin`` is
    its score minus the best score of the other category's detections whose box overlaps it at
    IoU >= 0.25 (computed here from the boxes), and 1 where none does; ``outer_rival_margin``
    and ``inner_rival_margin`` the same over a larger box holding at least half of it and a
    smaller box at least half inside it; a model alone has no rivals."""
    from isa.detection import DetectParams
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel, detect
    from isa.detection.shapes import ShapeLibrary
    from isa.evaluation.boxes3d import footprint_intersection_area, iou_3d

    def inter(a, b):
        dz = min(a.z_range[1], b.z_range[1]) - max(a.z_range[0], b.z_range[0])
        return footprint_intersection_area(a, b) * dz if dz > 0 else 0.0

    forest, lib, depth, Rg = chair_room
    box = model_box(forest)
    two = ShapeLibrary("toilet", lib.points[:2], lib.normals[:2], lib.spacing[:2], lib.bounds[:2],
                       lib.names[:2], lib.size_range)
    chair, toilet = CategoryModel("chair", forest, box, lib), CategoryModel("toilet", forest, box, two)
    p = replace(DetectParams(), nms_order="per_category", nms_iou=1.0, nms_overlap=1.0, max_detections=100_000)
    dets = detect(depth, KINECT_V1, [chair, toilet], gravity=Rg, params=p).detections
    assert {d.category for d in dets} == {"chair", "toilet"}
    boxes = [d.box(Rg) for d in dets]
    gaps, covered = [], {"outer_rival_margin": 0, "inner_rival_margin": 0}
    for i, d in enumerate(dets):
        rivals = [e.score for j, e in enumerate(dets)
                  if e.category != d.category and iou_3d(boxes[i], boxes[j]) >= 0.25]
        want = d.score - max(rivals) if rivals else 1.0
        assert d.meta["features"]["rival_margin"] == pytest.approx(want, abs=1e-9)
        gaps += [want] if rivals else []
        others = [(e, boxes[j], inter(boxes[i], boxes[j])) for j, e in enumerate(dets) if e.category != d.category]
        v = boxes[i].volume
        outer = [e.score for e, b, x in others if x > 0 and b.volume >= v and x >= 0.5 * v]
        inner = [e.score for e, b, x in others if x > 0 and b.volume <= v and x >= 0.5 * b.volume]
        for name, found in (("outer_rival_margin", outer), ("inner_rival_margin", inner)):
            want = d.score - max(found) if found else 1.0
            assert d.meta["features"][name] == pytest.approx(want, abs=1e-6), name
            covered[name] += bool(found)
    assert gaps and min(gaps) < 0 < max(gaps), gaps  # both sides of the margin are exercised
    assert min(covered.values()) > 0, covered
    alone = detect(depth, KINECT_V1, [chair], gravity=Rg, params=p).detections
    assert alone and all(d.meta["features"][n] == 1.0 for d in alone
                         for n in ("rival_margin", "outer_rival_margin", "inner_rival_margin"))


@pytest.mark.parametrize("features, needle", [("agree,agreement", "unknown or repeated agreement"),
                                              ("agree,depth,agree", "unknown or repeated names")])
def test_ranking_cli_refuses_unknown_or_repeated_features_before_any_work(tmp_path, capsys, features, needle):
    from isa.detection.ranking import main

    # No scene root or model exists: the refusal must come before anything is read.
    with pytest.raises(SystemExit) as e:
        main(["--scenes", str(tmp_path / "none"), "--model", f"chair={tmp_path / 'none.isa'}",
              "--features", features, "-o", str(tmp_path / "out")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert needle in err and "known: " + ", ".join(FEATURES) in err
    assert not (tmp_path / "out").exists()


def test_profile_features_are_the_seen_surface_in_each_box(chair_room):
    """The profile features of every detection of a rendered room, recomputed here in numpy
    from the depth: the frame back-projected every 4th pixel into the upright frame, each point
    weighted by its pixel's area on the surface, then binned in the detection's box (planes
    left in, so every seen pixel counts). ``fill``: area inside over the box's largest vertical
    face; ``level_k``: share of it in the k-th fifth of the height; ``back_k``: in that fifth
    and the object's +y half; ``middle``: over the central half of the length and width;
    ``span_length`` / ``span_width``: the seen extent along each over the box's; ``around``: area
    within 15 cm of the sides and top, outside, over (inside + 0.01 m^2)."""
    from isa.detection import DetectParams
    from isa.detection.category_boxes import model_box
    from isa.detection.multi import CategoryModel, detect

    forest, lib, depth, Rg = chair_room
    p = replace(DetectParams(), remove_planes=False, nms_iou=1.0, nms_overlap=1.0, max_detections=100_000,
                nms_order="per_category")
    dets = detect(depth, KINECT_V1, [CategoryModel("chair", forest, model_box(forest), lib)], gravity=Rg,
                  params=p).detections
    assert len(dets) > 5
    k = KINECT_V1
    v, u = np.mgrid[0:depth.shape[0]:4, 0:depth.shape[1]:4]
    z = depth[v, u].astype(float)
    ok = z > 0
    u, v, z = u[ok], v[ok], z[ok]
    pts = (Rg @ np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z])).T
    area = (4 * z / k.fx) * (4 * z / k.fy)
    filled = 0
    for d in dets:
        b = d.box(Rg)
        c, s = np.cos(b.yaw), np.sin(b.yaw)
        dx, dy = pts[:, 0] - b.centre[0], pts[:, 1] - b.centre[1]
        x, y, h = dx * c + dy * s, -dx * s + dy * c, pts[:, 2] - (b.centre[2] - b.size[2] / 2)
        half = b.size[:2] / 2
        inside = (np.abs(x) <= half[0]) & (np.abs(y) <= half[1]) & (h >= 0) & (h <= b.size[2])
        shell = ((np.abs(x) <= half[0] + 0.15) & (np.abs(y) <= half[1] + 0.15) & (h >= 0) & (h <= b.size[2] + 0.15)
                 & ~inside)
        a_in = area[inside].sum()
        level = np.minimum((h[inside] / b.size[2] * 5).astype(int), 4)
        f = d.meta["features"]
        assert f["fill"] == pytest.approx(a_in / (max(b.size[:2]) * b.size[2]), rel=1e-9, abs=1e-12)
        assert f["around"] == pytest.approx(area[shell].sum() / (a_in + 0.01), rel=1e-9, abs=1e-12)
        if a_in > 0:
            filled += 1
            want = np.bincount(level, weights=area[inside], minlength=5) / a_in
            assert [f[f"level_{i + 1}"] for i in range(5)] == pytest.approx(want, abs=1e-9)
            back = np.bincount(level[y[inside] > 0], weights=area[inside][y[inside] > 0], minlength=5) / a_in
            assert [f[f"back_{i + 1}"] for i in range(5)] == pytest.approx(back, abs=1e-9)
            mid = inside & (np.abs(x) <= half[0] / 2) & (np.abs(y) <= half[1] / 2)
            assert f["middle"] == pytest.approx(area[mid].sum() / a_in, abs=1e-9)
            assert f["span_length"] == pytest.approx(np.ptp(x[inside]) / b.size[0], abs=1e-9)
            assert f["span_width"] == pytest.approx(np.ptp(y[inside]) / b.size[1], abs=1e-9)
    assert filled >= 3  # boxes on the chairs see their surface

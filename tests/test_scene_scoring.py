"""Scene scoring: greedy matching, VOC AP, ignored objects, symmetric 6D matches (isa.scenes.scoring)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from isa.evaluation.boxes3d import Box3D, average_precision, rot_z
from isa.exceptions import InvalidInputError
from isa.privileged.symmetry import YawSymmetry
from isa.scenes.io import GroundTruth, box_points
from isa.scenes.scoring import Detection, evaluate, symmetry_transforms

SIZE = np.array([0.5, 0.5, 0.9])


def GT(category, R, t, size, visib_fract, symmetries=(), points=None, symmetry_centre=None):
    """A ground-truth record as isa.scenes.io reads it (box corners and centre without a mesh)."""
    size = np.asarray(size, float)
    if points is None:
        points = box_points(-size / 2, size)
    return GroundTruth(1, category, R, t, size, visib_fract, list(symmetries) if not isinstance(symmetries, str)
                       else symmetries, points, np.zeros(3) if symmetry_centre is None else symmetry_centre)


def cuboid_points(size, n=2000, seed=0, centre=(0.0, 0.0, 0.0)):
    """Seeded points on the surface of an axis-aligned cuboid."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.5, 0.5, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(p[np.arange(n), axis]) * 0.5
    return p * np.asarray(size) + np.asarray(centre)


def det(t, score, R=None, size=SIZE, category="chair"):
    return Detection(category, np.eye(3) if R is None else R, np.asarray(t, float), size, score)


def gt(t, visib, R=None, category="chair", **kw):
    return GT(category, np.eye(3) if R is None else R, np.asarray(t, float), SIZE, visib, **kw)


def hand_case():
    frames_gt = [[gt((0, 0, 3), 0.9), gt((1.5, 0, 3), 0.2)], [gt((-1, 0, 4), 0.5)]]
    frames_det = [
        [det((0, 0, 3), 0.9),          # on a: true positive
         det((0.01, 0, 3), 0.8),       # on a again: duplicate, false positive
         det((1.5, 0, 3), 0.7)],       # on b (visib 0.2 < 0.3): ignored
        [det((1, 0.5, 6), 0.6),        # on nothing: false positive
         det((-1.02, 0, 4), 0.5)],     # on c: true positive, 2 cm off
    ]
    return frames_gt, frames_det


def test_hand_computed_case():
    # Ranked without the ignored one: TP, FP, FP, TP over 2 counted objects. Precision 1, 1/2, 1/3,
    # 1/2 at recall 1/2, 1/2, 1/2, 1; made monotone: 1 up to recall 1/2, 1/2 up to 1 -> AP 0.75.
    s = evaluate(*hand_case())
    for m in ("6d", "6d_sym", "box_0.25", "box_0.5"):
        r = s.metrics["chair"][m]
        assert r.ap == pytest.approx(0.75), m
        assert (r.n_ground_truth, r.n_ignored, r.n_detections, r.n_true_positive) == (2, 1, 4, 2)
        assert r.final_recall == 1.0
        np.testing.assert_allclose(r.precision, [1, 1 / 2, 1 / 3, 1 / 2])
        np.testing.assert_allclose(r.recall, [0.5, 0.5, 0.5, 1.0])
        # Every bin's one object is found (the ignored one too, by the detection on it).
        assert r.recall_by_visib == {"0.1-0.3": (1.0, 1), "0.3-0.6": (1.0, 1), "0.6-1": (1.0, 1)}
        # Only the 0.6-1 object counted: TP, FP, FP (the rest land on ignored objects) -> AP 1.
        assert r.ap_by_visib["0.6-1"] == pytest.approx(1.0)
        # TPs are 0 and 2 cm off.
        assert r.median_translation_m == pytest.approx(0.01)
        assert r.median_rotation_deg == pytest.approx(0.0)
    assert [o["6d"] for o in s.outcome[0]] == ["tp", "fp", "ignored"]
    assert [o["box_0.25"] for o in s.outcome[1]] == ["fp", "tp"]
    # Without the visibility filter the low object counts: TP, FP, TP, FP, TP over 3.
    r = evaluate(*hand_case(), min_visib=0.0).metrics["chair"]["6d"]
    assert (r.n_ground_truth, r.n_ignored, r.n_true_positive) == (3, 0, 3)
    # precision 1, .5, .667, .5, .6 at recall 1/3, 1/3, 2/3, 2/3, 1 -> 1/3 + 1/3 * 2/3 + 1/3 * 0.6
    assert r.ap == pytest.approx(1 / 3 + 2 / 9 + 0.2)


def voc_all_points(tp: np.ndarray, n_gt: int) -> float:
    """PASCAL VOC 2010+ AP written out: sum over the ranks where recall rises of the rise times
    the best precision at that rank or any later one."""
    ap, prev_recall, hits = 0.0, 0.0, 0
    precision = np.cumsum(tp) / np.arange(1, len(tp) + 1)
    for k in range(len(tp)):
        hits += tp[k]
        recall = hits / n_gt
        if recall > prev_recall:
            ap += (recall - prev_recall) * precision[k:].max()
            prev_recall = recall
    return ap


def random_boxes(seed):
    rng = np.random.default_rng(seed)
    gts, dets = [], []
    for _ in range(8):
        g = [Box3D("chair", (rng.uniform(-2, 2), rng.uniform(1, 5), 0.45), (0.5, 0.5, 0.9), rng.uniform(-3, 3))
             for _ in range(rng.integers(0, 4))]
        d = []
        for b in g:
            for _ in range(rng.integers(0, 3)):  # misses, hits and duplicates
                d.append(b.replace(centre=b.centre + rng.normal(0, 0.12, 3), score=rng.uniform()))
        d += [Box3D("chair", (rng.uniform(-2, 2), rng.uniform(1, 5), 0.45), (0.5, 0.5, 0.9), 0.0, rng.uniform())
              for _ in range(rng.integers(0, 3))]
        gts.append(g)
        dets.append(d)
    return gts, dets


@pytest.mark.parametrize("seed", range(5))
def test_box_ap_is_voc_all_points(seed):
    gts, dets = random_boxes(seed)
    s = evaluate(gts, dets, categories=["chair"])
    r = s.metrics["chair"]["box_0.25"]
    ranked = sorted(((d.score, o["box_0.25"]) for fd, fo in zip(dets, s.outcome) for d, o in zip(fd, fo)),
                    key=lambda x: -x[0])
    tp = np.array([o == "tp" for _, o in ranked])
    n_gt = sum(len(g) for g in gts)
    assert r.n_ground_truth == n_gt and 0 < r.n_true_positive < len(tp)
    assert r.ap == pytest.approx(voc_all_points(tp, n_gt))
    # The same numbers as isa.evaluation.boxes3d's evaluation (the real-data path today), at both thresholds.
    for thr, m in ((0.25, "box_0.25"), (0.5, "box_0.5")):
        ref = average_precision(dets, gts, "chair", iou_threshold=thr)
        assert s.metrics["chair"][m].ap == pytest.approx(ref.ap)
        np.testing.assert_allclose(s.metrics["chair"][m].precision, ref.precision)
    # No poses on either side: the 6D metrics do not apply; nothing is in a visibility bin.
    assert s.metrics["chair"]["6d"] is None and s.metrics["chair"]["6d_sym"] is None
    assert all(n == 0 for _, n in r.recall_by_visib.values())


TABLE = np.array([1.2, 0.8, 0.75])


@pytest.mark.parametrize("form", ["3x3", "4x4", "yaw"])
def test_table_turned_half_way_counts_only_with_symmetries(form):
    # A rectangular table whose frame origin is off its symmetry axis (a centre-of-mass or SSC
    # origin need not lie on it): the axis is the vertical through c in the object frame.
    c = np.array([0.1, -0.05, 0.2])
    pts = cuboid_points(TABLE, centre=c)
    g = rot_z(math.pi)
    # As isa.scenes.io reads models_info: the group's rotations about the vertical through a centre.
    sym = {"3x3": [np.eye(3), g], "4x4": [np.block([[g, (c - g @ c)[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])],
           "yaw": [YawSymmetry(c, 2, 0.0)]}[form]
    R = rot_z(0.3) @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # object z up -> camera -y
    t = np.array([0.2, 0.4, 3.0])
    truth = GT("table", R, t, TABLE, 0.8, sym, pts, c if form == "3x3" else None)
    turned = Detection("table", R @ g, t + R @ (c - g @ c), TABLE, 1.0, c)  # the same surface
    s = evaluate([[truth]], [[turned]])
    m = s.metrics["table"]
    assert m["6d"].ap == 0.0
    assert m["6d_sym"].ap == 1.0
    assert m["6d_sym"].median_rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert m["box_0.5"].ap == 1.0  # the box does not see the turn
    # A genuinely wrong turn (90 degrees) is wrong under both.
    q = rot_z(math.pi / 2)
    wrong = Detection("table", R @ q, t + R @ (c - q @ c), TABLE, 1.0, c)
    assert evaluate([[truth]], [[wrong]]).metrics["table"]["6d_sym"].ap == 0.0


def test_round_table_any_turn():
    pts = cuboid_points((0.9, 0.9, 0.7))
    r = np.hypot(pts[:, 0], pts[:, 1])
    pts = pts[r <= 0.45]  # near enough round about z for a 0.1-diameter threshold
    c = np.array([0.0, 0.0, -0.3])  # a centre on the axis, below the origin: the turn moves nothing
    truth = GT("table", np.eye(3), np.array([0, 0, 3.0]), np.array([0.9, 0.9, 0.7]), 1.0, "continuous-z", pts, c)
    turned = Detection("table", rot_z(0.7), np.array([0, 0, 3.0]), np.array([0.9, 0.9, 0.7]), 1.0)
    m = evaluate([[truth]], [[turned]]).metrics["table"]
    assert m["6d"].ap == 0.0 and m["6d_sym"].ap == 1.0
    Rs, _ = symmetry_transforms(["continuous-z"])
    assert len(Rs) == 360


def test_symmetry_forms_agree():
    c = np.array([0.3, 0.0, 0.0])
    g = rot_z(math.pi)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = g, c - g @ c
    for form in (T, T.reshape(-1), YawSymmetry(c, 2, 0.0)):
        Rs, ts = symmetry_transforms([form])
        np.testing.assert_allclose(Rs[1], g, atol=1e-12)
        np.testing.assert_allclose(ts[1], c - g @ c, atol=1e-12)
    Rs, ts = symmetry_transforms([{"axis": (0, 0, 1), "offset": c}], n_continuous=4)
    np.testing.assert_allclose(Rs[2] @ c + ts[2], c, atol=1e-12)  # points on the axis stay
    Rs, ts = symmetry_transforms([np.eye(3), g], centre=c)  # isa.scenes.io's form
    np.testing.assert_allclose(ts[2], c - g @ c, atol=1e-12)
    with pytest.raises(InvalidInputError):
        symmetry_transforms(["mirror"])


def test_detection_box_round_trip_under_tilted_gravity():
    grav = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]) @ np.array(
        [[1, 0, 0], [0, math.cos(0.4), -math.sin(0.4)], [0, math.sin(0.4), math.cos(0.4)]])
    box = Box3D("chair", (0.5, 2.5, -1.0), SIZE, 0.7, 0.42)
    d = Detection.from_box(box, grav, box_centre=(0.0, 0.05, 0.45))
    back = d.box(grav)
    np.testing.assert_allclose(back.centre, box.centre, atol=1e-12)
    assert back.yaw == pytest.approx(box.yaw) and back.score == box.score
    # The detection's object z axis is up.
    np.testing.assert_allclose(grav @ d.R @ [0, 0, 1], [0, 0, 1], atol=1e-12)
    assert Detection.from_dict(d.to_dict()).box(grav).centre == pytest.approx(box.centre)


def test_bad_input_is_named(tmp_path):
    from isa.scenes.benchmark import load_detections, load_models

    with pytest.raises(FileNotFoundError, match="no.isa"):
        load_models({"chair": tmp_path / "no.isa"})
    (tmp_path / "d.json").write_text("{}")
    with pytest.raises(ValueError, match="d.json"):
        load_detections(tmp_path / "d.json")
    with pytest.raises(TypeError, match="Detection or a Box3D"):
        evaluate([[]], [["chair"]])
    with pytest.raises(InvalidInputError, match="frames"):
        evaluate([[]], [[], []])
    with pytest.raises(InvalidInputError, match="size"):
        Detection("chair", np.eye(3), (0, 0, 1), (0.5, -1, 1), 0.5)
    with pytest.raises(ValueError, match="min_visib"):
        evaluate([[]], [[]], min_visib=2)


# ----------------------------------------------------------------------------------------------
# The command, end to end, on two tiny procedural scenes


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory):
    from isa.detection.training import train_detector
    from isa.forest.model import ForestParams
    from isa.render.dataset import procedural_objects
    from isa.scenes import make_scenes, sources

    tmp = tmp_path_factory.mktemp("bench")
    root = tmp / "rooms"
    make_scenes(root, "test", sources.procedural(["chair"], seed=3, n=2), 2, 1, seed=0, noise=False, progress=False)
    forest, _ = train_detector("chair", procedural_objects("chair", 1, seed=1), views=4, stride=8,
                               use_ground_truth=True, forest_params=ForestParams(n_trees=1, max_depth=8, n_candidates=10))
    model = tmp / "chair.isa"
    forest.save(model)
    return tmp, root, model


def _chairs_in(root) -> int:
    """Chairs in the written scene_gt.json files, counted from the BOP files themselves."""
    import json

    info = json.loads((root / "models" / "models_info.json").read_text())
    chair_ids = {int(k) for k, v in info.items() if v.get("isa_category") == "chair"}
    return sum(g["obj_id"] in chair_ids for p in (root / "test").glob("*/scene_gt.json")
               for gts in json.loads(p.read_text()).values() for g in gts)


@pytest.mark.slow
def test_benchmark_command_end_to_end(tiny_bench):
    import json

    from isa.scenes.__main__ import main
    from isa.scenes.benchmark import load_detections, save_detections, scene_views

    tmp, root, model = tiny_bench
    out = tmp / "out"
    main(["run", "--models", f"chair={model}", "--scenes", str(root), "--split", "test", "--out", str(out),
          "--figures", "1"])
    res = json.loads((out / "results.json").read_text())
    assert res["schema"] == "isa-results/2" and res["command"] == "run"
    sc = res["scenes"]["rooms"]
    assert sc["n_frames"] == 2
    chair = sc["scores"]["per_category"]["chair"]
    assert set(chair) == {"6d", "6d_sym", "box_0.25", "box_0.5"}
    assert chair["6d"]["n_ground_truth"] + chair["6d"]["n_ignored"] == _chairs_in(root) > 0
    text = (out / "report.md").read_text()
    assert "## Scenes: rooms" in text
    for rel in [line.split("](")[1].rstrip(")") for line in text.splitlines() if line.startswith("![")]:
        assert (out / rel).is_file()
    # Scored again from the stored detections: the same numbers.
    main(["evaluate", "--detections", str(out / "detections.json"), "--out", str(tmp / "again"), "--figures", "0"])
    again = json.loads((tmp / "again" / "results.json").read_text())["scenes"]["rooms"]["scores"]
    assert again == sc["scores"]
    # The ground truth itself, as detections, is right under every metric: the reader, the
    # conversions and the scorer agree on the written scenes.
    views = scene_views(root, "test")
    perfect = [[Detection(g.category, g.R, g.t, g.size, 1.0, (g.points.min(0) + g.points.max(0)) / 2) for g in v.gt]
               for v in views]
    stored = load_detections(out / "detections.json")
    stored["rooms"]["detections"] = perfect
    save_detections(tmp / "perfect.json", stored)
    main(["evaluate", "--detections", str(tmp / "perfect.json"), "--out", str(tmp / "perfect"), "--figures", "0"])
    best = json.loads((tmp / "perfect" / "results.json").read_text())["scenes"]["rooms"]["scores"]["per_category"]
    for m in ("6d", "6d_sym", "box_0.25", "box_0.5"):
        assert best["chair"][m]["ap"] == pytest.approx(100.0), m


@pytest.mark.slow
def test_benchmark_command_runs_the_full_detector(tiny_bench):
    """`run --detector full` reads the shape library beside the model and stores exactly what
    `isa.detection.detect` gives on each view (gravity given)."""
    import json

    from isa.detection.multi import detect, load_model
    from isa.detection.shapes import shape_library
    from isa.render.dataset import procedural_objects
    from isa.scenes.__main__ import main
    from isa.scenes.benchmark import load_detections, scene_views

    tmp, root, model = tiny_bench
    full = tmp / "full"
    full.mkdir()
    m = full / "chair.isa"
    m.write_bytes(model.read_bytes())
    shape_library("chair", procedural_objects("chair", 2, seed=1)).save(m.with_suffix(".shapes.isl"))
    out = tmp / "out-full"
    main(["run", "--models", f"chair={m}", "--scenes", str(root), "--split", "test", "--out", str(out),
          "--figures", "0", "--detector", "full"])
    sc = json.loads((out / "results.json").read_text())["scenes"]["rooms"]
    assert "shapes: yes" in sc["models"]["chair"] and "verify" in sc["params"]
    stored = load_detections(out / "detections.json")["rooms"]["detections"]
    assert any(stored)
    cm = load_model(m, category="chair")
    for v, dets in zip(scene_views(root, "test"), stored, strict=True):
        direct = detect(v.depth, v.intrinsics, [cm], gravity=v.gravity).detections
        assert [d.score for d in dets] == pytest.approx([d.score for d in direct], abs=1e-9)
        for a, b in zip(dets, direct):
            np.testing.assert_allclose(a.t, b.t, atol=1e-9)

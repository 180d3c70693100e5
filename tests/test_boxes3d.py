"""3D boxes, exact 3D IoU and average precision against analytic and hand-computed truths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from isa.evaluation.boxes3d import (
    Box3D,
    average_precision,
    box_from_pose,
    clip_convex_polygon,
    evaluate_detections,
    iou_3d,
    iou_matrix,
    nms,
    polygon_area,
    voc_ap,
    yaw_from_rotation,
)


def box(c=(0, 0, 0), s=(1, 1, 1), yaw=0.0, cat="chair", score=1.0):
    return Box3D(cat, c, s, yaw, score)


def rot_z(a):
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])


# ---------------------------------------------------------------------------------------------- boxes


def test_corners_and_footprint_geometry():
    b = box(c=(1, 2, 3), s=(4, 2, 6), yaw=math.pi / 2)
    fp = b.footprint()
    assert polygon_area(fp) == pytest.approx(8.0)  # counter-clockwise -> positive area
    c = b.corners()
    assert c.shape == (8, 3)
    # yaw 90 deg: the 4 m length runs along y.
    np.testing.assert_allclose(c[:, 0].min(), 0.0, atol=1e-12)
    np.testing.assert_allclose(c[:, 0].max(), 2.0, atol=1e-12)
    np.testing.assert_allclose([c[:, 1].min(), c[:, 1].max()], [0.0, 4.0], atol=1e-12)
    np.testing.assert_allclose([c[:, 2].min(), c[:, 2].max()], [0.0, 6.0])
    np.testing.assert_allclose(c[4:, :2], c[:4, :2])  # vertical edges i -- i+4
    np.testing.assert_allclose(b.heading, [0, 1, 0], atol=1e-12)


def test_contains_matches_local_extent():
    b = box(c=(0.5, 0, 0), s=(2, 1, 1), yaw=math.pi / 4)
    d = b.heading[:2]
    inside = np.array([[0.5 + 0.99 * d[0], 0.99 * d[1], 0.0]])
    outside = np.array([[0.5 + 1.01 * d[0], 1.01 * d[1], 0.0], [0.5, 0, 0.51]])
    assert b.contains(inside).all() and not b.contains(outside).any()


def test_box_rejects_bad_values():
    with pytest.raises(ValueError, match="positive"):
        box(s=(1, 0, 1))
    with pytest.raises(ValueError, match="non-finite"):
        box(c=(np.nan, 0, 0))


# ---------------------------------------------------------------------------------------------- IoU


def test_iou_identical_is_one():
    b = box(c=(0.3, -2, 0.5), s=(1.9, 0.7, 1.1), yaw=0.7)
    assert iou_3d(b, b) == pytest.approx(1.0, abs=1e-12)


def test_iou_disjoint_is_zero():
    assert iou_3d(box(), box(c=(1.5, 0, 0))) == 0.0  # apart horizontally
    assert iou_3d(box(), box(c=(0, 0, 1.0))) == 0.0  # stacked, touching
    assert iou_3d(box(), box(c=(0.2, 0.2, 5.0))) == 0.0  # overlapping footprints, apart in z


def test_iou_half_shifted_is_one_third():
    # Overlap 0.5, union 1.5, in each axis separately.
    for shift in [(0.5, 0, 0), (0, 0.5, 0), (0, 0, 0.5)]:
        assert iou_3d(box(), box(c=shift)) == pytest.approx(1 / 3)
    # Shifted along its own rotated length axis.
    b = box(s=(2, 1, 1), yaw=0.9)
    assert iou_3d(b, box(c=1.0 * b.heading, s=(2, 1, 1), yaw=0.9)) == pytest.approx(1 / 3)


def test_iou_square_footprint_rotated_90_is_one():
    assert iou_3d(box(s=(1.3, 1.3, 0.8)), box(s=(1.3, 1.3, 0.8), yaw=math.pi / 2)) == pytest.approx(1.0)
    # A 2x1 box rotated by 180 deg is the same box; by 90 deg it is a cross.
    assert iou_3d(box(s=(2, 1, 1)), box(s=(2, 1, 1), yaw=math.pi)) == pytest.approx(1.0)
    assert iou_3d(box(s=(2, 1, 1)), box(s=(2, 1, 1), yaw=math.pi / 2)) == pytest.approx(1 / 3)


def test_iou_square_rotated_45_is_regular_octagon():
    # Unit square vs itself turned 45 deg about its centre: intersection is a regular octagon of
    # area 2(sqrt2 - 1), so IoU = 2(sqrt2-1) / (2 - 2(sqrt2-1)) = 1/sqrt2.
    assert iou_3d(box(), box(yaw=math.pi / 4)) == pytest.approx(1 / math.sqrt(2))


def test_iou_rotated_case_matches_monte_carlo():
    a = Box3D("bed", (0.2, 1.0, 0.1), (2.0, 1.4, 0.9), 0.35)
    b = Box3D("bed", (0.9, 1.4, 0.3), (1.6, 1.0, 1.2), -0.6)
    rng = np.random.default_rng(0)
    lo = np.minimum(a.corners().min(0), b.corners().min(0))
    hi = np.maximum(a.corners().max(0), b.corners().max(0))
    n = 1_000_000
    p = lo + (hi - lo) * rng.random((n, 3))
    ia, ib = a.contains(p), b.contains(p)
    mc = np.sum(ia & ib) / np.sum(ia | ib)
    se = math.sqrt(mc * (1 - mc) / np.sum(ia | ib))
    exact = iou_3d(a, b)
    assert 0.1 < exact < 0.6
    assert abs(exact - mc) < 4 * se + 1e-4
    assert iou_3d(b, a) == pytest.approx(exact, rel=1e-12)


def test_clip_convex_polygon_triangle_in_square():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    # Right triangle x, y >= 0, x + y <= 3 over the square [0, 2]^2: the square minus the corner
    # triangle (1,2)-(2,1)-(2,2) of area 1/2.
    tri = np.array([[0, 0], [3, 0], [0, 3]], float)
    inter = clip_convex_polygon(tri, square)
    assert polygon_area(inter) == pytest.approx(3.5)
    assert polygon_area(clip_convex_polygon(square, tri)) == pytest.approx(3.5)
    far = square + 10
    assert len(clip_convex_polygon(far, square)) == 0


def test_iou_matrix_shape_and_values():
    m = iou_matrix([box(), box(c=(5, 0, 0))], [box(), box(c=(0.5, 0, 0)), box(c=(9, 9, 9))])
    np.testing.assert_allclose(m, [[1, 1 / 3, 0], [0, 0, 0]], atol=1e-12)


def test_nms_keeps_best_of_overlapping():
    boxes = [box(score=0.5), box(c=(0.1, 0, 0), score=0.9), box(c=(3, 0, 0), score=0.1)]
    assert nms(boxes, 0.25) == [1, 2]


# ---------------------------------------------------------------------------------------------- AP


def test_voc_ap_hand_computed():
    # Ranked TP, FP, TP, FP with 3 ground truths: recall 1/3,1/3,2/3,2/3; precision 1,.5,2/3,.5.
    # Monotone envelope: 1 on (0,1/3], 2/3 on (1/3,2/3], 0 after -> AP = 1/3 + 2/9 = 5/9.
    rec = np.array([1, 1, 2, 2]) / 3
    prec = np.array([1, 1 / 2, 2 / 3, 1 / 2])
    assert voc_ap(rec, prec) == pytest.approx(5 / 9)
    # 11-point: r = 0..0.3 -> 1 (4 points), 0.4..0.6 -> 2/3 (3 points), 0.7..1 -> 0.
    assert voc_ap(rec, prec, "11point") == pytest.approx((4 + 3 * 2 / 3) / 11)
    with pytest.raises(ValueError):
        voc_ap(rec, prec, "bogus")


def test_average_precision_ranked_list_two_frames():
    gt = [
        [box(c=(0, 0, 0)), box(c=(3, 0, 0)), box(c=(0, 0, 0), cat="bed")],
        [box(c=(0, 5, 0))],
    ]
    dets = [
        [
            box(c=(0.05, 0, 0), score=0.9),  # TP (gt 0 of frame 0)
            box(c=(0.1, 0, 0), score=0.8),  # duplicate of gt 0 -> FP
            box(c=(3.4, 0, 0), score=0.5),  # IoU 0.6/1.4 = 0.43 with gt 1 -> TP
            box(c=(0, 0, 0), cat="bed", score=0.95),  # other category: ignored here
        ],
        [
            box(c=(0, 5.8, 0), score=0.7),  # IoU 0.2/1.8 = 0.11 < 0.25 -> FP
            box(c=(9, 9, 0), score=0.6),  # nothing there -> FP
        ],
    ]
    r = average_precision(dets, gt, "chair")
    # Rank: 0.9 TP, 0.8 FP, 0.7 FP, 0.6 FP, 0.5 TP; 3 chairs.
    np.testing.assert_array_equal(r.true_positive, [1, 0, 0, 0, 1])
    np.testing.assert_allclose(r.precision, [1, 1 / 2, 1 / 3, 1 / 4, 2 / 5])
    np.testing.assert_allclose(r.recall, [1 / 3, 1 / 3, 1 / 3, 1 / 3, 2 / 3])
    assert r.n_ground_truth == 3
    # Envelope: 1 up to recall 1/3, 2/5 up to 2/3 -> 1/3 + 2/15.
    assert r.ap == pytest.approx(1 / 3 + (1 / 3) * (2 / 5))
    # A stricter threshold turns the 0.43-IoU hit into a miss.
    assert average_precision(dets, gt, "chair", iou_threshold=0.5).ap == pytest.approx(1 / 3)
    beds = evaluate_detections(dets, gt, ["bed", "toilet"])
    assert beds["bed"].ap == pytest.approx(1.0)
    assert math.isnan(beds["toilet"].ap) and beds["toilet"].n_ground_truth == 0


def test_average_precision_best_match_taken_is_false_positive():
    # VOC / Deep Sliding Shapes rule: a detection is compared with its best-IoU ground truth only;
    # if that one is already matched it is a false positive even if another box overlaps enough.
    gt = [[box(c=(0, 0, 0)), box(c=(0.6, 0, 0))]]
    dets = [[box(c=(0.0, 0, 0), score=0.9), box(c=(0.2, 0, 0), score=0.8)]]
    # Second detection: IoU 0.8/1.2 = 0.667 with gt 0 (taken), 0.6/1.4 = 0.43 with gt 1.
    r = average_precision(dets, gt, "chair")
    np.testing.assert_array_equal(r.true_positive, [1, 0])
    assert r.ap == pytest.approx(0.5)


def test_average_precision_perfect_and_empty():
    gt = [[box(c=(i, 0, 0)) for i in range(0, 6, 2)]]
    assert average_precision([[g.replace(score=0.5) for g in gt[0]]], gt, "chair").ap == pytest.approx(1.0)
    assert average_precision([[]], gt, "chair").ap == 0.0
    with pytest.raises(ValueError, match="frames"):
        average_precision([[], []], gt, "chair")


# ---------------------------------------------------------------------------------------------- pose -> box


def test_box_from_pose_upright_camera():
    # Level camera: upright = axes permutation. Object 2 m ahead, turned 30 deg about gravity.
    P = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    yaw = math.radians(30)
    R = P.T @ rot_z(yaw)  # object (z up) -> camera (y down)
    size = np.array([2.0, 1.0, 0.8])
    ssc_offset = np.array([0.5, 0.0, 0.2])  # SSC sits 0.5 m ahead and 0.2 m above the box centre
    ssc_up = np.array([0.3, 2.0, -0.4])
    t = P.T @ ssc_up
    b = box_from_pose(R, t, size, ssc_offset, P, "bed", score=0.7)
    expected_centre = ssc_up - rot_z(yaw) @ ssc_offset
    np.testing.assert_allclose(b.centre, expected_centre, atol=1e-12)
    assert b.yaw == pytest.approx(yaw)
    np.testing.assert_allclose(b.size, size)
    assert (b.category, b.score) == ("bed", 0.7)


def test_box_from_pose_tilted_camera_and_tilted_pose():
    # Tilted camera: R_gravity undoes it, so the yaw is the object's heading about gravity.
    P = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    tilt = np.array([[1, 0, 0], [0, math.cos(0.2), -math.sin(0.2)], [0, math.sin(0.2), math.cos(0.2)]])
    R_gravity = P @ tilt
    yaw = math.radians(-120)
    small_tilt = np.array([[math.cos(0.05), 0, math.sin(0.05)], [0, 1, 0], [-math.sin(0.05), 0, math.cos(0.05)]])
    R = R_gravity.T @ rot_z(yaw) @ small_tilt
    b = box_from_pose(R, R_gravity.T @ np.array([1.0, 3.0, -0.5]), (1, 1, 1), (0, 0, 0), R_gravity, "chair")
    np.testing.assert_allclose(b.centre, [1.0, 3.0, -0.5], atol=1e-12)
    assert b.yaw == pytest.approx(yaw, abs=1e-9)  # a small pitch does not move the yaw
    assert yaw_from_rotation(rot_z(2.0)) == pytest.approx(2.0)

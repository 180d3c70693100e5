"""Privileged annotations: projection, link angles (wrap-around), node offsets, quaternions and the
vectorised training set against direct per-part loops and analytic geometry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from annotate_reference import loop_annotations
from isa.camera import KINECT_V1, Intrinsics
from isa.privileged.annotate import (
    Frame,
    angle_embedding,
    build_training_set,
    circular_difference,
    link_angles,
    project_skeleton,
    quaternion_to_matrix,
    rotation_quaternion,
)
from isa.skeleton_graph import SkeletonGraph


def _skeleton(seed: int = 0, n: int = 7) -> SkeletonGraph:
    rng = np.random.default_rng(seed)
    links = np.array([[i, i + 1] for i in range(n - 1)] + [[0, n - 1]])
    return SkeletonGraph(rng.uniform(-0.3, 0.3, (n, 3)), links)


def _plane_frame(R, t, skeleton, K=KINECT_V1, ssc=(0.0, 0.0, 0.0)) -> Frame:
    """Depth of a fronto-parallel square of side 0.6 m at the object origin's depth (analytic)."""
    z = float(t[2])
    u = np.arange(K.width)
    v = np.arange(K.height)
    x = (u - K.cx) * z / K.fx - t[0]
    y = (v - K.cy) * z / K.fy - t[1]
    mask = (np.abs(y)[:, None] < 0.3) & (np.abs(x)[None, :] < 0.3)
    depth = np.where(mask, z, 0).astype(np.float32)
    return Frame(depth, mask, np.asarray(R, float), np.asarray(t, float), K, skeleton, np.asarray(ssc, float))


def test_projection_matches_camera_model():
    sk = _skeleton()
    R = Rotation.from_euler("xyz", [20, -30, 50], degrees=True).as_matrix()
    t = np.array([0.1, -0.05, 2.5])
    p = project_skeleton(sk, R, t, KINECT_V1)
    Xc = sk.nodes @ R.T + t
    for i, X in enumerate(Xc):
        assert p[i, 0] == pytest.approx(KINECT_V1.fx * X[0] / X[2] + KINECT_V1.cx)
        assert p[i, 1] == pytest.approx(KINECT_V1.fy * X[1] / X[2] + KINECT_V1.cy)
        assert p[i, 2] == pytest.approx(X[2])
    with pytest.raises(ValueError, match="behind the camera"):
        project_skeleton(sk, R, np.array([0, 0, 0.1]), KINECT_V1)


def test_link_angles_known_directions_and_wrap():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [-1.0, -1e-9], [-1.0, 1e-9]])
    links = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [0, 5]])
    a = link_angles(uv, links)
    # +x: 0; +v (image down): +pi/2; -x: -pi (the [-pi, pi) convention); just either side of -x.
    assert a[0] == 0.0 and a[1] == pytest.approx(np.pi / 2)
    assert a[2] == pytest.approx(-np.pi)
    assert a[3] == pytest.approx(-np.pi, abs=1e-8) and a[4] == pytest.approx(np.pi, abs=1e-8)
    assert np.all((a >= -np.pi) & (a < np.pi))
    # Wrap-around: two links 2e-9 rad apart are far apart as raw numbers but not on the circle.
    assert abs(a[4] - a[3]) > 6.0
    assert abs(circular_difference(a[4], a[3])) < 1e-8
    e = angle_embedding(a[None, 3:5])[0]
    assert np.linalg.norm(e[0:2] - e[2:4]) < 1e-8


def test_training_set_matches_per_part_loop():
    sk = _skeleton(3)
    R = Rotation.from_euler("zyx", [170, 10, -5], degrees=True).as_matrix()
    frames = [
        _plane_frame(R, np.array([0.05, 0.02, 2.2]), sk, ssc=(0.01, -0.02, 0.03)),
        _plane_frame(np.eye(3), np.array([-0.1, 0.0, 3.0]), sk),
    ]
    ts = build_training_set(frames, stride=5, margin=6)
    assert len(ts.images) == 2 and all(im.dtype == np.uint16 and im.flags.c_contiguous for im in ts.images)
    assert ts.parts.dtype == np.int32 and ts.offsets.dtype == np.float32 and ts.node_offsets.dtype == np.float32
    P = 0
    for fi, f in enumerate(frames):
        ref = loop_annotations(f, 5)
        sel = ts.parts[:, 0] == fi
        assert sel.sum() == len(ref)
        u0, v0 = ts.crops[fi]
        got_uv = ts.parts[sel, 1:] + [u0, v0]
        assert got_uv.tolist() == [[u, v] for u, v, *_ in ref]
        # Every part lies on the foreground of its crop.
        assert np.all(ts.images[fi][ts.parts[sel, 2], ts.parts[sel, 1]] > 0)
        np.testing.assert_allclose(ts.offsets[sel], np.array([r[2] for r in ref]), atol=1e-5)
        np.testing.assert_allclose(ts.node_offsets[sel], np.array([r[3] for r in ref]), atol=2e-3, rtol=1e-5)
        np.testing.assert_allclose(ts.link_angles[sel], np.array([r[4] for r in ref]), atol=1e-5)
        q = Rotation.from_matrix(f.R).as_quat()  # scipy: (x, y, z, w)
        q = np.r_[q[3], q[:3]] * (1 if q[3] >= 0 else -1)
        np.testing.assert_allclose(ts.rotations[sel], np.tile(q, (sel.sum(), 1)), atol=1e-6)
        P += len(ref)
    assert len(ts) == P


def test_offsets_point_to_the_ssc_from_the_crop_pixel():
    sk = _skeleton(1)
    K = Intrinsics(500.0, 510.0, 160.0, 120.0, 320, 240)
    frame = _plane_frame(np.eye(3), np.array([0.0, 0.0, 1.5]), sk, K=K, ssc=(0.1, 0.0, -0.2))
    ts = build_training_set([frame], stride=3, margin=4)
    u = ts.parts[:, 1] + ts.crops[0, 0]
    v = ts.parts[:, 2] + ts.crops[0, 1]
    z = ts.images[0][ts.parts[:, 2], ts.parts[:, 1]] / 1000.0
    X = np.stack([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z], 1)
    np.testing.assert_allclose(X + ts.offsets, np.tile([0.1, 0.0, 1.3], (len(X), 1)), atol=1e-5)
    # The crop is the mask's bounding box plus the margin.
    rows, cols = np.flatnonzero(frame.mask.any(1)), np.flatnonzero(frame.mask.any(0))
    assert ts.images[0].shape == (rows[-1] - rows[0] + 1 + 8, cols[-1] - cols[0] + 1 + 8)
    # Node subset and its links.
    ts2 = build_training_set([frame], stride=3, nodes=[0, 1, 2])
    assert ts2.node_offsets.shape[1] == 9 and ts2.link_angles.shape[1] == 2  # links 0-1, 1-2


def test_quaternions_agree_with_scipy_including_half_turns():
    rng = np.random.default_rng(5)
    Rs = Rotation.random(200, random_state=rng).as_matrix()
    half = np.stack([Rotation.from_rotvec(np.pi * a / np.linalg.norm(a)).as_matrix() for a in rng.normal(size=(20, 3))])
    Rs = np.concatenate([Rs, half, np.eye(3)[None], np.diag([1.0, -1, -1])[None]])
    q = rotation_quaternion(Rs)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    ref = Rotation.from_matrix(Rs).as_quat()[:, [3, 0, 1, 2]]
    # Same rotation: q == +-ref (sign ambiguous only when w == 0).
    dots = np.abs((q * ref).sum(1))
    np.testing.assert_allclose(dots, 1, atol=1e-9)
    np.testing.assert_allclose(quaternion_to_matrix(q), Rs, atol=1e-9)


def test_frames_are_read_once_in_order_and_may_be_a_generator():
    sk = _skeleton(3)
    frames = [_plane_frame(np.eye(3), np.array([dx, 0.0, 2.5]), sk) for dx in (-0.1, 0.0, 0.1)]
    pulled = []

    def gen():
        for i, f in enumerate(frames):
            pulled.append(i)
            yield f

    a, b = build_training_set(frames, stride=3), build_training_set(gen(), stride=3)
    assert pulled == [0, 1, 2]
    for k, v in a.arrays().items():
        if k == "images":
            assert all(np.array_equal(x, y) for x, y in zip(v, b.images)) and len(v) == len(b.images)
        else:
            np.testing.assert_array_equal(v, b.arrays()[k])
    np.testing.assert_array_equal(a.crops, b.crops)


def test_errors_name_the_argument():
    sk = _skeleton()
    f = _plane_frame(np.eye(3), np.array([0, 0, 2.0]), sk)
    with pytest.raises(ValueError, match="frames"):
        build_training_set([])
    with pytest.raises(ValueError, match="stride"):
        build_training_set([f], stride=0)
    with pytest.raises(ValueError, match="nodes"):
        build_training_set([f], nodes=[99])
    bad = Frame(f.depth, f.mask[:10], f.R, f.t, f.intrinsics, sk)
    with pytest.raises(ValueError, match=r"frames\[0\].mask"):
        build_training_set([bad])
    other = Frame(f.depth, f.mask, f.R, f.t, f.intrinsics, _skeleton(n=5))
    with pytest.raises(ValueError, match=r"frames\[1\].skeleton"):
        build_training_set([f, other])

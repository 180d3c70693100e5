"""SSC average-distance metric (paper Eq. 14-15) on analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

from isa.evaluation.pose_metrics import (
    average_distance,
    is_correct,
    model_diameter,
    recall,
    recall_curve,
    symmetric_average_distance,
)


def _rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@pytest.fixture
def cloud():
    return np.random.default_rng(0).uniform(-0.4, 0.4, (500, 3))


def test_identity_is_zero(cloud):
    R, t = _rot_z(0.3), np.array([0.1, -0.2, 2.0])
    assert average_distance(cloud, R, t, R, t) == pytest.approx(0.0, abs=1e-12)


def test_pure_translation_is_its_length(cloud):
    R = _rot_z(1.1)
    t = np.array([0.0, 0.0, 2.0])
    d = np.array([0.03, -0.04, 0.12])  # |d| = 0.13
    assert average_distance(cloud, R, t, R, t + d) == pytest.approx(0.13, rel=1e-12)


def test_rotation_about_axis_on_a_circle():
    # Points on a circle of radius r about the rotation axis all move by the chord 2 r sin(theta/2).
    r, theta = 0.35, np.radians(40)
    phi = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    X = np.stack([r * np.cos(phi), r * np.sin(phi), np.full_like(phi, 0.2)], 1)
    om = average_distance(X, np.eye(3), np.zeros(3), _rot_z(theta), np.zeros(3))
    assert om == pytest.approx(2 * r * np.sin(theta / 2), rel=1e-12)


def test_batched_poses_match_single(cloud):
    rng = np.random.default_rng(1)
    Rs = np.stack([_rot_z(a) for a in rng.uniform(-1, 1, 5)])
    ts = rng.normal(size=(5, 3))
    om = average_distance(cloud, np.eye(3), np.zeros(3), Rs, ts)
    assert om.shape == (5,)
    for k in range(5):
        direct = np.linalg.norm(cloud - (cloud @ Rs[k].T + ts[k]), axis=1).mean()
        assert om[k] == pytest.approx(direct, rel=1e-12)


def test_diameter_of_a_box_is_its_diagonal():
    corners = np.array([[x, y, z] for x in (0, 0.4) for y in (0, 0.5) for z in (0, 1.2)])
    inner = np.random.default_rng(2).uniform([0, 0, 0], [0.4, 0.5, 1.2], (300, 3))
    assert model_diameter(np.vstack([inner, corners])) == pytest.approx(np.sqrt(0.4**2 + 0.5**2 + 1.2**2))


def test_model_points_diameter_of_a_mesh_box():
    import trimesh

    from isa.evaluation.pose_metrics import model_points

    box = trimesh.creation.box(extents=[0.4, 0.5, 1.2])
    X = model_points(box, 500, seed=1)
    assert np.all(np.abs(X) <= [0.2 + 1e-9, 0.25 + 1e-9, 0.6 + 1e-9])
    assert model_diameter(X) == pytest.approx(np.sqrt(0.4**2 + 0.5**2 + 1.2**2))  # corners included
    np.testing.assert_array_equal(X, model_points(box, 500, seed=1))
    with pytest.raises(ValueError, match="mesh"):
        model_points(np.zeros((3, 3)))


def test_correct_threshold_and_recall():
    diam = 1.0
    assert is_correct(0.1, diam, 0.1) and not is_correct(0.1000001, diam, 0.1)
    om = np.array([0.01, 0.05, 0.09, 0.2, np.inf])
    assert recall(om, diam, 0.1) == pytest.approx(3 / 5)
    zs, rc = recall_curve(om, diam, [0.0, 0.05, 0.1, 0.3])
    assert rc.tolist() == [0.0, 0.4, 0.6, 0.8]
    zs, rc = recall_curve(om, diam)
    assert np.all(np.diff(rc) >= 0) and rc[-1] == pytest.approx(0.8)


def test_errors_name_the_argument(cloud):
    with pytest.raises(ValueError, match="points"):
        average_distance(np.zeros((3, 2)), np.eye(3), np.zeros(3), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="R_est"):
        average_distance(cloud, np.eye(3), np.zeros(3), np.eye(2), np.zeros(3))
    with pytest.raises(ValueError, match="z"):
        is_correct(0.1, 1.0, -1)
    with pytest.raises(ValueError, match="diameter"):
        is_correct(0.1, 0.0)


# -- ADD-S (symmetries forgiven) -------------------------------------------------------------


def _box_grid(a: float, b: float, c: float, n: int = 9) -> np.ndarray:
    """A regular grid on a box of half sizes a, b, c: invariant under 180 degrees about z."""
    g = [np.linspace(-h, h, n) for h in (a, b, c)]
    return np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)


def test_symmetric_distance_forgives_the_symmetry_the_plain_one_does_not():
    X = _box_grid(0.6, 0.3, 0.2)
    R, t = _rot_z(0.4), np.array([0.2, 0.0, 2.5])
    flipped = R @ _rot_z(np.pi)
    assert symmetric_average_distance(X, R, t, flipped, t) == pytest.approx(0.0, abs=1e-9)
    # Eq. 14 sees every point moved through the origin: 2 * mean horizontal radius.
    assert average_distance(X, R, t, flipped, t) == pytest.approx(2 * np.linalg.norm(X[:, :2], axis=1).mean(), rel=1e-9)


def test_symmetric_distance_of_a_small_shift_on_a_dense_line_is_the_perpendicular_part():
    # Points densely along x on [-1, 1]: a shift of s along x is seen only by the fraction s / 2 of
    # them left uncovered at one end (mean distance s / 2 there): s^2 / 4 in all; one along y
    # costs its length.
    X = np.stack([np.linspace(-1, 1, 20001), np.zeros(20001), np.zeros(20001)], 1)
    eye, t = np.eye(3), np.zeros(3)
    assert symmetric_average_distance(X, eye, t, eye, t + [0.05, 0.0, 0.0]) == pytest.approx(0.05**2 / 4, rel=1e-2)
    assert symmetric_average_distance(X, eye, t, eye, t + [0.0, 0.05, 0.0]) == pytest.approx(0.05, rel=1e-6)


def test_symmetric_distance_never_exceeds_the_plain_one(cloud):
    rng = np.random.default_rng(3)
    for _ in range(5):
        R1, R2 = _rot_z(rng.uniform(-3, 3)), _rot_z(rng.uniform(-3, 3))
        t1, t2 = rng.normal(size=3), rng.normal(size=3)
        assert symmetric_average_distance(cloud, R1, t1, R2, t2) <= average_distance(cloud, R1, t1, R2, t2) + 1e-12


def test_symmetric_distance_refuses_batches(cloud):
    with pytest.raises(ValueError, match="single poses"):
        symmetric_average_distance(cloud, np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)), np.eye(3), np.zeros(3))

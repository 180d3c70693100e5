"""Turn symmetry against analytic truths: prisms whose symmetry groups are known, the closed-form
ceiling of a cylinder, and the renderer drawing the same image at a pose and its canonical one."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isa.camera import KINECT_V1
from isa.data.bop import BopFrame
from isa.evaluation.boxes3d import rot_z
from isa.evaluation.pose_metrics import model_diameter, model_points
from isa.exceptions import InvalidParameterError
from isa.privileged.symmetry import YawSymmetry, canonical_frames, canonical_pose, common_subgroup, find_yaw_symmetry, recall_ceiling
from isa.render.renderer import render_depth
from isa.render.views import look_at

OFFSET = np.array([0.21, -0.13, 0.4])  # the symmetry axis is not the object frame's z axis


def _moved(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_translation(OFFSET)
    return mesh


def _prism(sections: int) -> trimesh.Trimesh:
    return _moved(trimesh.creation.cylinder(radius=0.5, height=0.7, sections=sections))


def _table(extents=(1.6, 0.8)) -> trimesh.Trimesh:
    top = trimesh.creation.box(extents=(*extents, 0.05))
    top.apply_translation([0, 0, 0.7])
    legs = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = trimesh.creation.box(extents=(0.06, 0.06, 0.7))
            leg.apply_translation([sx * (extents[0] / 2 - 0.1), sy * (extents[1] / 2 - 0.1), 0.35])
            legs.append(leg)
    return _moved(trimesh.util.concatenate([top, *legs]))


def _lopsided(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    drawer = trimesh.creation.box(extents=(0.4, 0.3, 0.12))
    drawer.apply_translation(OFFSET + [0.45, 0.0, 0.6])
    return trimesh.util.concatenate([mesh, drawer])


@pytest.mark.parametrize("mesh, order", [
    (_table(), 2), (_table((1.0, 1.0)), 4), (_prism(3), 3), (_prism(6), 6), (_prism(96), 0), (_lopsided(_table()), 1),
])
def test_finds_the_turn_group_and_its_axis(mesh, order):
    sym = find_yaw_symmetry(mesh)
    assert sym.order == order
    if order != 1:
        np.testing.assert_allclose(sym.centre[:2], OFFSET[:2], atol=1e-6)
        assert sym.error < 0.012


def test_refuses_bad_arguments():
    with pytest.raises(InvalidParameterError, match="tolerance"):
        find_yaw_symmetry(_table(), tolerance=0)
    with pytest.raises(InvalidParameterError, match="mesh"):
        find_yaw_symmetry(trimesh.Trimesh())


@pytest.mark.parametrize("mesh, ceiling", [(_table(), 1 / 2), (_table((1.0, 1.0)), 1 / 4), (_prism(6), 1 / 6),
                                           (_lopsided(_table()), 1.0)])
def test_ceiling_of_a_discrete_group_is_one_over_its_order(mesh, ceiling):
    X = model_points(mesh)
    assert recall_ceiling(X, find_yaw_symmetry(mesh), model_diameter(X)) == pytest.approx(ceiling)


def test_ceiling_of_a_cylinder_matches_the_closed_form():
    # A turn by theta moves a point at distance rho from the axis by 2 rho sin(theta / 2), so Eq. 14
    # is 2 sin(theta / 2) mean(rho); the estimate passes for |theta| <= theta*, a share theta* / pi.
    mesh = _prism(96)
    X = model_points(mesh)
    diam = model_diameter(X)
    rho = np.linalg.norm((X - OFFSET)[:, :2], axis=1).mean()
    for z in (0.1, 0.2):
        theta = 2 * np.arcsin(z * diam / (2 * rho))
        assert recall_ceiling(X, find_yaw_symmetry(mesh), diam, z) == pytest.approx(theta / np.pi, abs=2 / 720)


@pytest.mark.parametrize("mesh", [_table(), _prism(3), _prism(96)])
@pytest.mark.parametrize("eye", [(0.9, 2.3, 1.6), (-2.6, 0.4, 1.1), (0.3, -2.8, 1.9)])
def test_canonical_pose_renders_the_same_image_with_the_camera_in_front(mesh, eye):
    sym = find_yaw_symmetry(mesh)
    R, t = look_at(np.asarray(eye) + OFFSET, target=OFFSET + [0, 0, 0.3])
    Rc, tc = canonical_pose(R, t, sym)
    assert np.allclose(Rc @ Rc.T, np.eye(3)) and np.isclose(np.linalg.det(Rc), 1.0)
    depth, mask = render_depth(mesh, R, t, KINECT_V1)
    depth_c, mask_c = render_depth(mesh, Rc, tc, KINECT_V1)
    both = mask & mask_c
    assert both.sum() / (mask | mask_c).sum() > 0.97
    assert np.median(np.abs(depth[both] - depth_c[both])) < 0.003
    # The camera, seen from the object under the canonical pose, is within 180/n degrees of the front (-y).
    d = -Rc.T @ tc - sym.centre
    azimuth = np.degrees(np.arctan2(d[1], d[0]))
    half = 180.0 / sym.order if sym.order else 1e-6
    assert abs(azimuth + 90.0) <= half + 1e-6
    # A view from the front already is canonical.
    Rf, tf = look_at(sym.centre + [0.0, -2.5, 1.2], target=sym.centre)
    Rf2, tf2 = canonical_pose(Rf, tf, sym)
    np.testing.assert_allclose(Rf2, Rf, atol=1e-9)
    np.testing.assert_allclose(tf2, tf, atol=1e-9)


def test_canonical_frames_relabel_only_symmetric_instances():
    table, lopsided = _table(), _lopsided(_table())
    syms = {1: find_yaw_symmetry(table), 2: find_yaw_symmetry(lopsided)}
    R, t = look_at(OFFSET + [0.5, 2.5, 1.5], target=OFFSET)  # from behind: a C2 table turns by 180 degrees
    blank = np.zeros((4, 4), np.float32)
    frames = [BopFrame(0, i, blank, blank > 0, KINECT_V1, R, t, obj_id=i) for i in (1, 2)]
    out = canonical_frames(frames, syms)
    np.testing.assert_allclose(out[0].R, R @ rot_z(np.pi), atol=1e-9)
    assert out[1] is frames[1]
    assert out[0].depth is frames[0].depth


def test_common_subgroup_is_the_turn_group_most_symmetric_instances_share():
    def of(*orders):
        got = common_subgroup({i: YawSymmetry(np.zeros(3), o, 0.0) for i, o in enumerate(orders)})
        return [got[i].order for i in range(len(orders))]

    # A square (C4), rectangles (C2) and a round table (continuous) share the half turn; no symmetry stays none.
    assert of(4, 2, 0, 1) == [2, 2, 2, 1]
    assert of(4, 0) == [4, 4]
    assert of(0, 0) == [0, 0]
    assert of(2, 2, 4, 3, 6) == [2, 2, 2, 1, 2]  # a three-legged table among rectangles stays unlabelled
    assert of(3, 3, 2) == [3, 3, 1]
    # Cut down to C2, a square table's canonical label still renders its own image.
    square = _table((1.0, 1.0))
    sym = common_subgroup({0: find_yaw_symmetry(square), 1: find_yaw_symmetry(_table())})[0]
    assert sym.order == 2
    R, t = look_at(OFFSET + [-2.2, 1.4, 1.5], target=OFFSET)
    Rc, tc = canonical_pose(R, t, sym)
    np.testing.assert_allclose(Rc, R @ rot_z(np.pi), atol=1e-9)

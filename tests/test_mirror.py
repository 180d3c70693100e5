"""Mirror augmentation against an independent truth: the renderer, asked for the mirrored pose
with the mirrored intrinsics, draws the flipped image."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isa.camera import KINECT_V1
from isa.data.bop import BopFrame
from isa.data.procedural import generate
from isa.exceptions import InvalidParameterError
from isa.privileged.mirror import find_mirror, mirrored_frame, with_mirrored
from isa.render.renderer import render_depth
from isa.render.views import look_at


@pytest.fixture(scope="module")
def chair() -> trimesh.Trimesh:
    # Off-centre, so that the symmetry plane does not pass through the object-frame origin.
    mesh = generate("chair", 3).mesh.copy()
    mesh.apply_translation([0.13, -0.07, 0.02])
    return mesh


def _lopsided(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The chair with a box stuck to one side: no longer symmetric."""
    lo, hi = mesh.bounds
    box = trimesh.creation.box(extents=(0.25, 0.25, 0.25))
    box.apply_translation([hi[0] + 0.12, hi[1] - 0.1, lo[2] + 0.5])
    return trimesh.util.concatenate([mesh, box])


def test_finds_the_symmetry_plane_and_refuses_an_asymmetric_mesh(chair):
    m = find_mirror(chair)
    assert m is not None and m.error < 0.006
    # The procedural chair is symmetric left to right (x); the plane is where its box's middle is.
    assert m.axis == 0
    np.testing.assert_allclose(m.b, [2 * chair.bounds[:, 0].mean(), 0, 0], atol=1e-9)
    np.testing.assert_allclose(m.M, np.diag([-1.0, 1, 1]))
    assert find_mirror(_lopsided(chair)) is None
    with pytest.raises(InvalidParameterError, match="tolerance"):
        find_mirror(chair, tolerance=0)


@pytest.mark.parametrize("eye", [(1.6, -2.1, 1.3), (-0.4, 2.7, 2.2)])
def test_mirrored_frame_is_the_render_at_the_mirrored_pose(chair, eye):
    R, t = look_at(eye, target=chair.centroid)
    depth, mask = render_depth(chair, R, t, KINECT_V1)
    frame = BopFrame(0, 0, depth, mask, KINECT_V1, R, t, obj_id=1)
    mir = mirrored_frame(frame, find_mirror(chair))
    assert np.allclose(mir.R @ mir.R.T, np.eye(3)) and np.isclose(np.linalg.det(mir.R), 1.0)
    assert mir.intrinsics.cx == pytest.approx(KINECT_V1.width - 1 - KINECT_V1.cx)  # Kinect's cx is off-centre
    truth, truth_mask = render_depth(chair, mir.R, mir.t, mir.intrinsics)
    both = truth_mask & mir.mask
    iou = both.sum() / (truth_mask | mir.mask).sum()
    assert iou > 0.98
    assert np.median(np.abs(truth[both] - mir.depth[both])) < 0.002
    # And it is not the unflipped image (the view is not itself symmetric).
    assert (mask & truth_mask).sum() / (mask | truth_mask).sum() < 0.9


def test_with_mirrored_adds_copies_only_for_symmetric_objects(chair):
    d, m = np.ones((4, 6), np.float32), np.ones((4, 6), bool)
    d[:, 0] = 2.0
    frames = [BopFrame(0, i, d, m, KINECT_V1, np.eye(3), np.array([0, 0, 2.0]), obj_id=1 + i % 2) for i in range(4)]
    out = with_mirrored(frames, {1: find_mirror(chair), 2: None})
    assert out[:4] == frames and len(out) == 6
    assert [f.im_id for f in out[4:]] == [0, 2]
    assert all(f.depth[0, -1] == 2.0 and f.depth[0, 0] == 1.0 for f in out[4:])

"""Curve-skeleton extraction against independent truths: bar frames whose axes are known
analytically (clean and deliberately messy meshes), and procedural objects with ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isa.data.procedural import generate, skeleton_segments
from isa.privileged.skeleton import extract_skeleton, solid_centre_of_mass, voxelize_solid


def _bar(p0, p1, r=0.02) -> trimesh.Trimesh:
    """Square bar of half-width r between p0 and p1 (axis-aligned bars only)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    lo, hi = np.minimum(p0, p1) - r, np.maximum(p0, p1) + r
    return trimesh.creation.box(bounds=[lo, hi])


# A stool-like frame: 4 legs, a rectangular seat frame (a loop) and two back posts with a top rail.
W, D, H, B = 0.4, 0.36, 0.45, 0.4
_AXES = (
    [((sx * W / 2, sy * D / 2, 0.0), (sx * W / 2, sy * D / 2, H)) for sx in (-1, 1) for sy in (-1, 1)]
    + [((-W / 2, sy * D / 2, H), (W / 2, sy * D / 2, H)) for sy in (-1, 1)]
    + [((sx * W / 2, -D / 2, H), (sx * W / 2, D / 2, H)) for sx in (-1, 1)]
    + [((sx * W / 2, D / 2, H), (sx * W / 2, D / 2, H + B)) for sx in (-1, 1)]
    + [((-W / 2, D / 2, H + B), (W / 2, D / 2, H + B))]
)
_KEY = np.array(
    [(sx * W / 2, sy * D / 2, z) for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, H)]
    + [(sx * W / 2, D / 2, H + B) for sx in (-1, 1)]
)


def _frame_mesh(messy: bool, seed: int = 0) -> trimesh.Trimesh:
    parts = [_bar(a, b) for a, b in _AXES]
    mesh = trimesh.util.concatenate(parts)  # overlapping closed boxes: internal faces everywhere
    if messy:
        rng = np.random.default_rng(seed)
        faces = mesh.faces[rng.random(len(mesh.faces)) > 0.08]  # ~8% of triangles missing (holes)
        faces = np.concatenate([faces, faces[:40]])  # duplicate faces
        verts = np.concatenate([mesh.vertices, mesh.vertices[:30]])  # unused duplicate vertices
        mesh = trimesh.Trimesh(verts, faces, process=False)
    return mesh


def _seg_dist(P, A, B):
    d = B - A
    t = np.clip(np.einsum("nmk,mk->nm", P[:, None] - A[None], d) / np.maximum((d * d).sum(1), 1e-12), 0, 1)
    return np.linalg.norm(P[:, None] - (A[None] + t[..., None] * d[None]), axis=2).min(1)


@pytest.mark.parametrize("messy", [False, True])
def test_bar_frame_skeleton_follows_the_axes(messy):
    mesh = _frame_mesh(messy)
    g = extract_skeleton(mesh)
    diam = float(np.linalg.norm(mesh.extents))
    A = np.array([a for a, _ in _AXES])
    Bx = np.array([b for _, b in _AXES])
    d = _seg_dist(g.nodes, A, Bx) / diam
    assert d.mean() < 0.02, f"mean node distance to the bar axes {d.mean():.3f} of the diameter"
    assert d.max() < 0.06
    # Every bar end / junction has an extracted node near it (the seat loop, feet, back top).
    near = np.linalg.norm(_KEY[:, None] - g.nodes[None], axis=2).min(1) / diam
    assert near.max() < 0.08, f"key points missed: {np.round(near, 3)}"
    # The seat frame and the back frame are loops: a tree would have links == nodes - 1.
    assert len(g.links) >= len(g.nodes) + 1
    kinds = np.array(g.meta["kind"])
    assert (kinds == "end").sum() == 4  # the four feet
    if not messy:  # end branches run on to the surface: the feet end on the bars' bottom faces
        np.testing.assert_allclose(g.nodes[kinds == "end", 2], -0.02, atol=g.meta["pitch"])


def test_thin_bar_is_one_line():
    # scikit-image's thinning erases a 2-voxel-thick bar; extraction must still give its axis.
    bar = trimesh.creation.box(extents=[1.0, 0.02, 0.02])
    g = extract_skeleton(bar)
    ends = g.nodes[np.array(g.meta["kind"]) == "end"]
    assert len(ends) == 2 and len(g.links) == len(g.nodes) - 1
    np.testing.assert_allclose(np.sort(ends[:, 0]), [-0.5, 0.5], atol=0.03)
    assert np.abs(g.nodes[:, 1:]).max() < 0.015


def test_deterministic_given_seed():
    mesh = _frame_mesh(True)
    a, b = extract_skeleton(mesh, seed=3), extract_skeleton(mesh, seed=3)
    assert np.array_equal(a.nodes, b.nodes) and np.array_equal(a.links, b.links)


def test_solid_fill_and_centre_of_mass_of_holed_box():
    # A finely triangulated box with ~5% of its small triangles missing (holes of about a voxel)
    # still fills to its volume, and its solid COM is the box centre.
    box = trimesh.creation.box(extents=[0.4, 0.3, 0.5])
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.02)
    keep = np.random.default_rng(0).random(len(f)) > 0.05
    holed = trimesh.Trimesh(v, f[keep], process=False)
    pitch = 0.01
    solid, origin = voxelize_solid(holed, pitch)
    assert solid.sum() * pitch**3 == pytest.approx(0.4 * 0.3 * 0.5, rel=0.12)
    np.testing.assert_allclose(solid_centre_of_mass(holed), [0, 0, 0], atol=0.01)
    # The free space inside a flat ring of bars is not filled (a seat frame stays a loop).
    ring = trimesh.util.concatenate([_bar(a, b) for a, b in _AXES[4:8]])
    solid, origin = voxelize_solid(ring, pitch)
    centre = np.round((np.array([0.0, 0.0, H]) - origin) / pitch).astype(int)
    assert not solid[tuple(centre)]
    # An L of two boxes: the volume-weighted centroid.
    a = trimesh.creation.box(bounds=[[0, 0, 0], [0.6, 0.2, 0.2]])
    b = trimesh.creation.box(bounds=[[0, 0, 0.2], [0.2, 0.2, 0.8]])
    L = trimesh.util.concatenate([a, b])
    va, vb = 0.6 * 0.2 * 0.2, 0.2 * 0.2 * 0.6
    truth = (va * np.array([0.3, 0.1, 0.1]) + vb * np.array([0.1, 0.1, 0.5])) / (va + vb)
    np.testing.assert_allclose(solid_centre_of_mass(L), truth, atol=0.012)


def _gt_scores(category: str, seeds, keep=None):
    """Per instance: the mean distance from the extracted nodes to the complete true skeleton (the
    template's links and the extra members, ``skeleton.meta["members"]``, as segments) and the
    distance from the worst-served true junction/endpoint of the template to its nearest extracted
    node, both as fractions of the diameter (the bounding-box diagonal)."""
    means, keys = [], []
    for s in seeds:
        o = generate(category, s)
        if keep is not None and not keep(o):
            continue
        gt = o.skeleton
        g = extract_skeleton(o.mesh)
        diam = float(np.linalg.norm(o.mesh.extents))
        means.append(_seg_dist(g.nodes, *skeleton_segments(gt)).mean() / diam)
        deg = np.bincount(gt.links.ravel(), minlength=len(gt.nodes))
        key = gt.nodes[deg != 2]  # true junctions and endpoints
        keys.append(np.linalg.norm(key[:, None] - g.nodes[None], axis=2).min(1).max() / diam)
    return np.array(means), np.array(keys)


# Issue #3's claims against the procedural ground truth (medial template nodes and extra members,
# see isa.data.procedural): (a) the extracted nodes lie within 5% of the diameter of the true skeleton
# on average, (b) every true junction/endpoint of the template has an extracted node within 10%.
# Numbers in the comments (python benches/bench_skeleton.py): seeds 0-11 (the tests run 0-5) and
# held-out seeds 50-57; mean (a) / instances meeting (b) / worst key point.


# Measured, per category:
# - chair: 1.7%, 12/12, 5.1%; held-out 1.6%, 8/8, 3.6%.
# - table: 3.6%, 12/12, 3.5% (pedestal tables, whose template "legs" run from the top's corners to
#   the spoke tips, meet (a) once their column and spokes count); held-out 3.1%, 8/8, 3.9%.
# - bed: 4.55% (template links alone 7.0%), 12/12, worst 8.5%; held-out 5.0% (at the claim, no
#   margin), 8/8, 7.0% (seeds 0-5: 4.6%, worst 8.5%). (b) since hull-vertex tips made the corners of
#   solid platform bases skeleton ends (before: 9/12, worst 12.4%); (a) since the coverage paths
#   follow TEASAR's centred metric through the mattress-on-base slab (before: 5.1%, held-out 5.6%).
#   What is left of (a) is mostly coverage paths to the middle of the slab's sides and ends, which
#   the true skeleton (spine and corner bisectors) does not reach.
# - toilet: 4.1%, 12/12, worst 7.5%; held-out 4.4%, 8/8, 8.9% (seeds 0-5: 3.9%, 7.5%). (b) since
#   mirror-image end branches at the rear body's two bottom-back corners fold into one at the
#   middle of that edge, where its medial skeleton ends (before: 9/12, worst 13.0%; held-out 5/8,
#   12.4%), and end branches run on to the surface. The tightest key points are now rim points.
@pytest.mark.parametrize("category", ["chair", "table", "bed", "toilet"])
def test_procedural_objects_meet_both_claims(category):
    means, keys = _gt_scores(category, range(6))
    assert means.mean() < 0.05, means
    assert keys.max() < 0.10, keys


def test_block_corners_fold_to_the_middle_of_their_edge():
    # A skirted toilet's rear body is a near-cubic block: thinning and coverage reach its two
    # bottom-back corners; the two mirror-image ends fold into one at the middle of that edge, the
    # true skeleton's floor_back (before: 13% of the diameter from it, the nearest node mid-branch).
    o = generate("toilet", 9)
    g = extract_skeleton(o.mesh)
    ends = g.nodes[np.array(g.meta["kind"]) == "end"]
    floor_back = o.skeleton.nodes[o.skeleton.names.index("floor_back")]
    assert np.linalg.norm(ends - floor_back, axis=1).min() < 2 * g.meta["pitch"]


def test_members_are_ground_truth_not_template():
    # The extra members are segments inside the solid, in the object frame, and move with the graph.
    o = generate("table", 4)  # a pedestal table: column and spokes
    m = np.asarray(o.skeleton.meta["members"])
    assert m.ndim == 3 and m.shape[1:] == (2, 3)
    A, B = skeleton_segments(o.skeleton)
    assert len(A) == len(o.skeleton.links) + len(m)
    moved = o.skeleton.transformed(np.eye(3), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(np.asarray(moved.meta["members"]), m + [1.0, 2.0, 3.0])
    assert np.abs(m).max() <= np.abs(o.mesh.bounds).max() + 1e-9


def test_errors_name_the_argument():
    mesh = _frame_mesh(False)
    with pytest.raises(ValueError, match="resolution"):
        extract_skeleton(mesh, resolution=4)
    with pytest.raises(ValueError, match="spacing"):
        extract_skeleton(mesh, spacing=0)
    with pytest.raises(TypeError, match="mesh"):
        extract_skeleton("chair.off")
    with pytest.raises(ValueError, match="pitch"):
        voxelize_solid(mesh, 0.0)

"""Training views in context (isa.scenes.context): the instance's mask is where it is seen, the
pose puts its mesh on those pixels, the room around it stays in the image (floor and walls
removed when asked), and the training set keeps the room around the mask but takes parts on
the mask only."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from isa.data import bop
    from isa.render.dataset import procedural_objects
    from isa.scenes.context import ContextParams, render_context_dataset

    obj = procedural_objects("chair", 1, seed=3)
    out = {}
    for planes in (True, False):
        root = tmp_path_factory.mktemp(f"context-{planes}")
        params = ContextParams(noise=None, remove_planes=planes, pool=1)
        s = render_context_dataset(root, obj, "chair", 2, seed=5, params=params, progress=False)
        assert s.rendered == 2
        again = render_context_dataset(root, obj, "chair", 2, seed=5, params=params, progress=False)
        assert (again.rendered, again.skipped) == (0, 2)  # resumed: nothing drawn twice
        out[planes] = list(bop.FrameSequence(root, "train"))
    return obj[0], out


def _object_points(f):
    """The frame's valid pixels in the object frame, and which of them are on the mask."""
    K = f.intrinsics
    v, u = np.nonzero(f.depth > 0)
    z = f.depth[v, u]
    X = np.stack([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z], 1)
    return (X - f.t) @ f.R, f.mask[v, u]


def test_mask_lies_on_the_posed_mesh(rendered):
    obj, frames = rendered
    surface = trimesh.sample.sample_surface_even(obj.mesh, 40000, seed=0)[0]  # ~3 mm apart on a chair
    for f in frames[True]:
        P, on = _object_points(f)
        assert on.sum() > 300
        dist, _ = cKDTree(surface).query(P[on])
        assert np.median(dist) < 0.005 and np.percentile(dist, 95) < 0.02


def test_room_around_the_object_and_floor_removed(rendered):
    obj, frames = rendered
    floor_z = obj.mesh.bounds[0, 2]  # the object stands on the floor
    for f_clean, f_raw in zip(frames[True], frames[False], strict=True):
        np.testing.assert_allclose(f_clean.R, f_raw.R)  # the same draws with and without removal
        P, on = _object_points(f_raw)
        on_floor = np.abs(P[:, 2] - floor_z) < 0.02
        assert (~on).sum() > on.sum() and on_floor.mean() > 0.1  # the room is there, floor included
        P, on = _object_points(f_clean)
        assert (~on).sum() > 0  # something beside the object stays (walls, clutter or neighbours)
        assert (np.abs(P[:, 2] - floor_z) < 0.02)[~on].mean() < 0.02


def test_training_set_keeps_the_room_parts_on_the_mask(rendered):
    from isa.forest.training import training_set

    obj, frames = rendered
    fs = frames[True]
    skeletons = {obj.obj_id: obj.skeleton}
    ctx = training_set(fs, skeletons, stride=4, progress=False, context=True)
    alone = training_set(fs, skeletons, stride=4, progress=False)
    assert len(ctx) == len(alone)  # the same parts: the mask's pixels on the grid
    np.testing.assert_array_equal(ctx.parts[:, 1:] + ctx.crops[ctx.parts[:, 0]],
                                  alone.parts[:, 1:] + alone.crops[alone.parts[:, 0]])
    for i, f in enumerate(fs):
        assert ctx.images[i].shape == f.depth.shape
        assert np.count_nonzero(ctx.images[i]) == np.count_nonzero(f.depth > 0)
        assert np.count_nonzero(alone.images[i]) == np.count_nonzero(f.mask & (f.depth > 0))


def test_train_category_in_context_learns_from_room_views(tmp_path):
    """``train_category(context=True)``: the forest's images are whole room views and the model
    says so; the one-class model's metadata has no such key (its bytes are the paper protocol's)."""
    from isa.forest.build import train_category
    from isa.forest.model import Forest

    kw = dict(procedural=1, views=2, stride=8, trees=1, depth=6, candidates=10, progress=False)
    ctx = Forest.load(train_category(None, "chair", tmp_path / "ctx.isa", context=True, cache=tmp_path / "c", **kw))
    alone = Forest.load(train_category(None, "chair", tmp_path / "alone.isa", cache=tmp_path / "c", **kw))
    t_ctx, t_alone = ctx.metadata["training"], alone.metadata["training"]
    assert t_ctx["context"] is True and "context" not in t_alone
    assert t_ctx["images"] == t_alone["images"] == 2
    assert (tmp_path / "c" / "renders").is_dir() and any(p.name.startswith("chair-context-")
                                                         for p in (tmp_path / "c" / "renders").iterdir())

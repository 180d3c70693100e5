"""Training views in context: each training instance standing in a room of the scene benchmark
(floor, walls, clutter, instances of the other categories beside it), seen by the benchmark's
hand-held cameras with the Kinect noise on, then the floor and walls removed as
:func:`isa.detection.multi.detect` removes them before voting. The object's visible pixels are
its mask (the positives); the rest of the image stays, so the probes that leave the object see
what they see in a room (:func:`isa.privileged.annotate.build_training_set` with ``context``).

Written as a BOP training split (one scene per instance, like :func:`isa.render.dataset.render_dataset`),
so the training path reads it unchanged; resumable and atomic in the same way. Frame ``im_id``
of instance ``obj_id`` is drawn from ``(seed, obj_id, im_id)`` alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from isa.categories import CATEGORIES
from isa.data import bop
from isa.exceptions import DataError
from isa.render.dataset import ObjectSpec, RenderSummary, _write_models, procedural_objects
from isa.render.noise import KinectNoise, apply_kinect_noise
from isa.scenes.cameras import CameraRig, sample_camera
from isa.scenes.rooms import RoomParams, make_room
from isa.scenes.writer import DELTA_MM, check_settings

__all__ = ["ContextParams", "render_context_dataset", "visible_mask"]


@dataclass(frozen=True)
class ContextParams:
    """``neighbours``: how many instances of the other categories (procedural, ``pool`` per
    category, generated from ``seed``) stand beside the training instance (inclusive range);
    ``min_visible``: a view is drawn again until this share of the instance is visible (at most
    ``attempts`` rooms); ``noise`` the sensor model (None: clean depth); ``remove_planes``: set
    the found floor and walls to missing, as detection does before voting."""

    neighbours: tuple[int, int] = (0, 3)
    pool: int = 4
    min_visible: float = 0.5
    attempts: int = 20
    noise: KinectNoise | None = KinectNoise()
    remove_planes: bool = True
    room: RoomParams = RoomParams()
    rig: CameraRig = CameraRig()


class _Pool:
    """Procedural instances of the categories other than the trained one (a
    :class:`isa.scenes.sources.MeshSource` look-alike for :func:`isa.scenes.rooms.make_room`)."""

    def __init__(self, category: str, n: int, seed: int) -> None:
        self.categories = tuple(c for c in CATEGORIES if c != category)
        self._objs = {c: procedural_objects(c, n, seed=seed + 5000 + i) for i, c in enumerate(self.categories)}

    def count(self, category: str) -> int:
        return len(self._objs[category])

    def instance(self, category: str, index: int) -> ObjectSpec:
        return self._objs[category][index]


def visible_mask(scene: np.ndarray, alone: np.ndarray) -> np.ndarray:
    """Pixels where the instance rendered alone is what the scene shows (bop_toolkit's rule:
    within :data:`isa.scenes.writer.DELTA_MM`)."""
    return (alone > 0) & (scene > 0) & (np.abs(scene - alone) < DELTA_MM / 1000.0)


def _view(obj: ObjectSpec, pool: _Pool, rng: np.random.Generator, renderer, p: ContextParams):
    """One view of ``obj`` in a fresh room: (clean scene depth, visible mask, camera, pose in the
    camera), or None when no view with enough of it visible was drawn."""
    for _ in range(p.attempts):
        room = make_room(rng, pool, p.neighbours, p.room, include=[obj])
        if not room.instances or room.instances[0].obj is not obj:
            continue  # no place for it in this room
        inst = room.instances[0]
        try:
            cam = sample_camera(rng, inst.centre[None], room.is_free, p.rig)
        except DataError:
            continue
        scene, _ = renderer.render(room.scene_mesh(), cam.R, cam.t)
        alone, _ = renderer.render(inst.world_mesh, cam.R, cam.t)
        vis = visible_mask(scene, alone)
        if (alone > 0).sum() == 0 or vis.sum() < p.min_visible * (alone > 0).sum():
            continue
        return scene, vis, cam, cam.R @ inst.R, cam.R @ inst.t + cam.t
    return None


def render_context_dataset(out_root: str | Path, objects: Sequence[ObjectSpec], category: str, n_views: int,
                           seed: int = 0, params: ContextParams = ContextParams(), split: str = "train",
                           progress: bool = True) -> RenderSummary:
    """``n_views`` views in context of every object into ``<out_root>/<split>/<obj_id>/`` (BOP):
    the depth (noisy, floor and walls set to missing) and the instance's visible pixels as its
    mask; ``models/`` as :func:`isa.render.dataset.render_dataset` writes it. ``DataError`` when
    an instance cannot be placed with ``params.min_visible`` of it in view."""
    import time

    from isa.detection.planes import PlaneParams, remove_planes
    from isa.render.renderer import DepthRenderer

    t0 = time.perf_counter()
    out_root = Path(out_root)
    if not objects:
        raise DataError("render_context_dataset: no objects to render")
    K = params.rig.intrinsics
    (out_root / split).mkdir(parents=True, exist_ok=True)
    check_settings(out_root / split / "isa_render.json",
                   {"context": asdict(params), "category": category, "views": n_views, "seed": seed})
    _write_models(out_root, objects)
    pool = _Pool(category, params.pool, seed)
    summary = RenderSummary(scenes=[o.obj_id for o in objects])
    with DepthRenderer(K, znear=0.05) as renderer, \
            tqdm(total=len(objects) * n_views, desc=f"context {category}", unit="frame", disable=not progress) as bar:
        for o in objects:
            with bop.SceneWriter(out_root, split, o.obj_id) as writer:
                for im_id in range(n_views):
                    bar.update(1)
                    if writer.has_frame(im_id):
                        summary.skipped += 1
                        continue
                    got = _view(o, pool, np.random.default_rng([seed, o.obj_id, im_id]), renderer, params)
                    if got is None:
                        raise DataError(f"{o.source}: no room view shows {params.min_visible:.0%} of it "
                                        f"in {params.attempts} tries")
                    scene, vis, cam, R, t = got
                    depth = scene
                    if params.noise is not None:
                        depth = apply_kinect_noise(scene, K, [seed, o.obj_id, im_id, 1], params.noise)
                    if params.remove_planes:
                        depth = remove_planes(depth, K, cam.gravity, PlaneParams()).depth
                    writer.write_frame(im_id, depth, vis & (depth > 0), K, R, t, o.obj_id)
                    summary.rendered += 1
    summary.seconds = time.perf_counter() - t0
    return summary

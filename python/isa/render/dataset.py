"""Render datasets of instances x views into the BOP scenewise format (progress bar, resumable).

One BOP scene per object instance (scene id = object id), one image per view. Rendering again
into the same folder skips every frame already committed, so an interrupted run resumes where it
stopped; files are written atomically (see :mod:`isa.data.bop`), so no half-written frame is ever left.

Command line (e.g. the paper's chair training set)::

    python -m isa dataset --modelnet ../shared/data/modelnet10 --category chair --out data/chair
    python -m isa dataset --procedural 10 --category table --out data/table
    python -m isa dataset --modelnet ../shared/data/modelnet10 --category chair --split test --views 10 --out data/chair
"""

from __future__ import annotations

import argparse
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import trimesh
from tqdm import tqdm

from isa import atomic
from isa.camera import KINECT_V1, Intrinsics
from isa.categories import PAPER_VIEWS, check_category
from isa.data import bop
from isa.data.meshes import prepare_mesh
from isa.data.modelnet import list_instances, paper_instances, validation_instances
from isa.data.procedural import generate
from isa.exceptions import DataError, InvalidValueError
from isa.render.noise import KinectNoise, apply_kinect_noise
from isa.render.views import Views, sample_test_views, training_views
from isa.skeleton_graph import SkeletonGraph

__all__ = [
    "ObjectSpec", "RenderSummary", "modelnet_objects", "procedural_objects", "hull_points", "default_views", "default_test_views",
    "render_dataset",
]


@dataclass
class ObjectSpec:
    """An instance to render: BOP ``obj_id``, category, mesh in the object frame (metres), where it
    came from, the scale applied to the source units, and (procedural objects) the true skeleton."""

    obj_id: int
    category: str
    mesh: trimesh.Trimesh
    source: str
    scale: float = 1.0
    skeleton: SkeletonGraph | None = None


@dataclass
class RenderSummary:
    """What :func:`render_dataset` did: frames rendered now, frames found already written, seconds."""

    rendered: int = 0
    skipped: int = 0
    seconds: float = 0.0
    scenes: list[int] = field(default_factory=list)


def modelnet_objects(
    root: str | Path, category: str, n: int | None = None, split: str = "train", seed: int = 0, first_obj_id: int = 1,
    progress: bool = True, skip: int = 0,
) -> list[ObjectSpec]:
    """ModelNet10 instances as :class:`ObjectSpec`, rescaled to real size (seeded per instance).

    For ``split="train"`` the first ``n`` instances in name order (``n=None``: the paper's count);
    for ``"test"`` the first ``n`` (``None``: all); for ``"validation"`` the last ``n`` of the train
    split (``None``: :data:`isa.data.modelnet.VALIDATION_INSTANCES`), held out for tuning; ``skip``
    (validation only) leaves the last ``skip`` out first.
    """
    if skip and split != "validation":
        raise DataError(f"modelnet_objects: skip={skip} applies to split='validation' only, not {split!r}")
    if split == "validation":
        insts = validation_instances(root, category, n, skip=skip)
    elif split == "train":
        insts = paper_instances(root, category, n)
    else:
        insts = list_instances(root, category, split)[: n or None]
    out = []
    for i, inst in enumerate(tqdm(insts, desc=f"load {category}/{split}", leave=False, disable=not progress or len(insts) < 8)):
        mesh, s = prepare_mesh(inst.path, category, seed=[seed, i])
        out.append(ObjectSpec(first_obj_id + i, category, mesh, str(inst.path), s))
    return out


def procedural_objects(category: str, n: int, seed: int = 0, first_obj_id: int = 1) -> list[ObjectSpec]:
    """``n`` procedural instances (``isa.data.procedural.generate(category, (seed, i))``) as :class:`ObjectSpec`."""
    out = []
    for i in range(n):
        o = generate(category, (seed, i))
        out.append(ObjectSpec(first_obj_id + i, category, o.mesh, f"procedural:{category}:{seed}:{i}", 1.0, o.skeleton))
    return out


def hull_points(mesh: trimesh.Trimesh) -> np.ndarray:
    """Convex-hull vertices of ``mesh`` (all vertices when it has no 3D hull): what must stay in view."""
    try:
        return np.asarray(mesh.convex_hull.vertices)
    except Exception:
        return np.asarray(mesh.vertices)


def default_views(obj: ObjectSpec, n_views: int = PAPER_VIEWS, seed: int = 0, intrinsics: Intrinsics = KINECT_V1) -> Views:
    """The training views of one object: ``training_views(n_views)`` seeded by (seed, obj_id),
    1.5-4 m away but moved back where needed so that the whole object is in the image."""
    return training_views(n_views, seed=[seed, obj.obj_id], fit_points=hull_points(obj.mesh), intrinsics=intrinsics)


def default_test_views(obj: ObjectSpec, n_views: int, seed: int = 0, intrinsics: Intrinsics = KINECT_V1) -> Views:
    """``n_views`` random test views of one object, each >= 3 deg away from every one of its
    :func:`default_views` (same ``seed``), fitted to keep the object in the image."""
    train = default_views(obj, PAPER_VIEWS, seed, intrinsics)
    return sample_test_views(n_views, seed=[seed, obj.obj_id, 1], exclude=train,
                             fit_points=hull_points(obj.mesh), intrinsics=intrinsics)


def _settings(intrinsics: Intrinsics, depth_scale: float, noise: KinectNoise | None, views_id: str) -> dict:
    return {"intrinsics": asdict(intrinsics), "depth_scale": depth_scale,
            "noise": asdict(noise) if noise is not None else None, "views": views_id}


def check_settings(path: Path, settings: dict) -> None:
    """Refuse to resume into a folder rendered with other settings (frames would be mixed)."""
    if path.is_file():
        old = bop.read_json(path)
        if old != settings:
            raise DataError(f"{path} was rendered with other settings ({old}); use a new output folder or delete it")
    else:
        bop.write_json(path, settings)


def _write_models(root: Path, objects: Sequence[ObjectSpec]) -> None:
    info_path = root / "models" / "models_info.json"
    isa_path = root / "models" / "models_isa.json"
    atomic.clean_stale_in(root / "models")  # a killed run's half-written files
    infos = bop.read_models_info(root) if info_path.is_file() else {}
    extras = {int(k): v for k, v in bop.read_json(isa_path).items()} if isa_path.is_file() else {}
    for o in objects:
        if o.obj_id in infos and bop.model_path(root, o.obj_id).is_file():
            continue
        bop.write_model(root, o.obj_id, o.mesh)
        infos[o.obj_id] = bop.model_info(o.mesh)
        extras[o.obj_id] = {"category": o.category, "source": o.source, "scale": o.scale,
                            "skeleton": o.skeleton.to_dict() if o.skeleton is not None else None}
    bop.write_models_info(root, infos)
    bop.write_json(isa_path, {str(k): extras[k] for k in sorted(extras)})


def render_dataset(
    out_root: str | Path,
    objects: Sequence[ObjectSpec],
    split: str = "train",
    views: Views | Callable[[ObjectSpec], Views] | None = None,
    n_views: int = PAPER_VIEWS,
    view_seed: int = 0,
    intrinsics: Intrinsics = KINECT_V1,
    noise: KinectNoise | None = None,
    noise_seed: int = 0,
    depth_scale: float = 1.0,
    progress: bool = True,
    renderer=None,
    io_threads: int = 2,
) -> RenderSummary:
    """Render every object from every view into ``<out_root>/<split>/<obj_id>/`` (BOP) and write
    ``<out_root>/models/``.

    ``views``: one :class:`~isa.render.views.Views` for all objects, a function of the object, or None for
    :func:`default_views` (``n_views`` per object, seeded by ``view_seed``). ``noise``: optional
    :class:`~isa.render.noise.KinectNoise` (off by default), seeded per frame from ``noise_seed``. Frames
    already written are skipped; resuming with other settings raises ``DataError``. PNG encoding
    runs on ``io_threads`` threads while the next frame renders. Pass a ``renderer``
    (:class:`~isa.render.renderer.DepthRenderer` with the same intrinsics) to reuse its GL context.
    """
    t0 = time.perf_counter()
    out_root = Path(out_root)
    _check_objects(objects)
    ids = [o.obj_id for o in objects]
    if renderer is not None and renderer.intrinsics != intrinsics:
        raise InvalidValueError("render_dataset: the renderer's intrinsics differ from `intrinsics`")
    views_id = "given" if isinstance(views, Views) else ("callable" if callable(views) else f"default-fit:{n_views}:{view_seed}")
    (out_root / split).mkdir(parents=True, exist_ok=True)
    check_settings(out_root / split / "isa_render.json", _settings(intrinsics, depth_scale, noise, views_id))
    _write_models(out_root, objects)

    per_obj = [_views_of(o, views, n_views, view_seed, intrinsics) for o in objects]
    summary = RenderSummary(scenes=ids)
    total = sum(len(v) for v in per_obj)
    own = renderer is None
    if own:
        from isa.render.renderer import DepthRenderer

        renderer = DepthRenderer(intrinsics)
    pool = ThreadPoolExecutor(max(1, io_threads))
    try:
        with tqdm(total=total, desc=f"render {split}", unit="frame", disable=not progress) as bar:
            for o, v in zip(objects, per_obj):
                _render_scene(out_root, split, o, v, renderer, noise, noise_seed, intrinsics, depth_scale, pool,
                              io_threads, summary, bar.update)
    finally:
        pool.shutdown(wait=True)
        if own:
            renderer.close()
    summary.seconds = time.perf_counter() - t0
    return summary


def _views_of(o: ObjectSpec, views, n_views: int, view_seed: int, intrinsics: Intrinsics) -> Views:
    return views if isinstance(views, Views) else (views(o) if callable(views) else default_views(o, n_views, view_seed, intrinsics))


def _render_scene(out_root: Path, split: str, o: ObjectSpec, v: Views, renderer, noise, noise_seed: int,
                  intrinsics: Intrinsics, depth_scale: float, pool: ThreadPoolExecutor, io_threads: int,
                  summary: RenderSummary, tick: Callable[[int], object]) -> None:
    """Renders object ``o``'s views ``v`` into its scene folder (frames already there skipped)."""
    with bop.SceneWriter(out_root, split, o.obj_id, depth_scale) as writer:
        pending: deque = deque()
        for im_id in range(len(v)):
            if writer.has_frame(im_id):
                summary.skipped += 1
                tick(1)
                continue
            R, t = v[im_id]
            depth, mask = renderer.render(o.mesh, R, t)
            if noise is not None:
                depth = apply_kinect_noise(depth, intrinsics, [noise_seed, o.obj_id, im_id], noise)
            pending.append(pool.submit(writer.write_frame, im_id, depth, mask, intrinsics, R, t, o.obj_id))
            # Bound the frames in flight (memory) and surface write errors early.
            while len(pending) > 2 * max(1, io_threads):
                pending.popleft().result()
                tick(1)
            summary.rendered += 1
        while pending:
            pending.popleft().result()
            tick(1)


def render_instance(out_root: str | Path, obj: ObjectSpec, split: str = "train", n_views: int = PAPER_VIEWS,
                    view_seed: int = 0, intrinsics: Intrinsics = KINECT_V1, noise: KinectNoise | None = None,
                    noise_seed: int = 0, depth_scale: float = 1.0, io_threads: int = 2) -> RenderSummary:
    """Renders one object's :func:`default_views` into ``<out_root>/<split>/<obj_id>/``, exactly
    as :func:`render_dataset` does (frames already written are skipped), in this process's GL
    context: one task of a cluster render (:func:`isa.cluster.render_dataset`, which writes the
    settings and ``models/`` first)."""
    from isa.render.renderer import DepthRenderer

    summary = RenderSummary(scenes=[obj.obj_id])
    v = default_views(obj, n_views, view_seed, intrinsics)
    renderer = DepthRenderer(intrinsics)
    pool = ThreadPoolExecutor(max(1, io_threads))
    try:
        _render_scene(Path(out_root), split, obj, v, renderer, noise, noise_seed, intrinsics, depth_scale, pool,
                      io_threads, summary, lambda _: None)
    finally:
        pool.shutdown(wait=True)
        renderer.close()
    return summary


def prepare_dataset(out_root: str | Path, objects: Sequence[ObjectSpec], split: str = "train",
                    n_views: int = PAPER_VIEWS, view_seed: int = 0, intrinsics: Intrinsics = KINECT_V1,
                    noise: KinectNoise | None = None, depth_scale: float = 1.0) -> None:
    """What :func:`render_dataset` writes before any frame (settings check, ``models/``), for
    renders whose instances run as separate tasks (:func:`render_instance`)."""
    _check_objects(objects)
    out_root = Path(out_root)
    (out_root / split).mkdir(parents=True, exist_ok=True)
    check_settings(out_root / split / "isa_render.json",
                   _settings(intrinsics, depth_scale, noise, f"default-fit:{n_views}:{view_seed}"))
    _write_models(out_root, objects)


def _check_objects(objects: Sequence[ObjectSpec]) -> None:
    if not objects:
        raise DataError("render_dataset: no objects to render")
    ids = [o.obj_id for o in objects]
    if len(set(ids)) != len(ids):
        raise DataError(f"render_dataset: duplicate obj_id in {ids}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m isa dataset", description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--modelnet", type=Path, help="ModelNet10 root (the paper's protocol instances)")
    src.add_argument("--procedural", type=int, metavar="N", help="render N procedural instances")
    ap.add_argument("--category", required=True)
    ap.add_argument("--out", type=Path, required=True, help="BOP dataset root to write")
    ap.add_argument("--instances", type=int, default=None, help="ModelNet: first N train instances (default: paper)")
    ap.add_argument("--split", choices=["train", "test"], default="train",
                    help="train: ModelNet train instances, protocol views; test: test instances, random views")
    ap.add_argument("--views", type=int, default=PAPER_VIEWS, help="views per instance")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", action="store_true", help="add Kinect-like noise")
    a = ap.parse_args(argv)
    try:
        check_category(a.category)
        if a.modelnet is not None:
            objs = modelnet_objects(a.modelnet, a.category, a.instances, split=a.split, seed=a.seed)
        else:  # test instances are other seeds than the training ones
            objs = procedural_objects(a.category, a.procedural, a.seed + (1000 if a.split == "test" else 0))
        views = (lambda o: default_test_views(o, a.views, a.seed)) if a.split == "test" else None
        s = render_dataset(a.out, objs, split=a.split, views=views, n_views=a.views, view_seed=a.seed,
                           noise=KinectNoise() if a.noise else None)
    except DataError as exc:
        ap.exit(2, f"error: {exc}\n")
    print(f"{s.rendered} frames rendered, {s.skipped} already there, {s.seconds:.1f} s -> {a.out}")


if __name__ == "__main__":
    main()

"""From meshes to a model file in one call: :func:`train_category` (``python -m isa train``).

It composes the existing stages, nothing new in between: meshes loaded and sized
(:mod:`isa.data.meshes`), skeletons matched to a template and the origin chosen
(:func:`isa.pipeline.prepare_category`), views rendered to BOP (:func:`isa.render.dataset.render_dataset`),
optional mirrored / canonical views, annotated parts and the size-aware forest
(:mod:`isa.forest.training`). :mod:`isa.experiment` trains through the same helpers
(:func:`procedural_training`, :func:`augmented_frames`, :func:`model_metadata`), so the same inputs
and seed give the same model bytes on either path.

Sources: files, folders and globs of meshes trimesh reads (OFF, OBJ, PLY, STL, GLB), a ModelNet10
root (its training instances of the category, the paper's protocol count unless ``instances``),
or ``procedural=N`` generated instances. Meshes must be upright with their front towards -y and
z up, as ModelNet10's are, or y up and front +z (glTF's convention: ``up="y"``). Any category
name: the paper's four are sized by :data:`isa.categories.SIZES` and use the procedural skeleton
template; any other needs ``height`` (metres) and gets a template built from its own instances'
extracted skeletons (:func:`isa.privileged.matching.template_from_instances`) and the centre of
mass as origin.

``cache``: a folder holding extracted skeletons (by mesh content), the category template and the
rendered views (by instances + views + seed); a rerun with it skips everything already there.
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh
from tqdm.auto import tqdm

from isa.categories import CATEGORIES, CENTRE, PAPER_VIEWS
from isa.data import bop
from isa.data.meshes import MESH_EXTENSIONS, load_mesh, prepare_mesh, to_object_frame
from isa.exceptions import DataError, IsaError
from isa.forest.model import QUALITIES, ForestParams
from isa.privileged.skeleton import extract_skeleton
from isa.privileged.ssc import CENTRES
from isa.render.dataset import ObjectSpec, procedural_objects
from isa.skeleton_graph import SkeletonGraph

#: Part stride on training images (the experiment's default).
DEFAULT_STRIDE = 4


# -- sources ---------------------------------------------------------------------------------
def procedural_training(category: str, n: int, seed: int = 0) -> list[ObjectSpec]:
    """The ``n`` procedural training instances of run ``seed`` (the experiment's: generator seed
    ``seed * 1000 + 1``; its test instances use ``+ 2``)."""
    return procedural_objects(category, n, seed=seed * 1000 + 1, first_obj_id=1)


def mesh_files(meshes: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """Mesh files named by ``meshes``: files, folders (their files with a mesh extension, sorted)
    and glob patterns, in the order given, each file once. ``DataError`` names an argument that
    does not exist or gives no mesh file."""
    items = [meshes] if isinstance(meshes, (str, os.PathLike)) else list(meshes)
    if not items:
        raise DataError("no meshes given: name mesh files, folders or glob patterns")
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in MESH_EXTENSIONS)
            if not found:
                raise DataError(f"{p}: folder holds no mesh file ({', '.join(MESH_EXTENSIONS)})")
        elif p.is_file():
            found = [p]
        elif glob.has_magic(str(item)):
            found = sorted(Path(f) for f in glob.glob(str(item), recursive=True)
                           if Path(f).is_file() and Path(f).suffix.lower() in MESH_EXTENSIONS)
            if not found:
                raise DataError(f"{item}: the pattern matches no mesh file ({', '.join(MESH_EXTENSIONS)})")
        else:
            raise DataError(f"mesh file or folder not found: {item}")
        out += [f for f in found if f not in out]
    return out


def _modelnet_root(meshes, category: str) -> Path | None:
    """The ModelNet10 root if ``meshes`` is one folder laid out as one (``<category>/train``)."""
    items = [meshes] if isinstance(meshes, (str, os.PathLike)) else list(meshes)
    if len(items) != 1 or not Path(items[0]).is_dir():
        return None
    from isa.data.modelnet import find_root

    try:
        root = find_root(Path(items[0]))
    except DataError:
        return None
    if not (root / category / "train").is_dir():
        raise DataError(f"{items[0]} is a ModelNet10 root without a {category}/train folder")
    return root


def _check_height(category: str, height: float | None) -> None:
    if height is None:
        if category not in CATEGORIES:
            raise DataError(f"category {category!r} has no real-size table (only {', '.join(CATEGORIES)} have one): "
                            "give its height in metres (--height / height=)")
        return
    if isinstance(height, bool) or not isinstance(height, (int, float)) or not np.isfinite(height) or height <= 0:
        raise DataError(f"--height / height=: a positive height in metres, got {height!r}")


#: File conventions of the up axis (``up=``): "z" is ours (z up, front -y); "y" is glTF's (y up,
#: front +z), turned into ours by +90 degrees about x.
UP_AXES: dict[str, np.ndarray] = {
    "z": np.eye(4),
    "y": np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]),
}


def _sized(path: Path, category: str, height: float | None, seed, up: str = "z") -> tuple[trimesh.Trimesh, float]:
    """``path``'s mesh in metres, z up, centred on its box: scaled to ``height`` when given, else
    to a real size of ``category`` drawn from ``seed`` (:func:`isa.data.meshes.prepare_mesh`)."""
    mesh = load_mesh(path)
    if up != "z":
        mesh.apply_transform(UP_AXES[up])
    if height is None:
        return prepare_mesh(mesh, category, seed=seed)
    z = float(mesh.extents[2])
    if not z > 0:
        raise DataError(f"mesh file {path}: flat along z (height 0), cannot scale it to --height {height}")
    scaled = mesh.copy()
    scaled.apply_scale(height / z)
    return to_object_frame(scaled), height / z


def training_objects(meshes, category: str, *, procedural: int | None = None, instances: int | None = None,
                     height: float | None = None, up: str = "z", seed: int = 0, progress: bool = True) -> list[ObjectSpec]:
    """The training instances named by ``meshes`` (or ``procedural``), sized, with ``obj_id`` 1..n;
    ``up``: the files' up axis (:data:`UP_AXES`)."""
    if up not in UP_AXES:
        raise DataError(f"--up / up=: one of {', '.join(UP_AXES)}, got {up!r}")
    if procedural is not None:
        if meshes:
            raise DataError("give meshes or --procedural N, not both")
        if height is not None or up != "z":
            raise DataError("--height and --up apply to mesh files; procedural instances come in real size, z up")
        if isinstance(procedural, bool) or not isinstance(procedural, int) or procedural < 1:
            raise DataError(f"--procedural: a positive number of instances, got {procedural!r}")
        return procedural_training(category, procedural, seed)
    if meshes is None:
        raise DataError("no meshes given: name mesh files, folders or glob patterns, or --procedural N")
    _check_height(category, height)
    root = _modelnet_root(meshes, category)
    if root is not None:
        from isa.data.modelnet import paper_instances

        files = [i.path for i in paper_instances(root, category, instances)]
    else:
        files = mesh_files(meshes)[: instances or None]
    out = []
    for i, f in enumerate(tqdm(files, desc=f"load {category}", unit="mesh", disable=not progress, leave=False)):
        mesh, s = _sized(f, category, height, [seed, i], up)
        out.append(ObjectSpec(1 + i, category, mesh, str(f), s))
    return out


# -- cache -----------------------------------------------------------------------------------
def mesh_digest(mesh: trimesh.Trimesh) -> str:
    """A short content hash of a mesh's vertices and faces (cache key)."""
    h = hashlib.sha256(np.ascontiguousarray(mesh.vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, np.int64).tobytes())
    return h.hexdigest()[:20]


class SkeletonCache:
    """:func:`isa.privileged.skeleton.extract_skeleton` remembered by mesh content in ``folder``
    (None: not remembered). JSON keeps every float exactly, so a cached skeleton is the same."""

    def __init__(self, folder: Path | None) -> None:
        self.folder = folder

    def __call__(self, mesh: trimesh.Trimesh) -> SkeletonGraph:
        if self.folder is None:
            return extract_skeleton(mesh)
        path = self.folder / f"{mesh_digest(mesh)}.json"
        if path.is_file():
            return SkeletonGraph.from_dict(bop.read_json(path))
        sk = extract_skeleton(mesh)
        bop.write_json(path, sk.to_dict())
        return sk


def _template(category: str, objects: Sequence[ObjectSpec], extract: SkeletonCache, cache: Path | None,
              progress: bool) -> tuple[SkeletonGraph, str]:
    """The category's skeleton template and where it came from."""
    from isa import __version__, pipeline
    from isa.privileged.matching import template_from_instances

    if category in CATEGORIES:
        path = cache / f"template-{category}-{__version__}.json" if cache is not None else None
        if path is not None and path.is_file():
            return SkeletonGraph.from_dict(bop.read_json(path)), "procedural"
        tmpl = pipeline.category_template(category)
        if path is not None:
            bop.write_json(path, tmpl.to_dict())
        return tmpl, "procedural"
    raws = [extract(o.mesh) for o in tqdm(objects, desc=f"template {category}", unit="mesh", disable=not progress, leave=False)]
    try:
        return template_from_instances(raws, [o.mesh.bounds for o in objects]), "instances"
    except ValueError as exc:
        raise DataError(f"{category}: no skeleton template could be built from the {len(objects)} instances "
                        f"({exc}); check that the meshes are closed solids") from exc


def _render_key(objects: Sequence[ObjectSpec], views: int, seed: int) -> str:
    h = hashlib.sha256(json.dumps([views, seed, [(o.obj_id, mesh_digest(o.mesh)) for o in objects]]).encode())
    return h.hexdigest()[:16]


# -- the shared training steps (also the experiment's) ----------------------------------------
def augmented_frames(frames, objects: Sequence[ObjectSpec], mirror: bool = False, canonical: bool = False):
    """Training frames with mirrored copies of mirror-symmetric instances' views (``mirror``) and
    turn-symmetric instances labelled canonically (``canonical``), and counts of both."""
    from isa.privileged.mirror import find_mirror, with_mirrored
    from isa.privileged.symmetry import (
        canonical_frames,
        common_subgroup,
        find_yaw_symmetry,
    )

    info: dict = {}
    if mirror:
        mirrors = {o.obj_id: find_mirror(o.mesh) for o in objects}
        info["mirrored_instances"] = sum(m is not None for m in mirrors.values())
        frames = with_mirrored(frames, mirrors)
    if canonical:
        syms = common_subgroup({o.obj_id: find_yaw_symmetry(o.mesh) for o in objects})
        info["canonical_instances"] = sum(s.is_symmetric for s in syms.values())
        frames = canonical_frames(frames, syms)
    return frames, info


def model_metadata(prepared, quality: str, training: dict) -> dict:
    """What a model file carries for inference: category, SSC, origin rule (``centre``), template,
    the category's box (size), quality and the ``training`` summary (instances, views, stride,
    seed, ...); :func:`isa.forest.training.train_forest` adds ``predict_defaults``."""
    from isa import __version__
    from isa.detection import box_metadata, category_box

    return {"category": prepared.category, "ssc": prepared.ssc.ssc.to_dict(), "centre": prepared.ssc.centre,
            "template": prepared.ssc.template.to_dict(), "isa_version": __version__,
            **box_metadata(category_box(prepared)), "quality": quality, "training": training}


def training_summary(prepared, *, views: int, stride: int, seed: int, mirror: bool, canonical: bool,
                     images: int, parts: int, height: float | None = None, up: str = "z",
                     template: str = "procedural", context: bool = False) -> dict:
    """The ``training`` entry of a model's metadata (``context`` only when set, so one-class
    models keep their bytes)."""
    out = {"instances": [o.source for o in prepared.objects], "views": views, "stride": stride, "seed": seed,
           "mirror": mirror, "canonical": canonical, "images": images, "parts": parts, "height": height,
           "up": up, "template": template}
    if context:
        out["context"] = True
    return out


# -- the whole thing -------------------------------------------------------------------------
def _check_output(out: Path) -> None:
    """Refuse an output that cannot be written, before any work (the folder is made later)."""
    if out.is_dir():
        raise DataError(f"-o / out: {out} is a folder; name the model file to write")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise DataError(f"-o / out: cannot create the output folder {out.parent}: {parent} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DataError(f"-o / out: the output folder {parent} is not writable")


def train_category(
    meshes, category: str, out: str | os.PathLike, *, procedural: int | None = None, instances: int | None = None,
    views: int = PAPER_VIEWS, stride: int = DEFAULT_STRIDE, quality: str = "Q1+Q2+Q3", trees: int = 10,
    depth: int = ForestParams.max_depth, candidates: int = ForestParams.n_candidates, mirror: bool = False,
    canonical: bool = False, height: float | None = None, up: str = "z", centre: str | None = None, seed: int = 0,
    cache: str | os.PathLike | None = None, context: bool = False, progress: bool = True,
    shards: str | os.PathLike | None = None, cluster: bool = False, scheduler: str | None = None,
    workers: int | None = None,
) -> Path:
    """Train a ``category`` model on ``meshes`` (files, folders, globs or a ModelNet10 root; or
    ``procedural=N``) and write it to ``out``; returns ``out``.

    ``views`` rendered views per instance (seeded by ``seed``), parts every ``stride`` pixels,
    a ``trees``-tree forest of criterion ``quality`` (depth ``depth``, ``candidates`` features per
    node), probes and vote kernel scaled to the objects' size. ``height`` (metres) sizes every
    instance (required for categories without a size table); ``up``: the files' up axis, "z"
    (ModelNet's) or "y" (glTF's, front +z). ``centre``: the origin rule
    (:data:`isa.privileged.ssc.CENTRES`; default the category's, the centre of mass for others).
    ``cache``: folder that makes reruns skip finished work (module docstring). ``context``: the
    views show each instance standing in a room with noise, floor and walls removed
    (:mod:`isa.scenes.context`) instead of alone (the paper's one-class protocol).

    ``shards``: a folder for the training set as shards (:mod:`isa.forest.shards`), written as
    annotation goes and trained from without holding the set in memory (the renders go there
    too unless ``cache``); the model bytes are those of the in-memory run. ``cluster``: render,
    annotate and train on Dask (:mod:`isa.cluster`; needs ``shards``): a local cluster of
    ``workers`` processes, or the cluster at ``scheduler`` (then ``shards`` and ``cache`` must be
    on storage every worker reads). Errors
    (``DataError``) name the file or argument at fault and come before any output is written; the
    model is written atomically.
    """
    from isa import pipeline

    out = Path(out)
    if not category or not isinstance(category, str):
        raise DataError(f"--category / category=: a category name, got {category!r}")
    if centre is not None and centre not in CENTRES:
        raise DataError(f"--centre / centre=: one of {', '.join(CENTRES)}, got {centre!r}")
    if views < 1 or stride < 1:
        raise DataError(f"--views and --stride must be positive, got {views} and {stride}")
    params = ForestParams(n_trees=trees, max_depth=depth, n_candidates=candidates, quality=quality, seed=seed)
    _check_output(out)
    _check_scale(shards, cluster, scheduler, workers, mirror, canonical, context)
    cache_dir = Path(cache) if cache is not None else None
    if cache_dir is not None:
        try:
            (cache_dir / "skeletons").mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataError(f"--cache: cannot create {cache_dir} ({exc.strerror})") from None
    objects = training_objects(meshes, category, procedural=procedural, instances=instances, height=height,
                               up=up, seed=seed, progress=progress)
    extract = SkeletonCache(cache_dir / "skeletons" if cache_dir is not None else None)
    template, template_source = _template(category, objects, extract, cache_dir, progress)
    centre = centre or CENTRE.get(category, "com")
    prepared = pipeline.prepare_category(category, objects, progress=progress, centre=centre, template=template,
                                         extract=extract)

    if shards is not None:
        forest = _train_sharded(prepared, Path(shards), cache_dir, params, views=views, stride=stride, seed=seed,
                                height=height, up=up, template_source=template_source, progress=progress,
                                cluster=cluster, scheduler=scheduler, workers=workers)
        out.parent.mkdir(parents=True, exist_ok=True)
        forest.save(out)
        return out

    from isa.render.dataset import render_dataset

    out.parent.mkdir(parents=True, exist_ok=True)  # checked writable above; inputs are valid by now
    with tempfile.TemporaryDirectory(prefix="isa-train-", dir=None if cache_dir else out.parent) as tmp:
        base = cache_dir / "renders" if cache_dir is not None else Path(tmp)
        data = base / f"{category}-{'context-' if context else ''}{_render_key(prepared.objects, views, seed)}"
        if context:
            from isa.scenes.context import render_context_dataset

            render_context_dataset(data, prepared.objects, category, views, seed=seed, progress=progress)
        else:
            render_dataset(data, prepared.objects, split="train", n_views=views, view_seed=seed, progress=progress)
        frames = pipeline.load_frames(data, "train", lazy=True)
        forest_frames, _ = augmented_frames(frames, prepared.objects, mirror, canonical)
        ts = pipeline.training_set(forest_frames, prepared.skeletons, stride=stride, progress=progress, context=context)
        params = pipeline.scaled_params(params, ts, frames[0].intrinsics.fx)
        summary = training_summary(prepared, views=views, stride=stride, seed=seed, mirror=mirror,
                                   canonical=canonical, images=len(forest_frames), parts=len(ts), height=height,
                                   up=up, template=template_source, context=context)
    forest = pipeline.train_forest(ts, params, metadata=model_metadata(prepared, params.quality, summary),
                                   progress=progress)
    forest.save(out)  # atomic: a temporary file renamed over ``out``
    return out


def _check_scale(shards, cluster: bool, scheduler: str | None, workers: int | None, mirror: bool,
                 canonical: bool, context: bool = False) -> None:
    if (cluster or scheduler is not None or workers is not None) and shards is None:
        raise DataError("--cluster / --scheduler / --workers need --shards DIR (the folder the workers share)")
    if (scheduler is not None or workers is not None) and not cluster:
        raise DataError("--scheduler and --workers apply with --cluster")
    if scheduler is not None and workers is not None:
        raise DataError("--workers sizes the local cluster; an existing one (--scheduler) has its own")
    if shards is not None and (mirror or canonical or context):
        raise DataError("--mirror / --canonical / --context are not supported with --shards yet")


def _train_sharded(prepared, shards: Path, cache_dir: Path | None, params: ForestParams, *, views: int, stride: int,
                   seed: int, height, up: str, template_source: str, progress: bool, cluster: bool,
                   scheduler: str | None, workers: int | None):
    """Render, annotate into ``shards`` and train from them (on the cluster when ``cluster``)."""
    from contextlib import nullcontext

    from isa import pipeline
    from isa.forest.model import Forest
    from isa.forest.shards import annotate_to_shards
    from isa.render.dataset import render_dataset

    try:
        shards.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"--shards: cannot create {shards} ({exc.strerror})") from None
    base = cache_dir / "renders" if cache_dir is not None else shards / "renders"
    data = base / f"{prepared.category}-{_render_key(prepared.objects, views, seed)}"
    if cluster:
        from isa import cluster as dask_cluster

        connection = dask_cluster.connect(scheduler, workers or dask_cluster.DEFAULT_WORKERS)
    else:
        connection = nullcontext()
    with connection as client:
        if client is not None:
            dask_cluster.render_dataset(client, data, prepared.objects, "train", n_views=views, view_seed=seed,
                                        progress=progress)
        else:
            render_dataset(data, prepared.objects, split="train", n_views=views, view_seed=seed, progress=progress)
        frames = pipeline.load_frames(data, "train", lazy=True)
        if client is not None:
            norms = dask_cluster.annotate_to_shards(client, data, "train", prepared.skeletons, shards, stride=stride,
                                                    quality=params.quality, progress=progress)
        else:
            norms = annotate_to_shards(frames, prepared.skeletons, shards, stride=stride, quality=params.quality,
                                       progress=progress)
        params = pipeline.scaled_params(params, norms, frames[0].intrinsics.fx)
        summary = training_summary(prepared, views=views, stride=stride, seed=seed, mirror=False, canonical=False,
                                   images=len(frames), parts=len(norms), height=height, up=up,
                                   template=template_source)
        metadata = model_metadata(prepared, params.quality, summary)
        metadata["predict_defaults"] = pipeline.scaled_predict_defaults(norms)
        if client is not None:
            return dask_cluster.fit_forest(client, shards, params, metadata, progress=progress)
        return Forest(params).fit_shards(shards, metadata, progress=progress)


# -- command line ----------------------------------------------------------------------------
def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m isa train", description=__doc__.split("\n\n")[0])
    p.add_argument("meshes", nargs="*", metavar="MESHES",
                   help="mesh files (OFF, OBJ, PLY, STL, GLB), folders of them, glob patterns, or a ModelNet10 root")
    p.add_argument("--category", required=True, help="category name (bed, chair, table, toilet have a size table)")
    p.add_argument("-o", "--out", required=True, type=Path, help="model file to write")
    p.add_argument("--procedural", type=int, metavar="N", help="train on N procedural instances instead of meshes")
    p.add_argument("--instances", type=int, help="use only the first N instances (ModelNet: default the paper's count)")
    p.add_argument("--height", type=float, help="height of every instance in metres (needed for other categories)")
    p.add_argument("--up", choices=tuple(UP_AXES), default="z",
                   help="the files' up axis: z (ModelNet, front -y) or y (glTF/GLB, front +z)")
    p.add_argument("--views", type=int, default=PAPER_VIEWS, help="rendered views per instance (paper: 89)")
    p.add_argument("--stride", type=int, default=DEFAULT_STRIDE, help="part stride in pixels on training images")
    p.add_argument("--quality", default="Q1+Q2+Q3", choices=QUALITIES, help="split criterion")
    p.add_argument("--trees", type=int, default=ForestParams.n_trees)
    p.add_argument("--depth", type=int, default=ForestParams.max_depth, help="maximum tree depth")
    p.add_argument("--candidates", type=int, default=ForestParams.n_candidates, help="features tried per node")
    p.add_argument("--mirror", action="store_true", help="also train on flipped views of mirror-symmetric instances")
    p.add_argument("--canonical", action="store_true", help="label turn-symmetric instances with one canonical pose")
    p.add_argument("--centre", choices=CENTRES, help="object-frame origin (default: the category's; com for others)")
    p.add_argument("--context", action="store_true",
                   help="views of each instance standing in a room (noise on, floor and walls removed), not alone")
    p.add_argument("--cache", type=Path, help="folder of skeletons and renders kept between runs (rerun skips them)")
    p.add_argument("--shards", type=Path, metavar="DIR",
                   help="write the training set as shards in DIR and train from them (sets larger than memory)")
    p.add_argument("--cluster", action="store_true",
                   help="render, annotate and train on Dask (a local cluster unless --scheduler; needs --shards)")
    p.add_argument("--scheduler", metavar="ADDR", help="address of an existing Dask scheduler (tcp://host:8786)")
    p.add_argument("--workers", type=int, metavar="N", help="worker processes of the local cluster (default 2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def main(argv: list[str] | None = None) -> None:
    ap = parser()
    a = ap.parse_args(argv)
    try:
        path = train_category(a.meshes or None, a.category, a.out, procedural=a.procedural, instances=a.instances,
                              views=a.views, stride=a.stride, quality=a.quality, trees=a.trees, depth=a.depth,
                              candidates=a.candidates, mirror=a.mirror, canonical=a.canonical, height=a.height, up=a.up,
                              centre=a.centre, seed=a.seed, cache=a.cache, context=a.context, progress=not a.quiet,
                              shards=a.shards, cluster=a.cluster, scheduler=a.scheduler, workers=a.workers)
    except IsaError as exc:
        ap.exit(2, f"error: {exc}\n")
    print(f"model: {path}")


if __name__ == "__main__":
    main()

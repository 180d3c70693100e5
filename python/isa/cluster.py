"""The training pipeline on a Dask cluster (``pip install isa[cluster]``; docs/cluster.md).

:func:`connect` gives a ``dask.distributed`` client: a ``LocalCluster`` of ``workers`` spawned
processes on this machine by default, or an existing cluster at ``scheduler``. Then three kinds
of task, each writing to storage every worker reads (a shared folder path):

- :func:`render_dataset`: one task per instance, each worker rendering in its own GL context
  (workers are spawned, never forked); an instance whose frames are all written is skipped;
- :func:`annotate_to_shards`: one task per rendered instance, writing its shard
  (:mod:`isa.forest.shards`); the driver writes the manifest;
- :func:`fit_forest`: one task per tree (:class:`isa._core.ShardTrainer`, seeded as
  :meth:`isa.forest.Forest.fit` seeds that tree); the driver assembles the forest, whose bytes are
  those of ``Forest.fit_shards`` in one process.

A worker that dies mid-task has its task rerun elsewhere by the scheduler (the result does not
depend on where a task runs); a task that raises fails the job with its error, which names the
input at fault. Progress: the project's tqdm bar, and the Dask dashboard when bokeh is installed.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import numpy as np

from isa.exceptions import DataError, UsageError

#: Workers of the embedded ``LocalCluster``.
DEFAULT_WORKERS = 2


def _distributed():
    try:
        import distributed
    except ImportError:
        raise UsageError("the cluster needs dask.distributed: pip install 'isa[cluster]'") from None
    return distributed


@contextmanager
def connect(scheduler: str | None = None, workers: int = DEFAULT_WORKERS) -> Iterator[Any]:
    """A ``distributed.Client``: of the cluster at ``scheduler`` (``tcp://host:8786``), else of a
    ``LocalCluster`` of ``workers`` single-threaded worker processes (closed on exit)."""
    distributed = _distributed()
    if scheduler is not None:
        with distributed.Client(scheduler) as client:
            yield client
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise DataError(f"--workers / workers=: a positive number of workers, got {workers!r}")
    dashboard = ":0" if find_spec("bokeh") is not None else None
    import dask

    # Dask's nannies start workers with MALLOC_TRIM_THRESHOLD_=65536, which also turns off
    # glibc's adaptive mmap threshold: every large buffer of the core is then mmapped and
    # faulted in afresh, and the tasks spend their time in the kernel (docs/cluster.md, with
    # the recipe for workers started by hand). None unsets it (distributed's pre-spawn-environ rule).
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=dashboard)
    with cluster, distributed.Client(cluster) as client:
        yield client


def core_threads(client) -> int | None:
    """Threads each task's Rust core uses: the machine's cores shared among a local cluster's
    workers; None (all cores) on a remote cluster, whose workers are machines of their own."""
    cluster = getattr(client, "cluster", None)
    if cluster is None:
        return None
    return max(1, (os.cpu_count() or 1) // max(1, len(cluster.workers)))


def _gather(client, futures: list, desc: str, unit: str, progress: bool) -> list:
    """The futures' results in submission order, with a progress bar; the first task error is
    raised as the task raised it (the remaining tasks are cancelled)."""
    from tqdm.auto import tqdm

    distributed = _distributed()
    index = {f.key: i for i, f in enumerate(futures)}
    out: list = [None] * len(futures)
    with tqdm(total=len(futures), desc=desc, unit=unit, disable=not progress, leave=False) as bar:
        if progress and getattr(client, "dashboard_link", None) and find_spec("bokeh") is not None:
            bar.write(f"dask dashboard: {client.dashboard_link}")
        try:
            for f in distributed.as_completed(futures):
                out[index[f.key]] = f.result()
                bar.update(1)
        except BaseException:
            client.cancel(futures)
            raise
    return out


# -- training -----------------------------------------------------------------------------
_TRAINER: dict = {}  # in each worker process: the last shard folder prepared for its trees


def _fit_tree_task(shards: str, params: dict, t: int, n_threads: int | None) -> bytes:
    from isa import _core

    stat = (Path(shards) / _core.SHARD_MANIFEST).stat()
    key = (shards, stat.st_mtime_ns, stat.st_size, json.dumps(params, sort_keys=True), n_threads)
    trainer = _TRAINER.get(key)
    if trainer is None:
        _TRAINER.clear()  # one prepared set per worker at a time
        trainer = _TRAINER[key] = _core.ShardTrainer(shards, n_threads=n_threads, **params)
    return trainer.fit_tree(t)


def fit_forest(client, shards: str | os.PathLike[str], params, metadata: dict | str | None = None,
               predict_defaults: dict | None = None, progress: bool = True, n_threads: int | None = None):
    """Trains the forest of ``params`` (:class:`isa.forest.ForestParams`) from the shard folder
    ``shards`` with one task per tree, and assembles it: the model
    :meth:`isa.forest.Forest.fit_shards` makes in one process, to the byte. ``n_threads``: the
    core's threads per task (default :func:`core_threads`)."""
    from isa.forest.model import Forest

    shards = os.fspath(Path(shards).resolve())
    threads = core_threads(client) if n_threads is None else n_threads
    kwargs = params._core_kwargs()
    futures = [client.submit(_fit_tree_task, shards, kwargs, t, threads, pure=False)
               for t in range(params.n_trees)]
    trees = _gather(client, futures, "train", "tree", progress)
    return Forest(params).assemble(trees, shards, metadata, predict_defaults)


# -- annotation -----------------------------------------------------------------------------
def _annotate_task(data: str, split: str, scene: int, skeletons: dict, path: str, stride: int,
                   quality: str) -> np.ndarray:
    from isa.data import bop
    from isa.forest.shards import annotate_shard

    frames = bop.FrameSequence(data, split)
    idx = [i for i, (sid, _) in enumerate(frames.keys) if sid == scene]
    return annotate_shard((frames[i] for i in idx), skeletons, path, stride=stride, quality=quality)


def annotate_to_shards(client, data: str | os.PathLike[str], split: str, skeletons: dict,
                       folder: str | os.PathLike[str], *, stride: int, quality: str, progress: bool = True) -> np.ndarray:
    """:func:`isa.forest.shards.annotate_to_shards` with one task per rendered instance (scene
    of the BOP set ``data``/``split``); the same shards and manifest."""
    from isa.data import bop
    from isa.forest.shards import scene_frames, shard_name, write_manifest

    folder = Path(folder).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    scenes = [sid for sid, _ in scene_frames(bop.FrameSequence(data, split))]
    if not scenes:
        raise DataError(f"{data}/{split}: no frames")
    futures = [client.submit(_annotate_task, os.fspath(Path(data).resolve()), split, sid, skeletons,
                             os.fspath(folder / shard_name(sid)), stride, quality, pure=False) for sid in scenes]
    norms = _gather(client, futures, "annotate", "instance", progress)
    write_manifest(folder, [shard_name(sid) for sid in scenes])
    return np.concatenate(norms)


# -- rendering ------------------------------------------------------------------------------
def _render_task(out_root: str, obj, split: str, n_views: int, view_seed: int):
    from isa.render.dataset import render_instance

    return render_instance(out_root, obj, split=split, n_views=n_views, view_seed=view_seed)


def _scene_complete(out_root: Path, split: str, obj_id: int, n_views: int) -> bool:
    from isa.data import bop

    gt = bop.scene_dir(out_root, split, obj_id) / "scene_gt.json"
    return gt.is_file() and len(bop.read_json(gt)) >= n_views


def render_dataset(client, out_root: str | os.PathLike[str], objects: Sequence, split: str = "train",
                   n_views: int | None = None, view_seed: int = 0, progress: bool = True) -> list[int]:
    """:func:`isa.render.dataset.render_dataset` of ``objects`` with their default views, one task
    per instance (instances already complete are skipped); the same frames. Returns the obj_ids
    rendered now."""
    from isa.categories import PAPER_VIEWS
    from isa.render.dataset import prepare_dataset

    n_views = PAPER_VIEWS if n_views is None else n_views
    out_root = Path(out_root).resolve()
    prepare_dataset(out_root, objects, split, n_views=n_views, view_seed=view_seed)
    todo = [o for o in objects if not _scene_complete(out_root, split, o.obj_id, n_views)]
    futures = [client.submit(_render_task, os.fspath(out_root), o, split, n_views, view_seed, pure=False)
               for o in todo]
    _gather(client, futures, f"render {split}", "instance", progress)
    return [o.obj_id for o in todo]

"""Training sets on disk as shards: one ``.isat`` file per rendered instance and a manifest
(``isa_core::shards``; docs/cluster.md), written as annotation goes, so a training set larger
than memory never sits in it; :meth:`isa.forest.Forest.fit_shards` trains from the folder.

The shards' rows, in manifest order, are the rows :func:`isa.pipeline.training_set` makes from
the same frames in the same order, so the model trained from shards is the in-memory one.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from isa import _core
from isa.exceptions import DataError, IsaError
from isa.forest.training import offset_norms
from isa.privileged.annotate import TrainingSet

#: The manifest's file name inside a shard folder.
MANIFEST = _core.SHARD_MANIFEST


def shard_name(key: int) -> str:
    """File name of the shard of instance (scene) ``key``."""
    return f"{key:06d}.isat"


def write_shard(path: str | os.PathLike[str], ts: TrainingSet, quality: str) -> None:
    """Writes ``ts`` as one shard (atomic). The wide targets are kept unless ``quality`` is
    "Q1", which trains without them (as :func:`isa.pipeline.train_forest` drops them)."""
    wide = quality != "Q1"
    _core.TrainSet(list(ts.images), ts.parts, ts.offsets, ts.rotations,
                   ts.link_angles if wide else None, ts.node_offsets if wide else None).write(os.fspath(path))


def shard_norms(path: str | os.PathLike[str]) -> np.ndarray | None:
    """The parts' distances to the SSC in an existing shard (None if the file is absent or not a
    valid shard, so it is written again)."""
    if not Path(path).is_file():
        return None
    try:
        d = _core.read_trainset(os.fspath(path))
    except IsaError:
        return None
    return np.linalg.norm(d["offsets"], axis=1)


def annotate_shard(frames: Iterable, skeletons: dict, path: str | os.PathLike[str], *, stride: int,
                   quality: str) -> np.ndarray:
    """Annotates ``frames`` (one instance's views) into shard ``path``, unless a valid shard is
    already there; returns its parts' distances to the SSC (for :func:`isa.pipeline.parts_diameter`)."""
    from isa import pipeline

    done = shard_norms(path)
    if done is not None:
        return done
    ts = pipeline.training_set(frames, skeletons, stride=stride, progress=False)
    write_shard(path, ts, quality)
    return offset_norms(ts)


def write_manifest(folder: str | os.PathLike[str], files: Sequence[str]) -> dict:
    """Writes the folder's manifest over the shards ``files`` (in training order), each read and
    validated (a bad shard raises, naming it); returns the manifest."""
    import json

    if not files:
        raise DataError(f"{folder}: no shards to list")
    return json.loads(_core.write_shard_manifest(os.fspath(folder), list(files)))


def scene_frames(frames) -> list[tuple[int, list[int]]]:
    """``(scene id, frame indices)`` of a :class:`isa.data.bop.FrameSequence`, in its order (one
    scene per instance in rendered training sets)."""
    out: list[tuple[int, list[int]]] = []
    for i, (sid, _) in enumerate(frames.keys):
        if not out or out[-1][0] != sid:
            out.append((sid, []))
        out[-1][1].append(i)
    return out


def annotate_to_shards(frames, skeletons: dict, folder: str | os.PathLike[str], *, stride: int, quality: str,
                       progress: bool = True) -> np.ndarray:
    """Annotates a rendered training set one instance at a time into shards of ``folder`` (a
    finished shard is kept on rerun) and writes the manifest; returns every part's distance to
    the SSC, in training order. :func:`isa.cluster.annotate_to_shards` does the same on a cluster."""
    from tqdm.auto import tqdm

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    groups = scene_frames(frames)
    norms = []
    for sid, idx in tqdm(groups, desc="annotate", unit="instance", disable=not progress, leave=False):
        norms.append(annotate_shard((frames[i] for i in idx), skeletons, folder / shard_name(sid),
                                    stride=stride, quality=quality))
    write_manifest(folder, [shard_name(sid) for sid, _ in groups])
    return np.concatenate(norms)

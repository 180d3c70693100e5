"""Training a category forest: annotated parts of rendered views, size-aware hyper-parameters and
inference defaults, the fit (the training half of :mod:`isa.pipeline`, which re-exports it)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from isa.data import bop
from isa.exceptions import DataError
from isa.forest.model import Forest, ForestParams
from isa.privileged.annotate import Frame, TrainingSet, build_training_set
from isa.skeleton_graph import SkeletonGraph

__all__ = [
    "load_frames", "training_set", "PROBE_REACH", "VOTE_BANDWIDTH", "parts_diameter", "scaled_max_offset", "scaled_params",
    "scaled_predict_defaults", "train_forest",
]


def load_frames(root: Path, split: str, lazy: bool = False) -> list[bop.BopFrame] | bop.FrameSequence:
    """Every frame of a BOP split, in scene then image order; with ``lazy``, a
    :class:`isa.data.bop.FrameSequence` that reads each frame when it is used (for training sets too
    large to hold: 6,052 views at 640x480 take 9.3 GB in memory)."""
    frames = bop.FrameSequence(root, split)
    if len(frames) == 0:
        raise DataError(f"{root}/{split}: no frames")
    return frames if lazy else list(frames)


def training_set(frames: Sequence[bop.BopFrame], skeletons: dict[int, SkeletonGraph], stride: int = 4,
                 progress: bool = True, context: bool = False) -> TrainingSet:
    """Annotated parts of rendered training frames (the forest's input); the frames are read
    once, one at a time, so a lazy sequence keeps only their crops in memory. ``context``: views
    in a room (:mod:`isa.scenes.context`), whose depth around the object is kept."""
    bar = tqdm(frames, desc="annotate", unit="frame", disable=not progress, leave=False)
    fs = (Frame(f.depth, f.mask, f.R, f.t, f.intrinsics, skeletons[f.obj_id]) for f in bar)
    return build_training_set(fs, stride=stride, context=context)


#: Scale-aware settings, as fractions of the objects' diameter (estimated from the training parts,
#: :func:`parts_diameter`), so large categories (tables, beds) get probes and kernels that fit them.
#: Chosen on held-out ModelNet *training* instances (``python -m isa experiment --validation``),
#: never on test instances: table recall rose from 5% (probes fixed at 150 px·m = 0.26 m) to 21%
#: at 400 px·m (0.34 of its 2 m diameter) and 35% at 800 px·m (0.68); see docs/experiments.md.
PROBE_REACH = 0.7
#: Position kernel radius of the Hough voting at inference (default 0.08 m suits a 1 m chair).
VOTE_BANDWIDTH = 0.09


def parts_diameter(ts: TrainingSet | np.ndarray) -> float:
    """The objects' diameter as the training parts see it: twice the 95th percentile of the
    parts' distance to the SSC (metres). ``ts``: a training set, or those distances
    (:func:`offset_norms`, e.g. gathered from shards)."""
    norms = offset_norms(ts) if isinstance(ts, TrainingSet) else np.asarray(ts)
    if len(norms) == 0:
        raise DataError("parts_diameter: the training set has no parts")
    return float(2 * np.percentile(norms, 95))


def offset_norms(ts: TrainingSet) -> np.ndarray:
    """Each part's distance to the SSC, (P,) float32 (what :func:`parts_diameter` ranks)."""
    return np.linalg.norm(ts.offsets, axis=1)


def scaled_max_offset(ts: TrainingSet | np.ndarray, fx: float) -> float:
    """``ForestParams.max_offset`` (pixel·metres) reaching :data:`PROBE_REACH` of the objects'
    diameter, for a camera of focal length ``fx`` pixels; clipped to [50, 2000]."""
    return float(np.clip(PROBE_REACH * parts_diameter(ts) * fx, 50.0, 2000.0))


def scaled_params(params: ForestParams, ts: TrainingSet | np.ndarray, fx: float) -> ForestParams:
    """``params`` with ``max_offset`` scaled to the objects' size (:func:`scaled_max_offset`)."""
    return replace(params, max_offset=scaled_max_offset(ts, fx))


def scaled_predict_defaults(ts: TrainingSet | np.ndarray) -> dict:
    """Size-aware inference defaults, stored as the model's ``predict_defaults`` and applied by its ``predict``."""
    return {"position_bandwidth": round(VOTE_BANDWIDTH * parts_diameter(ts), 4)}


def train_forest(ts: TrainingSet, params: ForestParams, metadata: dict | None = None, progress: bool = True) -> Forest:
    """Fit a forest on a training set; ``metadata`` (category, SSC, ...) goes into the model file,
    with size-aware inference defaults (``predict_defaults``, see :func:`scaled_predict_defaults`)
    unless it has its own."""
    forest = Forest(params)
    arrays = ts.arrays()
    if params.quality == "Q1":
        arrays["link_angles"] = None
        arrays["node_offsets"] = None
    metadata = dict(metadata or {})
    metadata.setdefault("predict_defaults", scaled_predict_defaults(ts))
    forest.fit(**arrays, metadata=metadata, progress=progress)
    return forest

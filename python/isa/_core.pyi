"""Type stubs of ``isa._core``, the Rust extension (PyO3). All array arguments are strict:
the stated dtype, shape and C-contiguity, finite values; anything else raises
``InvalidInputError`` naming the argument."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str
#: Version of the model-file format this build writes (and the newest it reads).
MODEL_FORMAT_VERSION: int
#: Depth (mm) a feature probe reads outside the image or on missing depth.
BACKGROUND_MM: float

class IsaError(Exception):
    """Base class of every error raised by isa."""

class InvalidInputError(IsaError):
    """An argument has the wrong dtype, shape, layout or value (the message names it)."""

class InvalidParameterError(IsaError):
    """A hyper-parameter failed validation (the message names it)."""

class ModelFormatError(IsaError):
    """A model file is truncated, corrupted, foreign or from a newer format version."""

class IsaIOError(IsaError):
    """An operating-system I/O failure on a named file."""

class Forest:
    """The ISA forest (Rust). Hyper-parameters are keyword arguments named as the fields of
    ``isa.forest.ForestParams`` (unknown names raise ``InvalidParameterError``).

    ``n_threads`` (None = rayon's default, i.e. all cores or RAYON_NUM_THREADS) only changes
    speed: the same parameters, seed and data give byte-identical models.
    """

    def __init__(self, *, n_threads: int | None = None, **params: Any) -> None: ...
    def fit(
        self,
        images: list[npt.NDArray[np.uint16]],
        parts: npt.NDArray[np.int32],
        offsets: npt.NDArray[np.float32],
        rotations: npt.NDArray[np.float32],
        link_angles: npt.NDArray[np.float32] | None = None,
        node_offsets: npt.NDArray[np.float32] | None = None,
        metadata: str = "{}",
        on_tree: Callable[[int], object] | None = None,
    ) -> None:
        """Trains (GIL released). images: uint16 (h, w) mm; parts (P, 3) int32 [image, u, v];
        offsets (P, 3) m; rotations (P, 4) (w, x, y, z); link_angles (P, L) rad; node_offsets
        (P, 3N); metadata: an opaque JSON string stored in the model file; on_tree(trees_done)
        after each tree (its first exception is raised when training ends)."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes the model atomically; ``IsaIOError`` on failure."""
    @staticmethod
    def load(path: str | os.PathLike[str], *, n_threads: int | None = None) -> Forest:
        """Reads a model; ``ModelFormatError`` if truncated/corrupted/foreign/newer."""
    def to_bytes(self) -> bytes:
        """The model-file bytes."""
    @staticmethod
    def from_bytes(data: bytes) -> Forest:
        """Parses model-file bytes (``ModelFormatError`` if invalid)."""
    def __getstate__(self) -> bytes: ...
    def __setstate__(self, state: bytes) -> None: ...
    def apply(self, images: list[npt.NDArray[np.uint16]], parts: npt.NDArray[np.int32]) -> npt.NDArray[np.int32]:
        """Leaf index of every part in every tree: (P, n_trees) int32 (GIL released)."""
    def votes(self, images: list[npt.NDArray[np.uint16]], parts: npt.NDArray[np.int32]) -> dict[str, np.ndarray]:
        """Flat votes of every (part, tree): part (V,) int32, tree (V,) int32, weight (V,)
        float32, offset (V, 3) float32 metres, rotation (V, 4) float32 (w, x, y, z, w >= 0);
        ordered by part, tree, decreasing weight (GIL released)."""
    def leaf_votes(
        self, tree: int, leaf: int
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """(weights (k,), offsets (k, 3), rotations (k, 4)) of one leaf."""
    @property
    def params_json(self) -> str:
        """The training configuration as JSON."""
    @property
    def metadata(self) -> str:
        """The opaque metadata JSON string stored with the model."""
    @property
    def is_fitted(self) -> bool: ...
    @property
    def n_trees(self) -> int: ...
    @property
    def n_threads(self) -> int | None: ...
    @n_threads.setter
    def n_threads(self, n: int | None) -> None: ...
    @property
    def crate_version(self) -> str:
        """Version of isa that trained the model."""
    @property
    def n_nodes(self) -> list[int]: ...
    @property
    def n_leaves(self) -> list[int]: ...
    @property
    def depths(self) -> list[int]: ...

def sample_parts(
    images: list[npt.NDArray[np.uint16]], stride: int = 4, max_per_image: int | None = None, seed: int = 0
) -> npt.NDArray[np.int32]:
    """Parts on a ``stride`` grid (``u % stride == v % stride == 0``) with depth > 0, image by
    image, row by row: (P, 3) int32 [image, u, v]. Test time: every valid pixel on the grid.
    Training (``max_per_image``): at most that many per image, drawn with ``seed``."""

def depth_features(
    images: list[npt.NDArray[np.uint16]],
    parts: npt.NDArray[np.int32],
    u: npt.NDArray[np.float32],
    v: npt.NDArray[np.float32],
) -> npt.NDArray[np.float32]:
    """Eq. 5 features, (P, C) float32 mm, for offsets u, v (C, 2) pixel·metres:
    D(w + round(u * 1000 / D_mm(w))) - D(w + round(v * 1000 / D_mm(w))) with round(x) =
    floor(x + 0.5) in float32; probes outside the image or on depth 0 read BACKGROUND_MM."""

def criterion_gains(
    offsets: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    link_angles: npt.NDArray[np.float32] | None,
    node_offsets: npt.NDArray[np.float32] | None,
    left_mask: npt.NDArray[np.bool_],
    reg: float = 1e-4,
    reduce_dims: int = 0,
) -> dict[str, float]:
    """Test hook: gains {"Q1", ["Q2"], ["Q3"]} of splitting these parts by ``left_mask``, with
    the forest's own embedding (6D rotation, cos/sin angles), standardisation over these parts,
    optional PCA reduction and ridge ``reg``."""

def criterion_targets(
    offsets: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    link_angles: npt.NDArray[np.float32] | None = None,
    node_offsets: npt.NDArray[np.float32] | None = None,
    reduce_dims: int = 0,
) -> tuple[npt.NDArray[np.float32], list[int]]:
    """The criterion's (P, D) float32 target vectors and the block sizes
    [3 (offset), 6 (rotation), links, nodes]."""

def split_search(
    features: npt.NDArray[np.float32],
    offsets: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    link_angles: npt.NDArray[np.float32] | None = None,
    node_offsets: npt.NDArray[np.float32] | None = None,
    *,
    quality: str = "Q1+Q2+Q3",
    n_thresholds: int = 16,
    min_samples_leaf: int = 1,
    reg: float = 1e-4,
    reduce_dims: int = 4,
    seed: int = 0,
    n_threads: int | None = None,
) -> dict[str, Any]:
    """Benchmark hook: the forest's split search of one node holding all P parts, candidates =
    columns of ``features`` (P, C). Returns candidate, threshold, gain, gains [Q1, Q2, Q3],
    n_left and seconds (search only)."""

# ---- Inference (crates/isa-py/src/vote.rs; owned by the inference work) --------------------
# Keyword parameters of predict / image_votes: stride (4), min_depth (0 m), max_depth (None m),
# min_leaf_weight (0) and the mode-finding ones shared with find_modes: position_bandwidth
# (0.08 m), rotation_bandwidth (0.5 rad), max_hypotheses (5), nms_radius (0.25 m), max_seeds
# (64), max_iterations (50), rotations_per_position (1), rotation_candidates (64),
# rotation_eval_votes (1024), min_support (3), coarse_votes (32768), refine_modes (16),
# refine_votes (4096); see isa_core::vote::VoteParams. Unknown names raise InvalidParameterError.

#: Version of the training-set (.isat) file format written by ``write_trainset``.
TRAINSET_FORMAT_VERSION: int

def predict(
    forest: Forest | Any,
    depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | npt.NDArray[np.float64],
    K: npt.ArrayLike | Any,
    *,
    n_threads: int | None = None,
    **params: Any,
) -> list[dict[str, Any]]:
    """Ranked 6D pose hypotheses of the objects in a whole depth image (paper Eq. 12-13): parts
    on a ``stride`` grid of valid pixels go down every tree, each leaf vote (part's 3D point +
    offset, rotation, weight / n_trees) is accumulated, modes are found by mean-shift in 3D then
    on SO(3). ``forest``: ``_core.Forest`` or ``isa.forest.Forest``; ``depth`` (H, W) uint16 mm or
    float metres (0 = missing); ``K`` a 3x3 matrix, (fx, fy, cx, cy) or ``isa.camera.Intrinsics``.
    Each hypothesis, best first: ``R`` (3, 3), ``t`` (3,) metres (SSC in the camera frame,
    X_cam = R X_obj + t), ``quaternion`` (w, x, y, z; w >= 0), ``score`` (joint kernel density),
    ``support`` (votes in both kernels), ``position_score``, ``position_support``. GIL released;
    deterministic for any ``n_threads`` (None = the forest's setting)."""

def image_votes(
    forest: Forest | Any,
    depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | npt.NDArray[np.float64],
    K: npt.ArrayLike | Any,
    *,
    n_threads: int | None = None,
    **params: Any,
) -> dict[str, Any]:
    """Every vote ``predict`` would aggregate (for plots): ``position`` (V, 3) float32 metres,
    ``rotation`` (V, 4) float32, ``weight`` (V,) float32, ``pixel`` (V, 2) int32 (u, v) of the
    casting part, ``tree`` (V,) int32, ``n_parts`` int."""

def find_modes(
    positions: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    weights: npt.NDArray[np.float32] | None = None,
    *,
    n_threads: int | None = None,
    **params: Any,
) -> list[dict[str, Any]]:
    """Mode finding alone on given votes: positions (V, 3), rotations (V, 4) (w, x, y, z, any
    sign), weights (V,) or None (all 1). Returns hypotheses as ``predict``."""

def default_predict_params() -> dict[str, Any]:
    """The default inference parameters (flat: image-level and mode-finding keys)."""

def write_trainset(
    path: str | os.PathLike[str],
    images: list[npt.NDArray[np.uint16]],
    parts: npt.NDArray[np.int32],
    offsets: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    link_angles: npt.NDArray[np.float32] | None = None,
    node_offsets: npt.NDArray[np.float32] | None = None,
    metadata: str = "{}",
) -> None:
    """Validates and writes a training-set file (.isat) for ``isa train``: the arguments of
    ``Forest.fit``. Format: versioned, checksummed container of NPY arrays (see
    ``isa_core::trainset_io`` and docs/CLI.md). Atomic (temporary file + rename)."""

def read_trainset(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Reads a training-set file: ``images`` (list of uint16 arrays), ``parts``, ``offsets``,
    ``rotations``, ``link_angles`` / ``node_offsets`` (or None), ``metadata`` (str)."""

"""Type stubs of ``isa._core``, the Rust extension (PyO3). All array arguments are strict:
the stated dtype, shape and C-contiguity, finite values; anything else raises
``InvalidInputError`` naming the argument."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str
#: Version of the model-file format this build writes (and the newest it reads).
MODEL_FORMAT_VERSION: int
#: Depth (mm) a feature probe reads outside the image or on missing depth.
BACKGROUND_MM: float

#: The core's training defaults (the fields of ``isa.forest.ForestParams``).
FOREST_DEFAULTS: dict[str, Any]
#: The core's inference defaults, flat keys (image-level and mode-finding).
PREDICT_DEFAULTS: dict[str, Any]

class IsaError(Exception):
    """Base class of every error raised by isa."""

class InvalidInputError(IsaError, ValueError):
    """An argument has the wrong dtype, shape, layout or value (the message names it)."""

class InvalidTypeError(InvalidInputError, TypeError):
    """An argument has the wrong type (the message names it)."""

class InvalidParameterError(IsaError, ValueError):
    """A hyper-parameter failed validation (the message names it)."""

class ModelFormatError(IsaError, ValueError):
    """A model file is truncated, corrupted, foreign or from a newer format version."""

class IsaIOError(IsaError, OSError):
    """An operating-system I/O failure on a named file (``filename``, ``errno`` set)."""

class IsaFileNotFoundError(IsaIOError, FileNotFoundError):
    """A file that isa needs does not exist."""

class IsaPermissionError(IsaIOError, PermissionError):
    """A file cannot be read or written for lack of permission."""

class IsaIsADirectoryError(IsaIOError, IsADirectoryError):
    """A path names a directory where isa needs a file."""

class Hypothesis:
    """A ranked 6D pose, ``X_cam = R @ X_obj + t``. Fields are attributes and also items under
    the same names (``h["R"]``, ``h.get("score")``, ``dict(h)``), as when hypotheses were dicts;
    registered as a ``collections.abc.Mapping``."""

    @property
    def R(self) -> npt.NDArray[np.float64]:
        """Rotation matrix (3, 3)."""
    @property
    def t(self) -> npt.NDArray[np.float64]:
        """Translation (3,), metres: the object-frame origin in the camera frame."""
    @property
    def quaternion(self) -> npt.NDArray[np.float64]:
        """The rotation as (w, x, y, z), w >= 0."""
    @property
    def score(self) -> float:
        """Joint kernel density of the votes at the mode (the ranking key)."""
    @property
    def support(self) -> int:
        """Votes inside both kernels."""
    @property
    def position_score(self) -> float: ...
    @property
    def position_support(self) -> int: ...
    def __getitem__(self, key: str) -> Any: ...
    def get(self, key: str, default: Any = None) -> Any: ...
    def __contains__(self, key: str) -> bool: ...
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[str]: ...
    def keys(self) -> list[str]: ...
    def values(self) -> list[Any]: ...
    def items(self) -> list[tuple[str, Any]]: ...
    def to_dict(self) -> dict[str, Any]:
        """The fields as a plain dict."""

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
        metadata: str = ...,  # "{}"
        on_tree: Callable[[int], object] | None = None,
        predict_defaults: dict[str, Any] | None = None,
    ) -> None:
        """Trains (GIL released). images: uint16 (h, w) mm; parts (P, 3) int32 [image, u, v];
        offsets (P, 3) m; rotations (P, 4) (w, x, y, z); link_angles (P, L) rad; node_offsets
        (P, 3N); metadata: a JSON object (category, centre, box, extra keys; a
        ``predict_defaults`` key in it is read as inference defaults) stored in the model file;
        predict_defaults: inference defaults (flat keys) overlaid on those; on_tree(trees_done)
        after each tree (its first exception is raised when training ends)."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes the model atomically; ``IsaIOError`` on failure."""
    @staticmethod
    def load(path: str | os.PathLike[str], *, n_threads: int | None = None) -> Forest:
        """Reads a model; ``ModelFormatError`` if truncated/corrupted/foreign/newer."""
    def to_bytes(self) -> bytes:
        """The model-file bytes."""
    @staticmethod
    def from_bytes(data: bytes | bytearray | memoryview) -> Forest:
        """Parses model-file bytes (``ModelFormatError`` if invalid)."""
    def __getstate__(self) -> bytes: ...
    def __setstate__(self, state: bytes | bytearray | memoryview) -> None: ...
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
        """The model's metadata as a JSON object: category, centre, box, training (counts of
        the training data), extra keys."""
    @property
    def predict_defaults(self) -> dict[str, Any]:
        """The inference defaults stored in the model (flat keys), which ``predict`` starts from."""
    def predict(
        self,
        depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | npt.NDArray[np.float64],
        K: npt.ArrayLike | Any,
        *,
        n_threads: int | None = None,
        **params: Any,
    ) -> list[Hypothesis]:
        """Ranked 6D hypotheses of a whole depth image (see ``predict``); keyword parameters
        (flat keys of ``PREDICT_DEFAULTS``) overlay the model's ``predict_defaults``."""
    def image_votes(
        self,
        depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | npt.NDArray[np.float64],
        K: npt.ArrayLike | Any,
        *,
        n_threads: int | None = None,
        **params: Any,
    ) -> dict[str, Any]:
        """Every vote ``predict`` would aggregate (see ``image_votes``)."""
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

# ---- Inference ------------------------------------------------------------------------------
# Keyword parameters of predict / image_votes: the keys of PREDICT_DEFAULTS (stride, min_depth,
# max_depth, min_leaf_weight, and the mode-finding ones shared with find_modes), overlaid on the
# model's predict_defaults. Unknown names raise InvalidParameterError. The criterion and
# split-search test hooks live in the private submodule ``isa._core._testing``.

#: Version of the training-set (.isat) file format written by ``write_trainset``.
TRAINSET_FORMAT_VERSION: int

def find_modes(
    positions: npt.NDArray[np.float32],
    rotations: npt.NDArray[np.float32],
    weights: npt.NDArray[np.float32] | None = None,
    *,
    n_threads: int | None = None,
    **params: Any,
) -> list[Hypothesis]:
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

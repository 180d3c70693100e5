"""Type stubs of ``isa._core``, the Rust extension (PyO3). All array arguments are strict:
the stated dtype, shape and C-contiguity, finite values; anything else raises
``InvalidInputError`` naming the argument."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from types import ModuleType
from typing import Any, final

import numpy as np
import numpy.typing as npt

# The module's names (pyo3 lists every addition in the runtime __all__; stubtest compares).
__all__ = [
    "BACKGROUND_MM",
    "DETECT_DEFAULTS",
    "FOREST_DEFAULTS",
    "Forest",
    "Hypothesis",
    "InputWarning",
    "InvalidInputError",
    "InvalidParameterError",
    "InvalidTypeError",
    "IsaError",
    "IsaFileNotFoundError",
    "IsaIOError",
    "IsaIsADirectoryError",
    "IsaPermissionError",
    "MODEL_FORMAT_VERSION",
    "ModelFormatError",
    "PREDICT_DEFAULTS",
    "RANKER_FORMAT",
    "RANK_FEATURES",
    "SHAPES_FORMAT_VERSION",
    "SHARD_MANIFEST",
    "ShapeLibrary",
    "ShardTrainer",
    "TRAINSET_FORMAT_VERSION",
    "TrainSet",
    "__version__",
    "_cli_main",
    "_testing",
    "check_ranker",
    "default_predict_params",
    "depth_from_points",
    "depth_to_metres",
    "depth_features",
    "detect",
    "find_modes",
    "find_planes",
    "nms_across",
    "read_trainset",
    "refine_pose",
    "render_depth",
    "sample_parts",
    "verify_pose",
    "write_shard_manifest",
]
__version__: str
#: Test hooks (criterion terms, split search): not public API.
_testing: ModuleType
#: The newest model-file format this build reads and writes (a forest without leaf weights is
#: written as format 2).
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

class InputWarning(UserWarning):
    """An input accepted but probably wrong: a depth range implausible for a depth sensor (a
    wrong ``depth_scale``), an image that looks transposed against its intrinsics."""

def _cli_main(argv: list[str]) -> int:
    """Runs the ``isa`` command line (``argv``: program name first); returns the exit code."""

def depth_to_metres(depth: npt.ArrayLike, K: Any, depth_scale: float | None = None) -> npt.NDArray[np.float32]:
    """A depth image (H, W) or organised point cloud (H, W, 3) as float32 metres, checked as
    ``Forest.predict`` checks it (``depth_scale``, image size, ``InputWarning``)."""

def depth_from_points(points: npt.ArrayLike, K: Any, width: int, height: int) -> npt.NDArray[np.float32]:
    """Camera-frame points (N, 3) float64 projected to a (height, width) float32 depth image in
    the points' unit (nearest point per pixel, 0 = missing)."""

def render_depth(
    vertices: npt.NDArray[np.float32],
    faces: npt.NDArray[np.integer[Any]],
    R: npt.ArrayLike,
    t: npt.ArrayLike,
    K: Any,
    width: int,
    height: int,
    znear: float,
    zfar: float,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Depth (H, W) float32 metres (0 = background) and mask (H, W) bool of the mesh
    (``vertices`` (N, 3) float32 in the object frame, ``faces`` (M, 3) integer) at pose
    ``X_cam = R @ X_obj + t``, through ``K`` (OpenCV, pixel centres at integers) in a
    ``width`` x ``height`` image between ``znear`` and ``zfar`` metres. Both windings of every
    face are drawn; the nearest face wins."""

@final
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
    def pose(self) -> npt.NDArray[np.float64]:
        """The 4x4 pose ``[[R, t], [0, 0, 0, 1]]``: ``X_cam = pose @ [X_obj, 1]``."""
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
    def __getitem__(self, key: str, /) -> Any: ...
    def get(self, key: str, default: Any = None) -> Any: ...
    def __contains__(self, key: str, /) -> bool: ...
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[str]: ...
    def keys(self) -> list[str]: ...
    def values(self) -> list[Any]: ...
    def items(self) -> list[tuple[str, Any]]: ...
    def to_dict(self) -> dict[str, Any]:
        """The fields as a plain dict."""

@final
class Forest:
    """The ISA forest (Rust). Hyper-parameters are keyword arguments named as the fields of
    ``isa.forest.ForestParams`` (unknown names raise ``InvalidParameterError``).

    ``n_threads`` (None = rayon's default, i.e. all cores or RAYON_NUM_THREADS) only changes
    speed: the same parameters, seed and data give byte-identical models.
    """

    def __new__(cls, *, n_threads: int | None = None, **params: Any) -> Forest: ...
    def fit(
        self,
        trainset: TrainSet,
        metadata: str | None = None,
        on_tree: Callable[[int], object] | None = None,
        predict_defaults: dict[str, Any] | None = None,
    ) -> None:
        """Trains on ``trainset`` (GIL released). metadata: a JSON object (category, centre,
        box, extra keys; a ``predict_defaults`` key in it is read as inference defaults) stored
        in the model file, by default the set's own; predict_defaults: inference defaults (flat
        keys) overlaid on those; on_tree(trees_done) after each tree (its first exception is
        raised when training ends)."""
    def fit_shards(
        self,
        shards: str | os.PathLike[str],
        metadata: str = ...,
        on_tree: Callable[[int], object] | None = None,
        predict_defaults: dict[str, Any] | None = None,
    ) -> None:
        """Trains from a shard folder (manifest.json + .isat shards): ``fit``'s bytes on the
        shards' arrays concatenated; other arguments as ``fit``'s."""
    def assemble(
        self,
        trees: list[bytes],
        shards: str | os.PathLike[str],
        metadata: str = ...,
        predict_defaults: dict[str, Any] | None = None,
    ) -> None:
        """The forest from ``ShardTrainer.fit_tree(t)`` of every tree, in order, on ``shards``
        (its counts): ``fit_shards``'s bytes."""
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
    def with_leaf_weights(self, weights: Sequence[npt.NDArray[np.float32]] | None) -> Forest:
        """This forest with per-leaf vote weights (one float32 array of ``n_leaves[t]`` weights
        in [0, 1] per tree), or without any (None): a new Forest, this one unchanged."""
    @property
    def leaf_weights(self) -> list[npt.NDArray[np.float32]] | None:
        """The per-leaf vote weights (one array per tree), or None (one-class)."""
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

#: Version of the training-set (.isat) file format written by ``TrainSet.write``.
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

@final
class TrainSet:
    """A training set as ``Forest.fit`` takes it and ``isa train`` reads it (.isat). images:
    uint16 (h, w) mm crops; parts (P, 3) int32 [image, u, v]; offsets (P, 3) m; rotations
    (P, 4) (w, x, y, z); link_angles (P, L) rad; node_offsets (P, 3N); metadata: a JSON
    object. Checked when made (errors name the array); the crops and parts are copied, the
    targets referenced."""

    def __new__(
        cls,
        images: list[npt.NDArray[np.uint16]],
        parts: npt.NDArray[np.int32],
        offsets: npt.NDArray[np.float32],
        rotations: npt.NDArray[np.float32],
        link_angles: npt.NDArray[np.float32] | None = None,
        node_offsets: npt.NDArray[np.float32] | None = None,
        metadata: str = "{}",
    ) -> TrainSet: ...
    def __len__(self) -> int:
        """The number of parts."""
    @property
    def n_images(self) -> int:
        """The number of depth crops."""
    def write(self, path: str | os.PathLike[str]) -> None:
        """Writes a training-set file (.isat) for ``isa train``: a versioned, checksummed
        container of NPY arrays (see ``isa_core::trainset_io`` and docs/CLI.md). Atomic
        (temporary file + rename)."""

def read_trainset(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Reads a training-set file: ``images`` (list of uint16 arrays), ``parts``, ``offsets``,
    ``rotations``, ``link_angles`` / ``node_offsets`` (or None), ``metadata`` (str)."""

SHARD_MANIFEST: str

def write_shard_manifest(dir: str | os.PathLike[str], files: list[str]) -> str:
    """Writes ``dir/manifest.json`` for the shards ``files`` (in training order), each read and
    validated; returns the manifest JSON. Atomic."""

@final
class ShardTrainer:
    """A shard folder opened and prepared for fitting single trees of the forest of ``params``
    (keyword arguments as ``Forest``'s); one per cluster worker."""

    def __new__(cls, shards: str | os.PathLike[str], *, n_threads: int | None = None, **params: Any) -> ShardTrainer: ...
    def fit_tree(self, t: int) -> bytes:
        """Tree ``t``'s bytes, for ``Forest.assemble``."""
    @property
    def n_parts(self) -> int: ...

# -- scene detection (isa_core::scene) ---------------------------------------------------------

DETECT_DEFAULTS: dict[str, Any]
"""The core's detection parameters (``isa_core::DetectParams``: nested ``planes``, ``verify``,
``refine``, ``proposals``), which ``isa.detection``'s parameter classes mirror."""
SHAPES_FORMAT_VERSION: int

@final
class ShapeLibrary:
    """A category's shape library: surface samples (S, N, 3) float32 and normals of its training
    shapes (object frame), spacing (S,), bounds (S, 2, 3), names, size range."""
    def __new__(
        cls,
        category: str,
        points: npt.NDArray[np.float32],
        normals: npt.NDArray[np.float32],
        spacing: npt.NDArray[np.float64],
        bounds: npt.NDArray[np.float64],
        names: list[str] = ...,
        size_range: tuple[tuple[float, float], tuple[float, float]] | None = None,
    ) -> ShapeLibrary: ...
    @staticmethod
    def load(path: str | os.PathLike[str]) -> ShapeLibrary:
        """Reads an ``.isl`` file."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes an ``.isl`` file atomically."""
    @property
    def category(self) -> str: ...
    @property
    def names(self) -> list[str]: ...
    @property
    def size_range(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """``((height_min, height_max), (length_min, length_max))`` metres, or None."""
    @property
    def points(self) -> npt.NDArray[np.float32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float32]: ...
    @property
    def spacing(self) -> npt.NDArray[np.float64]: ...
    @property
    def bounds(self) -> npt.NDArray[np.float64]: ...
    def __len__(self) -> int: ...

def detect(
    depth: npt.NDArray[np.float32],
    K: npt.ArrayLike | Any,
    models: list[dict[str, Any]],
    gravity: npt.ArrayLike | None = None,
    planes: dict[str, Any] | None = None,
    params: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Every category model over one frame (``isa_core::scene::detect``): ``depth`` (H, W) float32
    metres; ``models`` dicts ``{"category", "forest", "size", "ssc_offset", "shapes", "size_range",
    "hypotheses", "ranker"}`` (``ranker`` its JSON text or None); ``gravity`` (3, 3) camera -> upright or None; ``planes`` a ``find_planes``
    answer or None; ``params`` a ``DETECT_DEFAULTS``-shaped dict. Returns ``{"detections",
    "gravity", "gravity_source", "floor_height", "planes", "seconds"}``."""

def find_planes(
    depth: npt.NDArray[np.float32],
    K: npt.ArrayLike | Any,
    R_gravity: npt.ArrayLike,
    params: dict[str, Any] | None = None,
    floor: bool = True,
    walls: bool = True,
) -> dict[str, Any]:
    """The floor and walls: ``{"planes": [{"kind", "normal", "offset", "n_inliers"}], "removed":
    (H, W) bool}``."""

def verify_pose(
    depth: npt.NDArray[np.float32],
    K: npt.ArrayLike | Any,
    R: npt.ArrayLike,
    t: npt.ArrayLike,
    points: npt.NDArray[np.float64],
    spacing: float,
    planes: npt.NDArray[np.bool_] | None = None,
    params: dict[str, Any] | None = None,
    n_points: int | None = None,
) -> dict[str, Any]:
    """Verification of shape ``points`` at ``(R, t)``: ``{"score", "agree", "violate",
    "occluded", "missing", "outside", "unexplained"}``."""

RANK_FEATURES: list[str]
"""The features a ranker may use (``isa_core::scene::ranking::FEATURES``), in order."""
RANKER_FORMAT: int
"""The ranker file format this build reads and writes."""

def check_ranker(text: str, source: str) -> str:
    """A ranker's JSON text checked (errors name ``source``), in the core's layout."""

def refine_pose(
    points_up: npt.NDArray[np.float64],
    K: npt.ArrayLike | Any,
    width: int,
    height: int,
    R: npt.ArrayLike,
    t: npt.ArrayLike,
    shape_points: npt.NDArray[np.float64],
    bounds: npt.ArrayLike,
    R_gravity: npt.ArrayLike,
    params: dict[str, Any] | None = None,
    normals: npt.NDArray[np.float64] | None = None,
) -> dict[str, Any]:
    """Upright ICP: ``{"R", "t", "rms", "pairs", "yaw_change", "shift", "converged"}``."""

def nms_across(boxes: npt.NDArray[np.float64], iou: float = 0.25, overlap: float = 0.6) -> list[int]:
    """Greedy NMS across categories over rows ``[cx, cy, cz, sx, sy, sz, yaw, score]``: kept
    indices, best first."""

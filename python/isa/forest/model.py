"""Python face of the Rust ISA forest (paper Section 3.3).

``Forest`` trains the part-based random forest on depth-image parts, saves / loads versioned
model files, pickles, returns the leaf votes of parts and the 6D hypotheses of depth images.
All numerics and every parameter check run in Rust (``isa._core``) with the GIL released; this
module names the parameters.

Data contract (see ``docs/DESIGN.md``): ``images`` is a list of uint16 2D depth crops (mm,
0 = missing, C-contiguous); ``parts`` is (P, 3) int32 ``[image, u, v]`` on pixels with depth;
``offsets`` (P, 3) float32 metres (SSC minus the part's 3D point, camera frame);
``rotations`` (P, 4) float32 unit quaternions (w, x, y, z); ``link_angles`` (P, L) float32
radians and ``node_offsets`` (P, 3N) float32 are privileged: used by the split criterion only,
never stored. Arrays must already have the right dtype and be C-contiguous
(``np.ascontiguousarray(x, dtype=np.float32)``); anything else raises ``InvalidInputError``.

Votes: each leaf stores at most ``leaf_modes`` weighted modes ``(weight, offset (3,),
rotation (4,))``; ``votes(images, parts)`` returns every mode of every (part, tree) as flat
arrays. The SSC hypothesis of a vote is the part's back-projected 3D point plus ``offset``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from isa import _core
from isa.exceptions import InvalidParameterError, InvalidTypeError

QUALITIES = ("Q1", "Q1+Q2", "Q1+Q3", "Q1+Q2+Q3")

#: The core's defaults (``isa_core::ForestParams::default``), the one place they are set.
_D = _core.FOREST_DEFAULTS


@dataclass(frozen=True)
class ForestParams:
    """Hyper-parameters of a forest (all stored in the model file); a mirror of the core's
    ``ForestParams``, whose defaults (``isa._core.FOREST_DEFAULTS``) and checks (names, types,
    ranges, in messages naming the parameter) it uses.

    Attributes:
        n_trees: number of trees.
        max_depth: maximum depth (root = 0). The paper's forests use 20.
        min_samples_split: nodes with fewer parts become leaves.
        min_samples_leaf: each child of a split needs at least this many (scored) parts.
        min_gain: a node whose best total gain is below this becomes a leaf.
        n_candidates: random features ψ = (u, v) tried per node.
        n_thresholds: random thresholds τ per feature, drawn from the node's feature values.
        max_offset: largest feature-offset component, pixel·metres (divided by the part depth in
            metres: 150 reaches 150 px at 1 m, 75 px at 2 m).
        max_score_samples: nodes with more parts score candidates on a random subsample of this
            many (the chosen split is applied to all parts).
        quality: criterion terms summed, one of "Q1", "Q1+Q2", "Q1+Q3", "Q1+Q2+Q3".
        reg: ridge added to each standardised covariance before its log-determinant.
        reduce_dims: principal components kept of the link-angle and node-offset targets in the
            criterion (0 = full dimension).
        bag_fraction: fraction of parts each tree trains on (without replacement).
        leaf_modes: maximum weighted vote modes per leaf.
        leaf_max_points: at most this many of a leaf's parts are clustered into modes.
        vote_bandwidth_offset: mode clustering bandwidth of the SSC offset, metres.
        vote_bandwidth_rotation: mode clustering bandwidth of the rotation, radians.
        seed: seed of every random choice (same seed + data = byte-identical model).
    """

    n_trees: int = _D["n_trees"]
    max_depth: int = _D["max_depth"]
    min_samples_split: int = _D["min_samples_split"]
    min_samples_leaf: int = _D["min_samples_leaf"]
    min_gain: float = _D["min_gain"]
    n_candidates: int = _D["n_candidates"]
    n_thresholds: int = _D["n_thresholds"]
    max_offset: float = _D["max_offset"]
    max_score_samples: int = _D["max_score_samples"]
    quality: str = _D["quality"]
    reg: float = _D["reg"]
    reduce_dims: int = _D["reduce_dims"]
    bag_fraction: float = _D["bag_fraction"]
    leaf_modes: int = _D["leaf_modes"]
    leaf_max_points: int = _D["leaf_max_points"]
    vote_bandwidth_offset: float = _D["vote_bandwidth_offset"]
    vote_bandwidth_rotation: float = _D["vote_bandwidth_rotation"]
    seed: int = _D["seed"]

    def __post_init__(self) -> None:
        # The core checks every field; "q1 + q2" comes back as "Q1+Q2".
        checked = json.loads(_core.Forest(**self._core_kwargs()).params_json)
        object.__setattr__(self, "quality", checked["quality"])

    def _core_kwargs(self) -> dict[str, Any]:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, np.generic):
                d[k] = v.item()
        return d


class Forest:
    """The ISA forest: fit on parts, save / load, pickle, votes of parts.

    Args:
        params: a ``ForestParams``; or pass its fields as keyword arguments.
        n_threads: threads for training and traversal (None = all cores, or RAYON_NUM_THREADS).
            The trained model does not depend on it.
    """

    def __init__(self, params: ForestParams | None = None, *, n_threads: int | None = None, **kwargs: Any) -> None:
        if params is not None and kwargs:
            raise InvalidParameterError("pass either params or keyword hyper-parameters, not both")
        unknown = sorted(set(kwargs) - {f.name for f in fields(ForestParams)})
        if unknown:
            known = ", ".join(f.name for f in fields(ForestParams))
            # TypeError as for any unexpected keyword argument, and an isa error.
            raise InvalidTypeError(f"Forest: unknown parameter(s) {', '.join(unknown)} (known: {known})")
        self.params = params if params is not None else ForestParams(**kwargs)
        self._core = _core.Forest(n_threads=n_threads, **self.params._core_kwargs())

    # -- training ----------------------------------------------------------------------------
    def fit(
        self,
        images: list[np.ndarray],
        parts: np.ndarray,
        offsets: np.ndarray,
        rotations: np.ndarray,
        link_angles: np.ndarray | None = None,
        node_offsets: np.ndarray | None = None,
        metadata: dict[str, Any] | str | None = None,
        progress: bool = False,
        predict_defaults: dict[str, Any] | None = None,
    ) -> Forest:
        """Trains on parts (see the module docstring for the arrays) and returns ``self``.

        ``metadata`` (a JSON-serialisable dict or a JSON object string) goes into the model file:
        ``category``, ``centre`` (the object-frame origin), ``box`` (the category box) are typed
        fields, any other key is kept as given, and training adds ``training`` (counts of the
        data). ``predict_defaults`` (flat keys of ``isa._core.PREDICT_DEFAULTS``; or the same key
        inside ``metadata``) become the model's inference defaults, which :meth:`predict` starts
        from. ``progress`` shows a bar that advances per tree.
        """
        meta = _metadata_json(metadata)
        with tqdm(total=self.params.n_trees, desc="train", unit="tree", disable=not progress, leave=False) as bar:
            self._core.fit(_core.TrainSet(list(images), parts, offsets, rotations, link_angles, node_offsets), meta,
                           on_tree=(lambda done: bar.update(done - bar.n)) if progress else None,
                           predict_defaults=predict_defaults)
        return self

    def fit_shards(self, shards: str | os.PathLike[str], metadata: dict[str, Any] | str | None = None,
                   progress: bool = False, predict_defaults: dict[str, Any] | None = None) -> Forest:
        """Trains from a shard folder (:mod:`isa.forest.shards`) and returns ``self``: the model
        :meth:`fit` makes from the shards' arrays concatenated, to the byte, holding in memory
        only what the trees read (docs/cluster.md). Other arguments as :meth:`fit`'s."""
        meta = _metadata_json(metadata)
        with tqdm(total=self.params.n_trees, desc="train", unit="tree", disable=not progress, leave=False) as bar:
            self._core.fit_shards(os.fspath(shards), meta,
                                  on_tree=(lambda done: bar.update(done - bar.n)) if progress else None,
                                  predict_defaults=predict_defaults)
        return self

    def assemble(self, trees: list[bytes], shards: str | os.PathLike[str], metadata: dict[str, Any] | str | None = None,
                 predict_defaults: dict[str, Any] | None = None) -> Forest:
        """This forest from its trees fitted apart (``isa._core.ShardTrainer.fit_tree(t)`` for
        every ``t``, in order) on ``shards``: the model :meth:`fit_shards` makes. Returns ``self``."""
        self._core.assemble(list(trees), os.fspath(shards), _metadata_json(metadata), predict_defaults=predict_defaults)
        return self

    # -- files -------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes the model file atomically (temporary file + rename)."""
        self._core.save(os.fspath(path))

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, n_threads: int | None = None) -> Forest:
        """Reads a model file (``ModelFormatError`` if it is not a valid isa model)."""
        return cls._wrap(_core.Forest.load(os.fspath(path), n_threads=n_threads))

    def to_bytes(self) -> bytes:
        """The model-file bytes."""
        return self._core.to_bytes()

    @classmethod
    def from_bytes(cls, data: bytes) -> Forest:
        """Parses model-file bytes."""
        return cls._wrap(_core.Forest.from_bytes(bytes(data)))

    @classmethod
    def _wrap(cls, core: _core.Forest) -> Forest:
        self = cls.__new__(cls)
        self.params = ForestParams(**json.loads(core.params_json))
        self._core = core
        return self

    # -- inference ---------------------------------------------------------------------------
    def apply(self, images: list[np.ndarray], parts: np.ndarray) -> np.ndarray:
        """Leaf index of every part in every tree, (P, n_trees) int32."""
        return self._core.apply(list(images), parts)

    def votes(self, images: list[np.ndarray], parts: np.ndarray) -> dict[str, np.ndarray]:
        """Every leaf vote of every part through every tree.

        Returns flat arrays over the V votes: ``part`` (V,) int32, ``tree`` (V,) int32,
        ``weight`` (V,) float32 (the mode's share of its leaf), ``offset`` (V, 3) float32 metres,
        ``rotation`` (V, 4) float32 (w, x, y, z), ordered by part, tree, decreasing weight.
        """
        return self._core.votes(list(images), parts)

    def leaf_votes(self, tree: int, leaf: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(weights (k,), offsets (k, 3), rotations (k, 4)) of one leaf."""
        return self._core.leaf_votes(tree, leaf)

    def with_leaf_weights(self, weights: Sequence[np.ndarray] | None) -> Forest:
        """This forest with per-leaf vote weights: ``weights[t][l]`` in [0, 1] multiplies every
        vote of leaf ``l`` of tree ``t`` in :meth:`predict` (how likely a part reaching that leaf
        lies on the category, :mod:`isa.detection.background`), one array of ``n_leaves[t]`` per
        tree; None: one-class, every vote counts fully. Saved in the model file (format version
        3). A new forest; this one is unchanged."""
        rows = None if weights is None else [np.ascontiguousarray(w, dtype=np.float32) for w in weights]
        return self._wrap(self._core.with_leaf_weights(rows))

    @property
    def leaf_weights(self) -> list[np.ndarray] | None:
        """The per-leaf vote weights (one array per tree), or None (see :meth:`with_leaf_weights`)."""
        return self._core.leaf_weights

    # -- inference ---------------------------------------------------------------------------
    def predict(self, depth: np.ndarray, intrinsics: Any, **params: Any) -> list[_core.Hypothesis]:
        """Ranked 6D hypotheses of the objects in a whole depth image (paper Eq. 12-13).

        ``depth``: (H, W) uint16 millimetres or float metres (0 = missing), or an organised point
        cloud (H, W, 3) in the camera frame (an unorganised one: :func:`isa.camera.depth_from_points`);
        ``depth_scale=`` millimetres per stored unit when the values are in another unit (TUM's
        5000 per metre: 0.2; float millimetres: 1; see ``isa_core::params::DepthParams``).
        ``intrinsics``: an ``isa.camera.Intrinsics`` (its image size is checked against the
        depth's: a transposed image is an error), a 3x3 matrix or (fx, fy, cx, cy). A median depth
        implausible for a depth sensor (outside 0.15-10 m after scaling) or an image that looks
        transposed against the principal point raises :class:`isa.InputWarning`. Inference parameters not given
        come from the model's :attr:`predict_defaults` (size-aware ones the pipeline stores; the
        core's ``isa._core.PREDICT_DEFAULTS`` otherwise). Each :class:`isa._core.Hypothesis`:
        ``R`` (3, 3), ``t`` (3,) metres (the object-frame origin, SSC or centre of mass, in the
        camera frame), ``pose`` (4, 4) the two as one matrix, ``quaternion``, ``score``, ``support``; also readable as ``h["R"]``."""
        return self._core.predict(depth, intrinsics, **params)

    def image_votes(self, depth: np.ndarray, intrinsics: Any, **params: Any) -> dict[str, Any]:
        """Every vote :meth:`predict` aggregates (for plots; see ``isa._core.image_votes``)."""
        return self._core.image_votes(depth, intrinsics, **params)

    # -- properties --------------------------------------------------------------------------
    @property
    def is_fitted(self) -> bool:
        return self._core.is_fitted

    @property
    def metadata(self) -> dict[str, Any]:
        """The metadata stored with the model (see :meth:`fit`)."""
        return json.loads(self._core.metadata)

    @property
    def predict_defaults(self) -> dict[str, Any]:
        """The model's inference defaults (flat keys), which :meth:`predict` starts from."""
        return self._core.predict_defaults

    @property
    def n_trees(self) -> int:
        return self._core.n_trees

    @property
    def n_threads(self) -> int | None:
        return self._core.n_threads

    @n_threads.setter
    def n_threads(self, n: int | None) -> None:
        self._core.n_threads = n

    @property
    def n_nodes(self) -> list[int]:
        return self._core.n_nodes

    @property
    def n_leaves(self) -> list[int]:
        return self._core.n_leaves

    @property
    def depths(self) -> list[int]:
        return self._core.depths

    @property
    def core(self) -> _core.Forest:
        """The underlying ``isa._core.Forest``."""
        return self._core

    def __repr__(self) -> str:
        return repr(self._core)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Forest):
            return NotImplemented
        if not (self.is_fitted and other.is_fitted):
            return self.params == other.params and self.is_fitted == other.is_fitted
        return self.to_bytes() == other.to_bytes()

    __hash__ = None  # type: ignore[assignment]


def _metadata_json(metadata: dict[str, Any] | str | None) -> str:
    """JSON object text of ``metadata``; NaN and infinities become null (JSON has no such
    numbers, and ``np.asarray(..., dtype=float)`` reads null back as NaN)."""
    if metadata is None:
        return "{}"
    if isinstance(metadata, str):
        try:
            metadata = json.loads(metadata)
        except ValueError as e:
            raise InvalidParameterError(f"metadata: not a JSON string ({e})") from None
    try:
        return json.dumps(_finite(json.loads(json.dumps(metadata, default=_json_default))), sort_keys=True,
                          allow_nan=False)
    except TypeError as e:
        raise InvalidParameterError(f"metadata: not JSON-serialisable ({e})") from None


def _finite(o: Any) -> Any:
    if isinstance(o, float) and not np.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, list):
        return [_finite(v) for v in o]
    return o


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON-serialisable")


sample_parts = _core.sample_parts
depth_features = _core.depth_features

__all__ = ["QUALITIES", "Forest", "ForestParams", "depth_features", "sample_parts"]

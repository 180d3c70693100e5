"""Background parts (Hough-forest style): how likely a part reaching a leaf is on the object.

The one-class forest learned from object parts only, so in a room every floor, wall and
cupboard part votes as if it were on the object. Passing parts of rooms down the trees
(:meth:`isa.forest.model.Forest.apply`), some on the category's instances (positives) and the rest
on floors, walls, clutter and other categories (negatives), gives each leaf the share of
positives that reach it; with the classes weighted equally,
``p(object | leaf) = (a / A) / (a / A + b / B)`` (``a``, ``b`` the leaf's positive and negative
counts, ``A``, ``B`` the totals), smoothed towards 0.5 by ``prior`` pseudo-counts. Each vote is
weighted by its leaf's probability before the modes are found (:func:`isa._core.find_modes`), so
leaves that floors and walls reach stop piling up hypotheses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from isa.camera import Intrinsics
from isa.detection.shapes import load_npz, save_npz
from isa.exceptions import DataError, InvalidValueError

__all__ = ["LeafForeground", "fit_leaf_foreground", "depth_mm", "weighted_predict"]


@dataclass(frozen=True, eq=False)
class LeafForeground:
    """Per tree, ``p(object | leaf)`` indexed by the leaf ids :meth:`isa.forest.model.Forest.apply`
    gives (``probs`` (T, max_nodes) float32, 0.5 where no training part arrived), and the part
    counts it came from."""

    category: str
    probs: np.ndarray
    n_positive: int
    n_negative: int

    def of(self, leaves: np.ndarray) -> np.ndarray:
        """Probabilities (P, T) of the leaf ids (P, T)."""
        T = self.probs.shape[0]
        return self.probs[np.arange(T)[None, :], leaves]

    def save(self, path: str | Path) -> None:
        save_npz(path, category=self.category, probs=self.probs, n_positive=self.n_positive, n_negative=self.n_negative)

    @classmethod
    def load(cls, path: str | Path) -> "LeafForeground":
        z = load_npz(path, "leaf foreground file", ("category", "probs", "n_positive", "n_negative"))
        return cls(str(z["category"]), z["probs"], int(z["n_positive"]), int(z["n_negative"]))


def depth_mm(depth: np.ndarray) -> np.ndarray:
    """uint16 millimetres (0 = missing) of a float metre depth image (uint16 passes through)."""
    d = np.asarray(depth)
    if d.dtype == np.uint16:
        return np.ascontiguousarray(d)
    return np.ascontiguousarray(np.clip(np.round(np.nan_to_num(d) * 1000.0), 0, 65535).astype(np.uint16))


def fit_leaf_foreground(forest, images: Sequence[np.ndarray], parts: np.ndarray, positive: np.ndarray,
                        prior: float = 1.0, category: str = "") -> LeafForeground:
    """Leaf probabilities from parts ``(P, 3)`` [image, u, v] of uint16 ``images`` labelled
    ``positive`` (P,) bool (on an instance of the category or not)."""
    positive = np.asarray(positive, dtype=bool).reshape(-1)
    if len(positive) != len(parts):
        raise InvalidValueError(f"fit_leaf_foreground: {len(parts)} parts but {len(positive)} labels")
    A, B = int(positive.sum()), int((~positive).sum())
    if A == 0 or B == 0:
        raise DataError(f"fit_leaf_foreground({category!r}): needs positive and negative parts, got {A} and {B}")
    leaves = forest.apply(list(images), np.ascontiguousarray(parts, dtype=np.int32))
    n_nodes = max(forest.n_nodes)
    T = leaves.shape[1]
    probs = np.empty((T, n_nodes), dtype=np.float32)
    for k in range(T):
        a = np.bincount(leaves[positive, k], minlength=n_nodes) / A
        b = np.bincount(leaves[~positive, k], minlength=n_nodes) / B
        # prior pseudo-parts of each class (in units of one average part of that class)
        probs[k] = (a + prior / A) / (a + b + prior / A + prior / B)
    return LeafForeground(category, probs, A, B)


def weighted_predict(forest, fg: LeafForeground | None, depth: np.ndarray, intrinsics: Intrinsics, stride: int = 4,
                     power: float = 1.0, **params) -> list[dict]:
    """:meth:`isa.forest.model.Forest.predict` with every vote weighted by ``p(object | leaf) ** power``
    (``fg`` None: the plain votes, through the same path). ``params``: the mode-finding keywords
    of :func:`isa._core.find_modes` (default: the model's ``predict_defaults``)."""
    from isa import _core

    img = depth_mm(depth)
    parts = _core.sample_parts([img], stride=stride)
    if len(parts) == 0:
        return []
    v = forest.votes([img], parts)
    z = img[parts[:, 2], parts[:, 1]].astype(np.float64) / 1000.0
    pts = np.column_stack([(parts[:, 1] - intrinsics.cx) * z / intrinsics.fx,
                           (parts[:, 2] - intrinsics.cy) * z / intrinsics.fy, z])
    pos = (pts[v["part"]] + v["offset"]).astype(np.float32)
    w = v["weight"].astype(np.float64) / forest.n_trees
    if fg is not None:
        leaves = forest.apply([img], parts)
        w = w * fg.probs[v["tree"], leaves[v["part"], v["tree"]]] ** power
    kw = {**forest.predict_defaults, **params}
    for k in ("stride", "min_depth", "max_depth", "min_leaf_weight"):
        kw.pop(k, None)
    return _core.find_modes(np.ascontiguousarray(pos), np.ascontiguousarray(v["rotation"]),
                            np.ascontiguousarray(w, dtype=np.float32), **kw)

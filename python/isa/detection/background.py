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

Where the labelled parts come from (:func:`context_foreground`, ``python -m isa.detection.background``):
views of the training instances standing in rooms (:mod:`isa.scenes.context`: other
categories beside them, clutter, Kinect noise, floor and walls removed as detection removes
them), drawn with a seed other than the training views'; every valid pixel on the part grid
is a part, positive on the instance's visible mask.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from isa.camera import Intrinsics
from isa.detection.shapes import load_npz, save_npz
from isa.exceptions import DataError, InvalidValueError

__all__ = ["LeafForeground", "fit_leaf_foreground", "labelled_parts", "context_foreground", "depth_mm",
           "weighted_predict"]  # main: the module's command line, not a package name


@dataclass(frozen=True, eq=False)
class LeafForeground:
    """Per tree, ``p(object | leaf)`` indexed by the leaf ids :meth:`isa.forest.model.Forest.apply`
    gives (``probs`` (T, max_nodes) float32, 0.5 where no training part arrived), and the part
    counts it came from."""

    category: str
    probs: np.ndarray
    n_positive: int
    n_negative: int

    def leaf_weights(self, forest) -> list[np.ndarray]:
        """The probabilities as :meth:`isa.forest.model.Forest.with_leaf_weights` takes them (one
        array of each tree's leaves)."""
        if len(forest.n_leaves) != self.probs.shape[0] or max(forest.n_leaves) > self.probs.shape[1]:
            raise InvalidValueError(f"{self.category} leaf foreground: {self.probs.shape[0]} trees of "
                                    f"{self.probs.shape[1]} leaves do not fit a forest of {len(forest.n_leaves)} trees "
                                    f"with up to {max(forest.n_leaves)} leaves")
        return [self.probs[t, :n] for t, n in enumerate(forest.n_leaves)]

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
    in NumPy, from the votes of every part (the reference the core's leaf weights are tested
    against): ``fg``'s probabilities, else the forest's own leaf weights, else the plain votes
    through the same path. ``params``: the mode-finding keywords of :func:`isa._core.find_modes`
    (default: the model's inference defaults, ``Forest.predict_defaults``)."""
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
    weights = fg.leaf_weights(forest) if fg is not None else forest.leaf_weights
    if weights is not None:
        table = np.zeros((len(weights), max(len(t) for t in weights)))
        for t, row in enumerate(weights):
            table[t, :len(row)] = row
        leaves = forest.apply([img], parts)
        w = w * table[v["tree"], leaves[v["part"], v["tree"]]] ** power
    kw = {**forest.predict_defaults, **params}
    for k in ("stride", "min_depth", "max_depth", "min_leaf_weight"):
        kw.pop(k, None)
    return _core.find_modes(np.ascontiguousarray(pos), np.ascontiguousarray(v["rotation"]),
                            np.ascontiguousarray(w, dtype=np.float32), **kw)


def labelled_parts(frames, stride: int = 8) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """uint16 images, parts ``(P, 3)`` [image, u, v] on every valid pixel of the ``stride`` grid
    (as detection samples them, :func:`isa._core.sample_parts`) and whether each is on the
    frame's mask, from BOP frames (depth in metres, mask)."""
    from isa import _core

    images, parts, positive = [], [], []
    for f in frames:
        img = depth_mm(f.depth)
        p = np.asarray(_core.sample_parts([img], stride=stride))
        if len(p) == 0:
            continue
        p[:, 0] = len(images)
        images.append(img)
        parts.append(p)
        positive.append(np.asarray(f.mask, bool)[p[:, 2], p[:, 1]])
    if not parts:
        raise DataError("labelled_parts: no valid pixels in the frames")
    return images, np.concatenate(parts).astype(np.int32), np.concatenate(positive)


def context_foreground(forest, objects, category: str, views: int, out_dir: str | Path, seed: int = 1,
                       stride: int = 8, prior: float = 1.0, progress: bool = True) -> LeafForeground:
    """Leaf probabilities of ``forest`` from ``views`` in-context views of each of ``objects``
    (prepared training instances, :func:`isa.scenes.context.render_context_dataset`, rendered into
    ``out_dir``; resumable), drawn from ``seed``."""
    from isa.data import bop
    from isa.scenes.context import render_context_dataset

    render_context_dataset(out_dir, objects, category, views, seed=seed, progress=progress)
    images, parts, positive = labelled_parts(bop.FrameSequence(out_dir, "train"), stride)
    return fit_leaf_foreground(forest, images, parts, positive, prior=prior, category=category)


def main(argv: list[str] | None = None) -> None:
    """``python -m isa.detection.background MESHES --category C --model C.isa -o C-bg.isa``:
    leaf probabilities from in-context views of the model's training instances (the same
    ``MESHES`` / ``--instances`` / ``--seed`` as ``python -m isa train``)."""
    import argparse

    from isa import pipeline
    from isa.exceptions import IsaError
    from isa.forest.build import training_objects
    from isa.forest.model import Forest

    ap = argparse.ArgumentParser(prog="python -m isa.detection.background", description=main.__doc__.split("\n")[0])
    ap.add_argument("meshes", nargs="+", help="the model's training meshes (files, folders, globs or a ModelNet10 root)")
    ap.add_argument("--category", required=True)
    ap.add_argument("--model", required=True, type=Path)
    ap.add_argument("--instances", type=int, help="first N instances (ModelNet: default the paper's count)")
    ap.add_argument("--views", type=int, default=20, help="in-context views per instance")
    ap.add_argument("--stride", type=int, default=8, help="part grid (pixels), as at detection")
    ap.add_argument("--prior", type=float, default=1.0, help="pseudo-parts of each class per leaf")
    ap.add_argument("--training-seed", type=int, default=0, help="the seed the instances were sized with")
    ap.add_argument("--seed", type=int, default=1, help="the rooms' seed (not the training views')")
    ap.add_argument("--renders", type=Path, required=True, help="folder for the rendered views (resumable)")
    ap.add_argument("-o", "--out", required=True, type=Path,
                    help="C.isa: the model with these leaf weights (model format 3); "
                         "C.foreground.npz: the probabilities alone (load_model's foreground=)")
    a = ap.parse_args(argv)
    try:
        if not a.model.is_file():
            raise DataError(f"--model: {a.model} not found")
        forest = Forest.load(a.model)
        objs = training_objects(a.meshes, a.category, instances=a.instances, seed=a.training_seed)
        prepared = pipeline.prepare_category(a.category, objs, centre=forest.metadata.get("centre"))
        fg = context_foreground(forest, prepared.objects, a.category, a.views, a.renders, seed=a.seed,
                                stride=a.stride, prior=a.prior)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        if a.out.suffix == ".isa":
            forest.with_leaf_weights(fg.leaf_weights(forest)).save(a.out)
        else:
            fg.save(a.out)
    except IsaError as exc:
        ap.exit(2, f"error: {exc}\n")
    print(f"{a.out}: {fg.n_positive} parts on {a.category} instances, {fg.n_negative} off")


if __name__ == "__main__":
    main()

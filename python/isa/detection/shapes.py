"""A category's shape library: surface samples of its training meshes in the object frame.

Verification and refinement compare the observed depth with the category's own training shapes
at a hypothesis' pose, and the best-fitting shape gives the object's size (a 9D pose). The
library is small (a few thousand points per shape) and saved beside the model as ``.isl`` (the
core's versioned, checksummed format, which ``isa detect`` reads; ``isa_core::scene::shapes``)
or ``.npz`` (older files).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from isa import atomic
from isa.exceptions import DataError

__all__ = ["ShapeLibrary", "shape_library", "bop_shape_library"]

#: Surface samples per shape: enough for a dense z-buffer of a 1 m object at 1.5 m in 4 px cells.
N_POINTS = 3000


@dataclass(frozen=True, eq=False)
class ShapeLibrary:
    """``points`` (S, N, 3) float32 surface samples per shape (object frame, metres, the category's
    origin at 0); ``spacing`` (S,) their mean spacing (sqrt(area / N), metres); ``bounds`` (S, 2, 3)
    each shape's axis-aligned bounds; ``names`` where each shape came from; ``size_range``
    ``((height_min, height_max), (length_min, length_max))`` metres, the sizes the size fit may
    reach (default: the category's :data:`isa.categories.SIZES`, None for an unknown one)."""

    category: str
    points: np.ndarray
    normals: np.ndarray
    spacing: np.ndarray
    bounds: np.ndarray
    names: tuple[str, ...] = ()
    size_range: tuple[tuple[float, float], tuple[float, float]] | None = None

    def __post_init__(self) -> None:
        p = np.ascontiguousarray(self.points, dtype=np.float32)
        if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] == 0:
            raise DataError(f"ShapeLibrary({self.category!r}): points must be (S, N, 3), got {p.shape}")
        n = np.ascontiguousarray(self.normals, dtype=np.float32)
        if n.shape != p.shape:
            raise DataError(f"ShapeLibrary({self.category!r}): normals {n.shape} do not match points {p.shape}")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "normals", n)
        object.__setattr__(self, "spacing", np.asarray(self.spacing, dtype=float).reshape(len(p)))
        object.__setattr__(self, "bounds", np.asarray(self.bounds, dtype=float).reshape(len(p), 2, 3))
        object.__setattr__(self, "names", tuple(self.names))
        if self.size_range is None:
            from isa.categories import SIZES

            r = SIZES.get(self.category)
            object.__setattr__(self, "size_range", None if r is None else (tuple(r.height), tuple(r.length)))
        else:
            h, length = self.size_range
            object.__setattr__(self, "size_range", ((float(h[0]), float(h[1])), (float(length[0]), float(length[1]))))

    def __len__(self) -> int:
        return len(self.points)

    @property
    def sizes(self) -> np.ndarray:
        """(S, 3) full extents of each shape along the object's x, y, z."""
        return self.bounds[:, 1] - self.bounds[:, 0]

    @property
    def centres(self) -> np.ndarray:
        """(S, 3) each shape's box centre in the object frame."""
        return self.bounds.mean(1)

    @property
    def core(self):
        """The library as an ``isa._core.ShapeLibrary`` (made once), for the core's detector."""
        c = self.__dict__.get("_core")
        if c is None:
            from isa import _core

            c = _core.ShapeLibrary(self.category, self.points, self.normals, np.ascontiguousarray(self.spacing),
                                   np.ascontiguousarray(self.bounds), list(self.names), self.size_range)
            object.__setattr__(self, "_core", c)
        return c

    def save(self, path: str | Path) -> None:
        """``.isl`` (the core's format) or ``.npz``, by the file's suffix; written atomically."""
        path = Path(path)
        if path.suffix == ".isl":
            self.core.save(path)
            return
        extra = {} if self.size_range is None else {"size_range": np.asarray(self.size_range, dtype=float)}
        save_npz(path, category=self.category, points=self.points, normals=self.normals, spacing=self.spacing,
                 bounds=self.bounds, names=np.array(self.names, dtype=str), **extra)

    @classmethod
    def load(cls, path: str | Path) -> "ShapeLibrary":
        """A library from an ``.isl`` or ``.npz`` file (by its first bytes)."""
        path = Path(path)
        if path.is_file() and _magic(path) == b"ISASHAPE":
            from isa import _core

            try:
                c = _core.ShapeLibrary.load(path)
            except ValueError as exc:
                raise DataError(f"{path}: not a shape library ({exc})") from None
            return cls(c.category, c.points, c.normals, c.spacing, c.bounds, tuple(c.names), c.size_range)
        z = load_npz(path, "shape library", ("category", "points", "normals", "spacing", "bounds", "names"))
        size_range = None
        with np.load(path) as raw:
            if "size_range" in raw:
                size_range = tuple(map(tuple, raw["size_range"].tolist()))
        return cls(str(z["category"]), z["points"], z["normals"], z["spacing"], z["bounds"], tuple(z["names"].tolist()),
                   size_range)


def _magic(path: Path) -> bytes:
    with open(path, "rb") as f:
        return f.read(8)


def save_npz(path: str | Path, **arrays) -> None:
    """``np.savez_compressed`` written atomically (:mod:`isa.atomic`)."""
    # The temporary name keeps ``.npz``, so NumPy does not append one.
    atomic.write_with(path, lambda tmp: np.savez_compressed(tmp, **arrays))


def load_npz(path: str | Path, what: str, keys: Sequence[str]) -> dict:
    """The arrays ``keys`` of an ``.npz`` file; :class:`DataError` naming the file and ``what`` it
    should be when it is missing, unreadable or lacks a key."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: {what} not found")
    try:
        with np.load(path) as z:
            return {k: z[k] for k in keys}
    except (KeyError, ValueError, OSError) as exc:
        raise DataError(f"{path}: not a {what} ({exc})") from None


def shape_library(category: str, meshes: Sequence, names: Sequence[str] | None = None, n_points: int = N_POINTS,
                  seed: int = 0) -> ShapeLibrary:
    """Surface samples of ``meshes`` (``trimesh.Trimesh`` or objects with a ``.mesh``, already in the
    category's object frame, e.g. :class:`isa.pipeline.PreparedCategory` ``.objects``)."""
    import trimesh

    meshes = [getattr(m, "mesh", m) for m in meshes]
    if not meshes:
        raise DataError(f"shape_library({category!r}): no meshes")
    pts, nrm, spacing, bounds = [], [], [], []
    for i, m in enumerate(meshes):
        p, face = trimesh.sample.sample_surface(m, n_points, seed=seed + i)
        pts.append(np.asarray(p, dtype=np.float32))
        nrm.append(np.asarray(m.face_normals[face], dtype=np.float32))
        spacing.append(float(np.sqrt(m.area / n_points)))
        bounds.append(np.asarray(m.bounds, dtype=float))
    return ShapeLibrary(category, np.stack(pts), np.stack(nrm), spacing, np.stack(bounds),
                        tuple(names) if names is not None else tuple(str(i) for i in range(len(meshes))))


def bop_shape_library(root: str | Path, category: str, split: str = "train", n_points: int = N_POINTS,
                      seed: int = 0) -> ShapeLibrary:
    """The shape library of the objects a BOP split shows (the training renders of
    :func:`isa.render.dataset.render_dataset` / ``python -m isa experiment``: their
    ``models/obj_*.ply`` are already in the category's object frame)."""
    from isa.data import bop

    ids = sorted(set(bop.FrameSequence(root, split).obj_ids))
    if not ids:
        raise DataError(f"{root}/{split}: no frames, so no training shapes")
    return shape_library(category, [bop.read_model(root, k) for k in ids], names=[f"obj_{k:06d}" for k in ids],
                         n_points=n_points, seed=seed)

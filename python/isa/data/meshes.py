"""Mesh loading (through trimesh), rescaling to real-world size, and the object-frame origin.

Object frame (see docs/DESIGN.md): metres, z up, the category's front facing -y (ModelNet10's
manual alignment: chair backs, bed headboards and toilet tanks sit at +y), origin at
:func:`object_origin`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from isa.categories import size_range
from isa.exceptions import DataError, DataNotFoundError

__all__ = ["MESH_EXTENSIONS", "load_mesh", "object_origin", "real_size_scale", "rescale_to_real_size", "to_object_frame", "prepare_mesh"]

#: File extensions accepted by :func:`load_mesh` (lower case, with the dot).
MESH_EXTENSIONS: tuple[str, ...] = (".off", ".obj", ".ply", ".stl", ".glb")


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load one triangle mesh from an OFF, OBJ, PLY, STL or GLB file.

    Scenes (GLB, multi-object OBJ) are flattened into one mesh with their transforms applied.
    Raises ``DataError`` naming ``path`` when the file is missing, has an unsupported extension,
    cannot be parsed, has no triangles or has non-finite vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"mesh file not found: {path}")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise DataError(f"mesh file {path}: unsupported extension {ext!r}; expected one of {', '.join(MESH_EXTENSIONS)}")
    if path.stat().st_size == 0:
        raise DataError(f"mesh file {path} is empty (0 bytes)")
    try:
        # process=False keeps the file's vertices and faces as they are (no merging/reordering),
        # so what we render is exactly what is on disk.
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types (ValueError, KeyError, IndexError, ...)
        raise DataError(f"mesh file {path} is corrupt or unreadable: {type(exc).__name__}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise DataError(f"mesh file {path} holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise DataError(f"mesh file {path} has non-finite (NaN/inf) vertex coordinates")
    if mesh.faces.max() >= len(mesh.vertices) or mesh.faces.min() < 0:
        raise DataError(f"mesh file {path} has face indices outside its {len(mesh.vertices)} vertices")
    return mesh


def object_origin(mesh: trimesh.Trimesh) -> np.ndarray:
    """The object-frame origin of ``mesh`` in its own coordinates: the axis-aligned bounding-box centre.

    This is the single place that defines the origin; ``isa.privileged.ssc`` replaces it with the
    Semantically Selected Center.
    """
    lo, hi = mesh.bounds
    return (lo + hi) / 2.0


def real_size_scale(extents, category: str, seed: int | np.random.Generator | None = 0) -> float:
    """A uniform scale factor that gives a mesh with ``extents`` (x, y, z) a real size of ``category``.

    The scale is drawn log-uniformly from the scales for which both the height (z) and the larger
    horizontal extent fall in the category's :data:`isa.categories.SIZES` range. When no scale
    satisfies both (an unusual instance, e.g. a backless stool among chairs) the geometric mean
    of the two ranges' closest ends is used, so the object is as plausible as it can be.
    """
    ext = np.asarray(extents, dtype=float).reshape(3)
    if not np.all(np.isfinite(ext)) or ext[2] <= 0 or max(ext[0], ext[1]) <= 0:
        raise DataError(f"cannot rescale a degenerate mesh with extents {ext.tolist()} to a real {category}")
    rng = np.random.default_rng(seed)
    sr = size_range(category)
    length = max(ext[0], ext[1])
    lo_h, hi_h = sr.height[0] / ext[2], sr.height[1] / ext[2]
    lo_l, hi_l = sr.length[0] / length, sr.length[1] / length
    lo, hi = max(lo_h, lo_l), min(hi_h, hi_l)
    if lo <= hi:
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    # Disjoint ranges: meet in the middle of the gap between them.
    return float(np.sqrt(min(hi_h, hi_l) * max(lo_h, lo_l)))


def rescale_to_real_size(
    mesh: trimesh.Trimesh, category: str, seed: int | np.random.Generator | None = 0
) -> tuple[trimesh.Trimesh, float]:
    """Copy of ``mesh`` scaled about the origin to a real size (see :func:`real_size_scale`), and the scale."""
    s = real_size_scale(mesh.extents, category, seed)
    out = mesh.copy()
    out.apply_scale(s)
    return out, s


def to_object_frame(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of ``mesh`` translated so that :func:`object_origin` is at (0, 0, 0)."""
    out = mesh.copy()
    out.apply_translation(-object_origin(mesh))
    return out


def prepare_mesh(
    source: str | Path | trimesh.Trimesh, category: str, seed: int | np.random.Generator | None = 0
) -> tuple[trimesh.Trimesh, float]:
    """Load (if a path), rescale to a real ``category`` size and move into the object frame.

    Returns the mesh in metres in the object frame and the scale applied to the file's units.
    """
    mesh = load_mesh(source) if isinstance(source, (str, Path)) else source
    scaled, s = rescale_to_real_size(mesh, category, seed)
    return to_object_frame(scaled), s

"""A category's 3D box (size and SSC position) learned from its training instances and stored in
a model's metadata."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from isa.exceptions import DataError, InvalidValueError

__all__ = ["CategoryBox", "category_box", "box_metadata", "model_box"]


@dataclass(frozen=True, eq=False)
class CategoryBox:
    """A category's 3D box in its object frame (metres, z up, front -y, origin at the SSC).

    ``size`` (3,): full extents along the object's x, y, z; ``ssc_offset`` (3,): the SSC's position
    relative to the box centre (so the box centre is at ``-ssc_offset`` in the object frame);
    ``n_instances``: how many training meshes it was learned from.
    """

    category: str
    size: np.ndarray
    ssc_offset: np.ndarray
    n_instances: int = 0

    def __post_init__(self) -> None:
        size = np.asarray(self.size, dtype=float).reshape(-1)
        off = np.asarray(self.ssc_offset, dtype=float).reshape(-1)
        if size.shape != (3,) or off.shape != (3,) or not (np.all(np.isfinite(size)) and np.all(np.isfinite(off))):
            raise InvalidValueError(f"CategoryBox({self.category!r}): size and ssc_offset need 3 finite values, got {size}, {off}")
        if np.any(size <= 0):
            raise InvalidValueError(f"CategoryBox({self.category!r}): sizes must be positive, got {size}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "ssc_offset", off)

    def to_dict(self) -> dict:
        return {"category": self.category, "size": self.size.tolist(), "ssc_offset": self.ssc_offset.tolist(),
                "n_instances": int(self.n_instances)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], category: str | None = None) -> "CategoryBox":
        try:
            return cls(d.get("category", category), d["size"], d["ssc_offset"], int(d.get("n_instances", 0)))
        except (KeyError, TypeError, AttributeError) as exc:
            raise DataError(f"category box: needs 'size' and 'ssc_offset', got {d!r} ({exc})") from None


def category_box(objects, category: str | None = None) -> CategoryBox:
    """The category's box from its training instances: the median over instances of each mesh's
    axis-aligned extents and of its SSC's position relative to the mesh's box centre.

    ``objects``: a :class:`isa.pipeline.PreparedCategory` (meshes already SSC-centred), or a
    sequence of :class:`isa.render.dataset.ObjectSpec` or ``trimesh.Trimesh`` in SSC-centred object
    frames. The median (not the mean) so one odd instance (a bunk bed) does not stretch the box.
    """
    if hasattr(objects, "objects") and hasattr(objects, "category"):
        category = category or objects.category
        objects = objects.objects
    meshes = [getattr(o, "mesh", o) for o in objects]
    if not meshes:
        raise DataError(f"category_box({category!r}): no training instances")
    if category is None:
        category = getattr(objects[0], "category", None)
    if category is None:
        raise InvalidValueError("category_box: pass category= when giving bare meshes")
    bounds = np.array([np.asarray(m.bounds, dtype=float) for m in meshes])  # (n, 2, 3)
    size = np.median(bounds[:, 1] - bounds[:, 0], axis=0)
    offset = np.median(-(bounds[:, 0] + bounds[:, 1]) / 2, axis=0)  # SSC (origin) minus box centre
    return CategoryBox(category, size, offset, len(meshes))


def box_metadata(box: CategoryBox) -> dict:
    """``{"box": ...}`` to merge into a model's metadata (``train_forest(..., metadata=...)``)."""
    return {"box": box.to_dict()}


def model_box(forest_or_metadata, source: str = "model") -> CategoryBox:
    """The :class:`CategoryBox` stored in a model's metadata (``metadata["box"]``).

    Raises :class:`DataError` naming ``source`` when the model has none (models trained before the
    box was stored: pass the box explicitly, e.g. ``category_box(prepared)``).
    """
    meta = getattr(forest_or_metadata, "metadata", forest_or_metadata)
    if not isinstance(meta, Mapping) or "box" not in meta:
        raise DataError(f"{source}: the model's metadata has no 'box' (category size and SSC offset); "
                        "retrain with metadata=box_metadata(category_box(prepared)) or pass the box explicitly")
    return CategoryBox.from_dict(meta["box"], meta.get("category"))

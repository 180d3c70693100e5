"""Object categories of the paper, their real-world sizes and the paper's training protocol.

ModelNet10 meshes come in arbitrary units, so every instance is rescaled to a real size (see
``isa.data.meshes.rescale_to_real_size``). The ranges below are what a depth camera sees in real rooms;
they are deliberately wide enough to cover a category's sub-types (e.g. coffee and dining tables)
and are taken from furniture and sanitary-ware standards and the ergonomics literature:

[PZ]   J. Panero, M. Zelnik, *Human Dimension & Interior Space*, Whitney Library of Design, 1979:
       dining chair seat height 40.6-43.2 cm (16-17 in), overall chair heights ~76-107 cm,
       dining table height 73.7-76.2 cm (29-30 in), coffee table height 38-46 cm.
[EN1335] EN 1335-1:2000, Office furniture - Office work chair - Dimensions: seat height
       400-510 mm, seat width >= 400 mm, seat depth 380-470 mm.
[EN527] EN 527-1:2011, Office furniture - Work tables and desks - Dimensions: fixed-height desks
       740 mm (+/- 20 mm), top depth >= 800 mm, width >= 1200 mm for a workplace.
[ISPA] International Sleep Products Association, standard mattress sizes: twin 0.99 x 1.91 m,
       full 1.37 x 1.91 m, queen 1.52 x 2.03 m, king 1.93 x 2.03 m; EU 0.90-1.80 x 2.00 m.
[ADA]  2010 ADA Standards for Accessible Design, section 604.4: toilet seat height 17-19 in
       (432-483 mm); standard residential bowls are 14.5-15.5 in (368-394 mm) to the rim.
[ASME] ASME A112.19.2/CSA B45.1 vitreous china fixtures; typical close-coupled two-piece toilets
       project 0.65-0.80 m from the wall and are 0.70-0.85 m tall to the tank lid.
"""

from __future__ import annotations

from dataclasses import dataclass

from isa.exceptions import DataError

#: The four categories of the paper (Table 1), in the paper's order.
CATEGORIES: tuple[str, ...] = ("bed", "chair", "table", "toilet")

#: Paper protocol (Table 1): number of ModelNet10 train instances per category (first N by name).
PAPER_INSTANCES: dict[str, int] = {"bed": 2, "chair": 28, "table": 8, "toilet": 7}

#: Paper protocol (Table 1): rendered training views per instance.
PAPER_VIEWS: int = 89


@dataclass(frozen=True)
class SizeRange:
    """Real-world extents of a category's objects, metres, in the object frame (z up).

    ``height`` is the z extent (floor to highest point); ``length`` is the larger horizontal
    extent (x or y). ``sources`` are the keys of the references in this module's docstring.
    """

    height: tuple[float, float]
    length: tuple[float, float]
    sources: tuple[str, ...]


#: Real-world size ranges per category (see the module docstring for the sources).
SIZES: dict[str, SizeRange] = {
    # Beds: mattress lengths 1.91-2.03 m plus frame, head- and footboard (up to ~2.4 m); heights from a bare
    # platform (~0.35 m) to a tall headboard (~1.4 m).
    "bed": SizeRange(height=(0.35, 1.40), length=(1.90, 2.40), sources=("ISPA",)),
    # Chairs: seat 0.40-0.51 m, overall 0.75-1.10 m incl. high-backed office chairs; the larger
    # footprint side is 0.42 m (armless dining chair) to 0.75 m (armchair).
    "chair": SizeRange(height=(0.75, 1.10), length=(0.42, 0.75), sources=("PZ", "EN1335")),
    # Tables: coffee tables (0.38-0.46 m) to dining tables and desks (0.72-0.78 m); tops from a
    # 0.45 m side table to a 2.2 m dining table.
    "table": SizeRange(height=(0.38, 0.80), length=(0.45, 2.20), sources=("PZ", "EN527")),
    # Toilets: close-coupled two-piece toilets, rim 0.37-0.48 m, overall 0.65-0.90 m tall,
    # 0.60-0.80 m deep.
    "toilet": SizeRange(height=(0.65, 0.90), length=(0.60, 0.80), sources=("ADA", "ASME")),
}


def check_category(category: str) -> str:
    """Return ``category`` if it is one of :data:`CATEGORIES`, else raise ``DataError`` naming it."""
    if category not in CATEGORIES:
        raise DataError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    return category


def size_range(category: str) -> SizeRange:
    """The real-world :class:`SizeRange` of ``category``."""
    return SIZES[check_category(category)]


#: Object-frame origin per category (:data:`isa.privileged.ssc.CENTRES`): the paper's SSC, or the solid's
#: centre of mass where the forest predicts that better on unseen instances. Chosen on the
#: validation instances (``python -m isa experiment --validation --centre ...``), never on test
#: instances; docs/experiments.md has the numbers.
CENTRE: dict[str, str] = {"bed": "com", "chair": "com", "table": "ssc", "toilet": "com"}

"""Hypotheses from the frame's geometry (``isa_core::scene::proposals``): once the floor and walls
are set aside, the points standing on the floor are binned in a grid over it; connected occupied
cells form a footprint, and each footprint proposes every category's box in the four yaws along
its minimum-area rectangle, reaching away from the camera where the box is longer than what is
seen. A proposal carries the score of its category's best forest hypothesis over the footprint,
and verification decides among them and the forests' own hypotheses."""

from __future__ import annotations

from isa.detection.stage_params import StageParams, core_params

__all__ = ["ProposalParams"]



# The fields are the core's section, one per parameter (stage_params.core_params).
@core_params("proposals")
class ProposalParams(StageParams):
    """``stride`` pixel stride of the points binned; ``cell`` grid side (metres); points between
    ``clearance`` and ``max_height`` above the floor count; a cell with fewer than
    ``min_cell_points`` is empty; a footprint needs ``min_points``; ``max_footprints`` largest
    are used; a forest hypothesis within ``vote_margin`` (metres) of a footprint lends it its
    score, and a footprint none lends one to carries ``unvoted`` times the weakest hypothesis'
    score (0: it proposes nothing for that category); a footprint longer, higher or lower than
    the category's sizes (the size fit's 15% margin, then ``size_slack`` metres) proposes nothing
    for it (None: no check). Defaults: the core's."""


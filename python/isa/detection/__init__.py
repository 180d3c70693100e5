"""3D object detection on real depth frames with category forests (paper Table 2, right).

A category model (an ISA forest trained on synthetic renders only) is run on a real frame
(:class:`isa.data.sunrgbd.SceneFrame`) in four steps:

1. **Planes** (optional, :func:`remove_planes`): the floor and large walls are found in the
   upright frame and their pixels set to missing depth. The forest was trained on isolated objects
   whose background is missing depth, so this makes a room look more like its training data, and
   the floor's height is kept for step 3. The floor is the dominant horizontal layer at the bottom
   of the cloud (gravity gives its normal, so one height is searched, no RANSAC); walls are
   vertical planes found by gravity-constrained RANSAC (two points fix a vertical plane) that are
   both tall and wide, so furniture faces are kept.
2. **Votes**: :func:`isa.pipeline.predict` on the whole (cleaned) depth image gives ranked 6D
   hypotheses ``(R, t)``; ``t`` is the object-frame origin (SSC or centre of mass,
   ``isa.categories.CENTRE``) in the camera frame.
3. **Gravity** (:func:`hypothesis_box`): hypotheses whose object z axis is more than
   ``max_tilt_deg`` from up are rejected (furniture stands upright); the rest are snapped to a yaw
   about gravity; each becomes a gravity-aligned :class:`isa.evaluation.boxes3d.Box3D` of the category's box
   (:class:`CategoryBox`: size and SSC position learned from the training meshes, stored in the
   model's metadata). With a floor found, boxes whose bottom is more than ``floor_gap`` from it are
   rejected and the rest are set down on it (``rest_on_floor``): all four categories stand on the
   floor.
4. **NMS**: greedy 3D non-maximum suppression at IoU 0.25 per category (as Deep Sliding Shapes).

:func:`evaluate_real` runs every category model on every frame and scores the detections with
average precision at 3D IoU >= 0.25 (:mod:`isa.evaluation.boxes3d`, the metric of Sliding Shapes);
:func:`real_section` adds the report's real-data section. Command line (:mod:`isa.detection.cli`)::

    python -m isa detect-real --model chair=out/paper/models/chair.isa --data ../shared/data/sunrgbd --out out/real
    python -m isa detect-real --train-procedural 6 --categories chair bed --data ../shared/data/sunrgbd --out out/real

All 3D quantities of boxes and planes are in the frame's upright frame (z up, camera at the
origin; see :mod:`isa.data.sunrgbd`)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, [
    "planes", "category_boxes", "hypotheses", "training", "real", "cli", "shapes", "verify", "proposals", "ranking",
    "refine", "gravity", "background", "multi",
])

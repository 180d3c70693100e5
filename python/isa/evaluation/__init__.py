"""Evaluation: pose metrics, 3D boxes, IoU, NMS and AP, the paper's published numbers and the Linemod
baseline (the experiment that runs them all is :mod:`isa.experiment`)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["pose_metrics", "boxes3d", "published", "linemod"])

"""Rendering: depth renders (``renderer``: the Rust core's rasteriser by default, or pyrender; the
only module that sets ``PYOPENGL_PLATFORM``, when a pyrender renderer is first made), camera views,
Kinect noise, and BOP training and test sets of rendered views (``dataset``)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["renderer", "views", "noise", "dataset"])

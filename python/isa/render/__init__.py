"""Rendering: depth renders (``renderer``: the Rust core's rasteriser by default, or pyrender; the
only module that sets ``PYOPENGL_PLATFORM``, when a pyrender renderer is first made), camera views,
Kinect noise, and BOP training and test sets of rendered views (``dataset``)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, {
    "renderer": [
        "release_gl", "DepthRenderer", "render_depth", "resolve_backend", "BACKENDS",
    ],
    "views": [
        "GOLDEN_ANGLE", "Views", "ViewBand", "look_at", "hemisphere_directions", "fit_distance", "training_views",
        "sample_test_views",
    ],
    "noise": [
        "KinectNoise", "apply_kinect_noise",
    ],
    "dataset": [
        "ObjectSpec", "RenderSummary", "modelnet_objects", "procedural_objects", "hull_points",
        "default_views", "default_test_views", "render_dataset",
    ],
})

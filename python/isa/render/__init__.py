"""Rendering: headless depth renders (``renderer``, the only module that sets
``PYOPENGL_PLATFORM``, when a renderer is first made), camera views, Kinect noise, and BOP training
and test sets of rendered views (``dataset``).

Public names are re-exported lazily (``lazy_loader``): importing the package loads none of its
modules, so ``import isa.render`` pulls in no OpenGL or OpenCV until a name that needs them is used.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(
    __name__,
    submodules=["renderer", "views", "noise", "dataset"],
    submod_attrs={
        "renderer": [
            "release_gl", "DepthRenderer", "render_depth",
        ],
        "views": [
            "GOLDEN_ANGLE", "Views", "look_at", "hemisphere_directions", "fit_distance", "training_views",
            "sample_test_views",
        ],
        "noise": [
            "KinectNoise", "apply_kinect_noise",
        ],
        "dataset": [
            "ObjectSpec", "RenderSummary", "modelnet_objects", "procedural_objects", "hull_points",
            "default_views", "default_test_views", "render_dataset",
        ],
    },
)

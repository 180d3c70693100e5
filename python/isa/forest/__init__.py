"""The ISA forest: the Rust forest's Python face (``model``) and its training from rendered views
(``training``).

Public names are re-exported lazily (``lazy_loader``): importing the package loads none of its
modules, so ``import isa.forest`` pulls in no OpenGL or OpenCV until a name that needs them is used.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(
    __name__,
    submodules=["model", "training"],
    submod_attrs={
        "model": [
            "QUALITIES", "Forest", "ForestParams", "depth_features", "sample_parts",
        ],
        "training": [
            "load_frames", "training_set", "PROBE_REACH", "VOTE_BANDWIDTH", "parts_diameter",
            "scaled_max_offset", "scaled_params", "scaled_predict_defaults", "train_forest",
        ],
    },
)

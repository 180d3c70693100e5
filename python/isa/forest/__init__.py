"""The ISA forest: the Rust forest's Python face (``model``) and its training from rendered views
(``training``)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, {
    "model": [
        "QUALITIES", "Forest", "ForestParams", "depth_features", "sample_parts",
    ],
    "training": [
        "load_frames", "training_set", "PROBE_REACH", "VOTE_BANDWIDTH", "parts_diameter", "scaled_max_offset",
        "scaled_params", "scaled_predict_defaults", "train_forest",
    ],
})

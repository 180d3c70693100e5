"""Privileged data (training only): skeletons, their matching to a category template, the SSC,
part annotation, and the symmetries (mirror, turn) of instances."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, {
    "skeleton": [
        "sample_surface", "voxelize_solid", "extract_skeleton", "solid_centre_of_mass",
    ],
    "matching": [
        "normalise", "denormalise", "template_from_ground_truth", "match_skeleton", "calibrate_template",
        "template_from_instances", "match_graphs_qap",
    ],
    "ssc": [
        "centre_of_mass", "SSC", "select_ssc", "CENTRES", "CategorySSC", "fit_category_ssc",
    ],
    "annotate": [
        "project_skeleton", "link_angles", "angle_embedding", "circular_difference", "node_offsets",
        "rotation_quaternion", "quaternion_to_matrix", "Frame", "TrainingSet", "build_training_set",
    ],
    "symmetry": [
        "ORDERS", "YawSymmetry", "find_yaw_symmetry", "recall_ceiling", "canonical_turn", "canonical_pose",
        "common_subgroup", "canonical_frames",
    ],
    "mirror": [
        "SYMMETRY_TOLERANCE", "Mirror", "find_mirror", "mirrored_frame", "with_mirrored",
    ],
})

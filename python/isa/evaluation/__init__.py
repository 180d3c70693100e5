"""Evaluation: pose metrics, 3D boxes, IoU, NMS and AP, the paper's published numbers and the Linemod
baseline (the experiment that runs them all is :mod:`isa.experiment`).

Public names are re-exported lazily (``lazy_loader``): importing the package loads none of its
modules, so ``import isa.evaluation`` pulls in no OpenGL or OpenCV until a name that needs them is used.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(
    __name__,
    submodules=["pose_metrics", "boxes3d", "published", "linemod"],
    submod_attrs={
        "pose_metrics": [
            "average_distance", "symmetric_average_distance", "model_points", "model_diameter", "is_correct",
            "recall", "recall_curve",
        ],
        "boxes3d": [
            "Box3D", "APResult", "polygon_area", "clip_convex_polygon", "footprint_intersection_area",
            "iou_3d", "iou_matrix", "nms", "voc_ap", "average_precision", "evaluate_detections",
            "box_from_pose", "yaw_from_rotation", "IOU_THRESHOLD",
        ],
        "published": [
            "POSE_RECALL", "DETECTION_AP", "PRINTED_MEANS", "mean", "table_rows",
        ],
        "linemod": [
            "DEFAULT_PYRAMID", "LinemodDetector", "LinemodMatch", "LinemodRecall", "depth_to_mm",
            "linemod_recall",
        ],
    },
)

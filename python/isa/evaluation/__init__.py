"""Evaluation: pose metrics, 3D boxes, IoU, NMS and AP, the paper's published numbers and the Linemod
baseline (the experiment that runs them all is :mod:`isa.experiment`)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, {
    "pose_metrics": [
        "average_distance", "symmetric_average_distance", "model_points", "model_diameter", "is_correct",
        "recall", "recall_curve",
    ],
    "boxes3d": [
        "Box3D", "APResult", "polygon_area", "clip_convex_polygon", "footprint_intersection_area", "iou_3d",
        "iou_matrix", "nms", "voc_ap", "average_precision", "evaluate_detections", "box_from_pose",
        "yaw_from_rotation", "IOU_THRESHOLD",
    ],
    "published": [
        "POSE_RECALL", "DETECTION_AP", "PRINTED_MEANS", "mean", "table_rows",
    ],
    "linemod": [
        "DEFAULT_PYRAMID", "LinemodDetector", "LinemodMatch", "LinemodRecall", "depth_to_mm", "linemod_recall",
    ],
})

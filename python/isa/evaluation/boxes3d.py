"""Gravity-aligned oriented 3D boxes, their exact 3D IoU, and 3D detection average precision.

Frame: every box lives in the **upright frame** of a depth frame (see :mod:`isa.data.sunrgbd`): origin at
the camera centre, ``z`` up (against gravity), ``x`` and ``y`` horizontal with ``y`` the camera's
viewing direction projected on the floor and ``x`` to its right. This is SUN RGB-D's "upright
depth" frame, the one Sliding Shapes, Deep Sliding Shapes, VoteNet and mmdetection3d use.

A :class:`Box3D` is ``centre`` (metres), ``size`` = full extents ``(length, width, height)`` and
``yaw``: the box's local ``x`` axis (along which ``length`` is measured) is
``(cos yaw, sin yaw, 0)``, i.e. yaw is counter-clockwise about ``+z`` seen from above, from the
upright ``x`` axis. ``height`` is along ``z``.

The metric is the one of Sliding Shapes (Song & Xiao, ECCV 2014) and Deep Sliding Shapes (Song &
Xiao, CVPR 2016, ``cnn3d_eval_class.m``):

* 3D IoU = footprint-polygon intersection area x vertical overlap / union volume, computed exactly
  (convex polygon clipping, Sutherland-Hodgman);
* detections of one category, over all frames, are taken in decreasing score; each is matched to
  the ground-truth box of its frame with the largest IoU; it is a true positive when that IoU is
  >= the threshold (0.25) and that box is not matched yet, otherwise a false positive (duplicates
  and detections whose best box is taken count as false positives, as in PASCAL VOC);
* AP is the area under the precision-recall curve made monotone (the PASCAL VOC 2010+ "all
  points" interpolation, ``xVOCap`` in the Deep Sliding Shapes code), not the 11-point VOC 2007
  variant (available with ``interpolation="11point"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from isa.exceptions import InvalidValueError

__all__ = [
    "Box3D",
    "APResult",
    "polygon_area",
    "clip_convex_polygon",
    "footprint_intersection_area",
    "iou_3d",
    "iou_matrix",
    "nms",
    "voc_ap",
    "average_precision",
    "evaluate_detections",
    "box_from_pose",
    "yaw_from_rotation",
    "IOU_THRESHOLD",
]

#: IoU above which a detection counts as correct in Sliding Shapes / Deep Sliding Shapes.
IOU_THRESHOLD = 0.25


def rot_z(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` (radians) about the z (up) axis."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class Box3D:
    """A gravity-aligned oriented box in the upright frame (see the module docstring).

    ``centre`` (3,) metres; ``size`` (3,) full extents (length along the yaw direction, width
    across it, height along z), all > 0; ``yaw`` radians; ``score`` the detector's confidence
    (ignored for ground truth); ``category`` a SUN RGB-D class name such as ``"chair"``.
    """

    category: str
    centre: np.ndarray
    size: np.ndarray
    yaw: float
    score: float = 1.0
    meta: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        centre = np.asarray(self.centre, dtype=float).reshape(-1)
        size = np.asarray(self.size, dtype=float).reshape(-1)
        if centre.shape != (3,) or size.shape != (3,):
            raise InvalidValueError(f"Box3D: centre and size must have 3 values, got {centre.shape}, {size.shape}")
        if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(size)) and math.isfinite(self.yaw)):
            raise InvalidValueError(f"Box3D: non-finite centre/size/yaw ({centre}, {size}, {self.yaw})")
        if np.any(size <= 0):
            raise InvalidValueError(f"Box3D: sizes must be positive, got {size}")
        centre.flags.writeable = False
        size.flags.writeable = False
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "yaw", float(self.yaw))
        object.__setattr__(self, "score", float(self.score))

    @property
    def volume(self) -> float:
        return float(np.prod(self.size))

    @property
    def z_range(self) -> tuple[float, float]:
        """(bottom, top) heights."""
        return self.centre[2] - self.size[2] / 2, self.centre[2] + self.size[2] / 2

    @property
    def heading(self) -> np.ndarray:
        """Unit vector (3,) of the box's local x axis (the ``length`` direction)."""
        return np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])

    def footprint(self) -> np.ndarray:
        """The 4 floor-plan corners (4, 2), counter-clockwise seen from above."""
        hl, hw = self.size[0] / 2, self.size[1] / 2
        local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return local @ np.array([[c, s], [-s, c]]) + self.centre[:2]

    def corners(self) -> np.ndarray:
        """The 8 corners (8, 3): the bottom face (counter-clockwise from above), then the top face
        in the same order, so corner ``i`` and ``i + 4`` share a vertical edge."""
        fp = self.footprint()
        z0, z1 = self.z_range
        return np.concatenate([np.column_stack([fp, np.full(4, z0)]), np.column_stack([fp, np.full(4, z1)])])

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Boolean mask (N,) of upright-frame points (N, 3) inside the box (boundary included)."""
        d = np.asarray(points, dtype=float).reshape(-1, 3) - self.centre
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        # Written out rather than a (N, 3) @ (3, 3) matmul, which BLAS threading makes slow.
        half = self.size / 2 + 1e-12
        return ((np.abs(d[:, 0] * c + d[:, 1] * s) <= half[0]) & (np.abs(d[:, 1] * c - d[:, 0] * s) <= half[1])
                & (np.abs(d[:, 2]) <= half[2]))

    def replace(self, **changes) -> "Box3D":
        """A copy with some fields changed (e.g. ``score``)."""
        fields = dict(category=self.category, centre=self.centre, size=self.size, yaw=self.yaw,
                      score=self.score, meta=dict(self.meta))
        fields.update(changes)
        return Box3D(**fields)


# ----------------------------------------------------------------------------------------------
# Polygons and IoU


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (shoelace) of a polygon (N, 2); positive when counter-clockwise."""
    poly = np.asarray(poly, dtype=float)
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def clip_convex_polygon(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon ``subject`` inside the convex polygon ``clip``.

    Both (N, 2); ``clip`` must be counter-clockwise. Returns the intersection polygon (M, 2),
    possibly empty (M < 3).
    """
    out = [tuple(p) for p in np.asarray(subject, dtype=float)]
    clip = np.asarray(clip, dtype=float)
    # Points within this (scaled) distance of an edge count as on it, so coincident edges (the
    # identical-box case) keep their vertices instead of flickering in and out on round-off.
    scale = max(1.0, float(np.abs(clip).max()))
    eps = 1e-12 * scale * scale
    for i in range(len(clip)):
        if len(out) == 0:
            break
        ax, ay = clip[i]
        bx, by = clip[(i + 1) % len(clip)]
        ex, ey = bx - ax, by - ay

        def side(p, ax=ax, ay=ay, ex=ex, ey=ey):
            return ex * (p[1] - ay) - ey * (p[0] - ax)

        inp, out = out, []
        prev = inp[-1]
        s_prev = side(prev)
        for cur in inp:
            s_cur = side(cur)
            if s_cur >= -eps:
                if s_prev < -eps:
                    out.append(_cross_point(prev, cur, s_prev, s_cur))
                out.append(cur)
            elif s_prev >= -eps:
                out.append(_cross_point(prev, cur, s_prev, s_cur))
            prev, s_prev = cur, s_cur
    return np.array(out, dtype=float).reshape(-1, 2)


def _cross_point(p, q, sp, sq):
    # The point of segment p-q on the clip line, from the signed distances of its ends.
    t = sp / (sp - sq)
    return (p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]))


def footprint_intersection_area(a: Box3D, b: Box3D) -> float:
    """Exact area of the intersection of two boxes' floor plans (square metres)."""
    # Cheap rejection by circumscribed circles: most pairs in a scene are far apart.
    ra = 0.5 * math.hypot(a.size[0], a.size[1])
    rb = 0.5 * math.hypot(b.size[0], b.size[1])
    if np.hypot(*(a.centre[:2] - b.centre[:2])) >= ra + rb:
        return 0.0
    return max(0.0, polygon_area(clip_convex_polygon(a.footprint(), b.footprint())))


def iou_3d(a: Box3D, b: Box3D) -> float:
    """Exact 3D intersection over union of two gravity-aligned oriented boxes, in [0, 1]."""
    za0, za1 = a.z_range
    zb0, zb1 = b.z_range
    dz = min(za1, zb1) - max(za0, zb0)
    if dz <= 0:
        return 0.0
    inter = footprint_intersection_area(a, b) * dz
    if inter <= 0:
        return 0.0
    return float(min(1.0, inter / (a.volume + b.volume - inter)))


def iou_matrix(boxes_a: Sequence[Box3D], boxes_b: Sequence[Box3D]) -> np.ndarray:
    """(len(a), len(b)) matrix of :func:`iou_3d`."""
    m = np.zeros((len(boxes_a), len(boxes_b)))
    for i, a in enumerate(boxes_a):
        for j, b in enumerate(boxes_b):
            m[i, j] = iou_3d(a, b)
    return m


def nms(boxes: Sequence[Box3D], iou_threshold: float = IOU_THRESHOLD) -> list[int]:
    """Greedy non-maximum suppression by score; returns the kept indices, best first.

    A box is dropped when its 3D IoU with an already kept box exceeds ``iou_threshold``
    (Deep Sliding Shapes runs it at 0.25 before evaluation). Ties keep the input order.
    """
    order = sorted(range(len(boxes)), key=lambda i: -boxes[i].score)
    kept: list[int] = []
    for i in order:
        if all(iou_3d(boxes[i], boxes[k]) <= iou_threshold for k in kept):
            kept.append(i)
    return kept


# ----------------------------------------------------------------------------------------------
# Average precision


@dataclass(frozen=True, eq=False)
class APResult:
    """Average precision of one category.

    ``precision``/``recall`` (D,) after each of the D ranked detections; ``true_positive`` (D,)
    bool in rank order; ``n_ground_truth`` boxes of the category over all frames; ``ap`` in
    [0, 1] (``nan`` when there is no ground truth of the category).
    """

    category: str
    ap: float
    precision: np.ndarray
    recall: np.ndarray
    true_positive: np.ndarray
    n_ground_truth: int
    iou_threshold: float


def voc_ap(recall: np.ndarray, precision: np.ndarray, interpolation: str = "area") -> float:
    """Area under a precision-recall curve.

    ``"area"``: PASCAL VOC 2010+ / Deep Sliding Shapes ``xVOCap`` - precision replaced by its
    running maximum from the right, integrated exactly over recall. ``"11point"``: VOC 2007, the
    mean of the maximum precision at recall >= 0, 0.1, ..., 1.
    """
    recall = np.asarray(recall, dtype=float)
    precision = np.asarray(precision, dtype=float)
    if interpolation == "area":
        mrec = np.concatenate([[0.0], recall, [1.0]])
        mpre = np.concatenate([[0.0], precision, [0.0]])
        mpre = np.maximum.accumulate(mpre[::-1])[::-1]
        idx = np.nonzero(mrec[1:] != mrec[:-1])[0] + 1
        return float(np.sum((mrec[idx] - mrec[idx - 1]) * mpre[idx]))
    if interpolation == "11point":
        ap = 0.0
        for r in np.linspace(0.0, 1.0, 11):
            p = precision[recall >= r - 1e-12]
            ap += (p.max() if p.size else 0.0) / 11
        return float(ap)
    raise InvalidValueError(f"voc_ap: interpolation must be 'area' or '11point', got {interpolation!r}")


def average_precision(
    detections: Sequence[Sequence[Box3D]],
    ground_truth: Sequence[Sequence[Box3D]],
    category: str,
    iou_threshold: float = IOU_THRESHOLD,
    interpolation: str = "area",
) -> APResult:
    """AP of one category over a set of frames (see the module docstring for the rules).

    ``detections[f]`` and ``ground_truth[f]`` are the boxes of frame ``f`` (all categories; only
    ``category`` is used). Detections need a ``score``; equal scores keep the input order.
    """
    if len(detections) != len(ground_truth):
        raise InvalidValueError(f"average_precision: {len(detections)} detection lists for {len(ground_truth)} frames")
    gts = [[g for g in frame if g.category == category] for frame in ground_truth]
    dets = [(d.score, f, d) for f, frame in enumerate(detections) for d in frame if d.category == category]
    n_gt = sum(len(g) for g in gts)
    if any(not math.isfinite(s) for s, _, _ in dets):
        raise InvalidValueError(f"average_precision: non-finite detection scores for {category!r}")
    # Stable sort: ties keep the order of the input (frame, then position).
    dets = sorted(dets, key=lambda x: -x[0])
    matched = [np.zeros(len(g), dtype=bool) for g in gts]
    tp = np.zeros(len(dets), dtype=bool)
    for k, (_, f, d) in enumerate(dets):
        if not gts[f]:
            continue
        ious = np.array([iou_3d(d, g) for g in gts[f]])
        j = int(np.argmax(ious))
        if ious[j] >= iou_threshold and not matched[f][j]:
            tp[k] = True
            matched[f][j] = True
    ctp = np.cumsum(tp)
    cfp = np.cumsum(~tp)
    precision = ctp / np.maximum(ctp + cfp, 1)
    recall = ctp / n_gt if n_gt else np.zeros(len(dets))
    ap = voc_ap(recall, precision, interpolation) if n_gt else float("nan")
    return APResult(category, ap, precision, recall, tp, n_gt, iou_threshold)


def evaluate_detections(
    detections: Sequence[Sequence[Box3D]],
    ground_truth: Sequence[Sequence[Box3D]],
    categories: Sequence[str] = ("bed", "chair", "table", "toilet"),
    iou_threshold: float = IOU_THRESHOLD,
    interpolation: str = "area",
) -> dict[str, APResult]:
    """:func:`average_precision` for each category (default: the paper's four)."""
    return {c: average_precision(detections, ground_truth, c, iou_threshold, interpolation) for c in categories}


# ----------------------------------------------------------------------------------------------
# From a 6D pose hypothesis to a box


def yaw_from_rotation(M: np.ndarray) -> float:
    """The rotation about z closest (Frobenius) to the 3x3 rotation ``M``: the yaw of M's x axis
    for an upright M, and a stable answer when M is tilted (no special case near vertical)."""
    M = np.asarray(M, dtype=float)
    return math.atan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])


def box_from_pose(
    R: np.ndarray,
    t: np.ndarray,
    size: np.ndarray,
    ssc_offset: np.ndarray,
    R_gravity: np.ndarray,
    category: str,
    score: float = 1.0,
) -> Box3D:
    """Turn a 6D pose hypothesis into a gravity-aligned box in the upright frame.

    ``R``, ``t``: the pose, ``X_cam = R @ X_obj + t`` (object frame z up, origin at the SSC, see
    docs/DESIGN.md); ``size`` (3,): the category box's full extents along the object's x, y, z;
    ``ssc_offset`` (3,): the SSC's position relative to the box centre in the object frame;
    ``R_gravity``: camera to upright, ``X_up = R_gravity @ X_cam``. The box centre is the object's
    box centre carried by the pose; its yaw comes from the object's x axis (:func:`yaw_from_rotation`
    of ``R_gravity @ R``); any tilt of the pose is dropped because the box is gravity-aligned.
    """
    R = np.asarray(R, dtype=float).reshape(3, 3)
    t = np.asarray(t, dtype=float).reshape(3)
    Rg = np.asarray(R_gravity, dtype=float).reshape(3, 3)
    centre_cam = R @ (-np.asarray(ssc_offset, dtype=float).reshape(3)) + t
    return Box3D(category, Rg @ centre_cam, size, yaw_from_rotation(Rg @ R), score)

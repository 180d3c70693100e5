"""Scoring detections in scenes: one function for synthetic rooms, real scans and real frames.

:func:`evaluate` takes, per frame, the ground truth, the detections and the gravity rotation, and
scores every category with four metrics, each by greedy matching in decreasing score, one
detection per object (PASCAL VOC's rule, as :func:`isa.evaluation.boxes3d.average_precision`): a detection
is matched to the ground-truth object of its frame and category it agrees with best; it is a true
positive when the agreement passes the metric's threshold and that object is not taken yet, a
false positive otherwise (duplicates included).

- ``6d``: the paper's Eq. 14 (:func:`isa.evaluation.pose_metrics.average_distance` over the instance's
  model points) at most ``z`` (0.1) times the diameter;
- ``6d_sym``: the same with symmetries forgiven: the minimum of Eq. 14 over the instance's
  symmetry group (the true pose composed with each symmetry), as BOP's MSSD does for its maximum
  distance; a rectangular table turned by 180 degrees is right here and wrong under ``6d``;
- ``box_0.25`` / ``box_0.5``: the 3D IoU (:func:`isa.evaluation.boxes3d.iou_3d`) of the gravity-aligned
  boxes in the frame's upright frame, at least 0.25 (Sliding Shapes, the paper's real metric) or
  0.5.

AP is the VOC 2010+ "all points" area (:func:`isa.evaluation.boxes3d.voc_ap`). Objects whose visible
fraction is below ``min_visib`` (0.3) are **ignored** ground truth, as VOC's "difficult": they do
not count in the recall, and a detection matched to one is neither a true nor a false positive.
Besides AP, each metric reports the recall over all detections of the objects in each visible-
fraction bin (0.1-0.3, 0.3-0.6, 0.6-1.0; ignored objects included there), AP with only one bin's
objects counted (the others ignored), and the median translation (metres) and rotation (degrees)
errors of the true positives.

Ground truth is either a pose record (anything with ``category``, ``R``, ``t``, ``size``,
``visib_fract``, ``symmetries``, ``points``: :class:`isa.scenes.io.GroundTruth`) or a bare
:class:`isa.evaluation.boxes3d.Box3D` in the upright frame (SUN RGB-D, no 6D truth, visible fraction unknown:
never ignored, in no bin); detections are :class:`Detection` (a 6D pose with a size) or bare
``Box3D``. The 6D metrics are ``None`` (n/a) for a category where either side lacks poses.
Poses map object to camera, ``X_cam = R X + t``, metres; ``gravity`` is camera to upright
(``X_up = gravity @ X_cam``, z up), None for a level camera.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from isa.evaluation.boxes3d import Box3D, box_from_pose, iou_matrix, rot_z, voc_ap
from isa.evaluation.pose_metrics import average_distance, model_diameter
from isa.exceptions import InvalidTypeError, InvalidValueError

__all__ = [
    "LEVEL_GRAVITY",
    "METRICS",
    "MIN_VISIB",
    "VISIB_BINS",
    "Detection",
    "MetricScore",
    "Scores",
    "Z",
    "evaluate",
    "ground_truth_box",
    "rotation_error_deg",
    "symmetry_transforms",
]

#: The metrics, in report order.
METRICS: tuple[str, ...] = ("6d", "6d_sym", "box_0.25", "box_0.5")
#: The box metrics' IoU thresholds (0.25: Sliding Shapes, the paper's real-data metric).
IOU_THRESHOLDS = {"box_0.25": 0.25, "box_0.5": 0.5}
#: Visible-fraction bins of the recall (the last one includes 1.0).
VISIB_BINS: tuple[tuple[float, float], ...] = ((0.1, 0.3), (0.3, 0.6), (0.6, 1.0))
#: Objects less visible than this are ignored ground truth (targets are quoted at visib >= 0.3).
MIN_VISIB = 0.3
#: Eq. 15's threshold: correct when the average distance is at most Z x the diameter.
Z = 0.1
#: Steps of a continuous symmetry (one degree).
N_CONTINUOUS = 360

#: The level camera's gravity (used where a frame has none): OpenCV camera axes renamed to the upright frame's (z up).
LEVEL_GRAVITY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _vec3(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidValueError(f"{name}: expected 3 finite numbers, got {v!r}")
    return a


def _rot(R, name: str) -> np.ndarray:
    a = np.asarray(R, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise InvalidValueError(f"{name}: expected a finite 3x3 rotation, got shape {a.shape}")
    return a


@dataclass(frozen=True, eq=False)
class Detection:
    """One detected object: ``category``, pose ``R`` (3, 3) / ``t`` (3,) metres (object to
    camera), ``size`` (3,) the object's full extents along its own x, y, z (metres), ``score``
    (higher is surer), ``box_centre`` (3,) the centre of that box in the object frame (zeros when
    the object-frame origin is the box centre; a centre-of-mass origin is not)."""

    category: str
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    score: float
    box_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", _rot(self.R, f"Detection({self.category!r}).R"))
        object.__setattr__(self, "t", _vec3(self.t, f"Detection({self.category!r}).t"))
        size = _vec3(self.size, f"Detection({self.category!r}).size")
        if np.any(size <= 0):
            raise InvalidValueError(f"Detection({self.category!r}).size: must be positive, got {size}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "box_centre", _vec3(self.box_centre, f"Detection({self.category!r}).box_centre"))
        if not math.isfinite(float(self.score)):
            raise InvalidValueError(f"Detection({self.category!r}).score: must be finite, got {self.score}")
        object.__setattr__(self, "score", float(self.score))

    def box(self, gravity: np.ndarray | None = None) -> Box3D:
        """The gravity-aligned box in the upright frame (tilt dropped, :func:`isa.evaluation.boxes3d.box_from_pose`)."""
        Rg = LEVEL_GRAVITY if gravity is None else gravity
        return box_from_pose(self.R, self.t, self.size, -self.box_centre, Rg, self.category, self.score)

    @classmethod
    def from_box(cls, box: Box3D, gravity: np.ndarray | None = None, box_centre=(0.0, 0.0, 0.0)) -> Detection:
        """The upright pose of a gravity-aligned box (object x axis along the box's yaw), the
        inverse of :meth:`box`: what :func:`isa.detection.hypotheses.detect` reports, as a 6D detection.
        ``box_centre``: where the box centre is in the object frame (the category box's
        ``-ssc_offset``)."""
        Rg = LEVEL_GRAVITY if gravity is None else np.asarray(gravity, dtype=float)
        # solve, not transpose: gravity read from rounded calibration files is not exactly orthogonal.
        R = np.linalg.solve(Rg, rot_z(box.yaw))
        c = np.asarray(box_centre, dtype=float)
        t = np.linalg.solve(Rg, box.centre) - R @ c
        return cls(box.category, R, t, box.size, box.score, c)

    def to_dict(self) -> dict:
        return {"category": self.category, "R": self.R.tolist(), "t": self.t.tolist(), "size": self.size.tolist(),
                "score": self.score, "box_centre": self.box_centre.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Detection:
        try:
            return cls(d["category"], d["R"], d["t"], d["size"], d["score"], d.get("box_centre", (0.0, 0.0, 0.0)))
        except (KeyError, TypeError) as exc:
            raise InvalidValueError(f"detection: needs category, R, t, size, score; got {d!r} ({exc})") from None


# ----------------------------------------------------------------------------------------------
# Symmetry groups


def _axis_rotation(axis: np.ndarray, theta: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * (K @ K)


def symmetry_transforms(symmetries: Sequence | str = (), n_continuous: int = N_CONTINUOUS,
                        centre=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The symmetry group of an instance as object-frame transforms ``x -> R_s x + t_s``:
    ``(R (k, 3, 3), t (k, 3))``, the identity first.

    Each item is a 3x3 rotation (about ``centre``: :class:`isa.scenes.io.GroundTruth`'s
    ``symmetry_centre``), a 4x4 or flat 16 rigid transform (translation in metres: BOP's
    ``symmetries_discrete`` once converted from mm), ``"continuous-z"`` (every turn about the
    vertical through ``centre``; alone or in a list), a BOP continuous symmetry ``{"axis": (3,),
    "offset": (3,) metres}``, or a :class:`isa.privileged.symmetry.YawSymmetry` (turns about the vertical
    through its own ``centre``). Continuous ones are sampled every 360 / ``n_continuous`` degrees;
    duplicates (the identity listed again) change no minimum.
    """
    if isinstance(symmetries, str):
        symmetries = [symmetries]
    c0 = _vec3(centre, "symmetry centre")
    Rs, ts = [np.eye(3)], [np.zeros(3)]

    def turns(axis, offset, angles):
        for th in angles:
            R = _axis_rotation(np.asarray(axis, float), th)
            Rs.append(R)
            ts.append(np.asarray(offset, float) - R @ np.asarray(offset, float))

    for s in symmetries:
        if isinstance(s, str):
            if s != "continuous-z":
                raise InvalidValueError(f"symmetry: unknown name {s!r} (expected 'continuous-z')")
            turns((0, 0, 1), c0, 2 * np.pi * np.arange(1, n_continuous) / n_continuous)
        elif isinstance(s, Mapping):
            if "axis" not in s:
                raise InvalidValueError(f"symmetry: a continuous symmetry needs 'axis', got {s!r}")
            turns(_vec3(s["axis"], "symmetry axis"), _vec3(s.get("offset", (0, 0, 0)), "symmetry offset"),
                  2 * np.pi * np.arange(1, n_continuous) / n_continuous)
        elif hasattr(s, "order") and hasattr(s, "centre"):
            if s.order == 1:
                continue
            n = n_continuous if s.order == 0 else int(s.order)
            turns((0, 0, 1), _vec3(s.centre, "symmetry centre"), 2 * np.pi * np.arange(1, n) / n)
        else:
            a = np.asarray(s, dtype=float)
            if a.size == 16:
                a = a.reshape(4, 4)
                Rs.append(a[:3, :3])
                ts.append(a[:3, 3])
            elif a.shape == (3, 3):
                Rs.append(a)
                ts.append(c0 - a @ c0)
            else:
                raise InvalidValueError(f"symmetry: expected a 3x3 or 4x4 matrix, got shape {a.shape}")
    return np.array(Rs), np.array(ts)


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The angle (degrees) of the rotation between ``R_a`` and ``R_b``."""
    c = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


# ----------------------------------------------------------------------------------------------
# Normalised targets and candidates


@dataclass(eq=False)
class _Target:
    category: str
    box: Box3D
    visib: float  # nan: unknown
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    points: np.ndarray | None = None
    diameter: float = float("nan")
    sym_R: np.ndarray | None = None
    sym_t: np.ndarray | None = None


@dataclass(eq=False)
class _Candidate:
    category: str
    box: Box3D
    score: float
    R: np.ndarray | None = None
    t: np.ndarray | None = None


def _target(g, gravity: np.ndarray, cache: dict) -> _Target:
    if isinstance(g, Box3D):
        return _Target(g.category, g, float("nan"))
    name = f"ground truth {getattr(g, 'obj_id', '')} ({g.category!r})"
    R, t, size = _rot(g.R, f"{name}.R"), _vec3(g.t, f"{name}.t"), _vec3(g.size, f"{name}.size")
    pts = getattr(g, "points", None)
    key = id(pts) if pts is not None else None
    if key is not None and key in cache:
        pts, diam, centre = cache[key]
    else:
        if pts is None:
            from isa.scenes.io import box_points

            centre = np.zeros(3)
            pts = box_points(-size / 2, size)
        else:
            pts = np.asarray(pts, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
                raise InvalidValueError(f"{name}.points: expected (N, 3), got shape {pts.shape}")
            centre = (pts.min(0) + pts.max(0)) / 2
        diam = model_diameter(pts)
        if key is not None:
            cache[key] = (pts, diam, centre)
    syms, sc = getattr(g, "symmetries", None), getattr(g, "symmetry_centre", None)
    sR, st = symmetry_transforms(() if syms is None else syms, centre=(0.0, 0.0, 0.0) if sc is None else sc)
    v = getattr(g, "visib_fract", None)
    box = box_from_pose(R, t, size, -centre, gravity, g.category)
    return _Target(g.category, box, float("nan") if v is None else float(v), R, t, pts, diam, sR, st)


def ground_truth_box(g, gravity: np.ndarray | None = None) -> Box3D:
    """A ground-truth object's gravity-aligned box in the upright frame (a Box3D is returned as is)."""
    return _target(g, LEVEL_GRAVITY if gravity is None else gravity, {}).box


def _candidate(d, gravity: np.ndarray) -> _Candidate:
    if isinstance(d, Box3D):
        return _Candidate(d.category, d, d.score)
    if not isinstance(d, Detection):
        raise InvalidTypeError(f"detection: expected a Detection or a Box3D, got {type(d).__name__}")
    return _Candidate(d.category, d.box(gravity), d.score, d.R, d.t)


# ----------------------------------------------------------------------------------------------
# Agreement matrices (higher is better; a pair passes at >= the threshold)


def _distances(points, Rg, tg, R, t, chunk: int = 32) -> np.ndarray:
    """Eq. 14 for each of the k true poses ``Rg`` (k, 3, 3), ``tg`` (k, 3) against one estimate,
    in chunks of poses (a sampled continuous group would otherwise hold k x N x 3 numbers)."""
    return np.concatenate([np.atleast_1d(average_distance(points, Rg[i:i + chunk], tg[i:i + chunk], R, t))
                           for i in range(0, len(Rg), chunk)])


def _pose_agreement(cands: Sequence[_Candidate], targets: Sequence[_Target], symmetric: bool, z: float) -> np.ndarray:
    """-(Eq. 14 / diameter) per (candidate, target). Pairs whose centroids alone are further
    apart than ``z`` diameters cannot pass (the mean distance is at least the distance of the
    means) and keep that lower bound instead of the exact value."""
    S = np.full((len(cands), len(targets)), -np.inf)
    for j, g in enumerate(targets):
        Rg = g.R @ g.sym_R if symmetric else g.R[None]
        tg = g.t + g.sym_t @ g.R.T if symmetric else g.t[None]
        xbar = g.points.mean(0)
        for i, d in enumerate(cands):
            lb = np.linalg.norm(Rg @ xbar + tg - (d.R @ xbar + d.t), axis=-1).min() / g.diameter
            if lb > z:
                S[i, j] = -lb
                continue
            S[i, j] = -float(_distances(g.points, Rg, tg, d.R, d.t).min()) / g.diameter
    return S


def _pose_errors(d: _Candidate, g: _Target, symmetric: bool) -> tuple[float, float]:
    """Translation (m) and rotation (deg) errors; with symmetries, of the group element closest under Eq. 14."""
    if symmetric:
        Rg = g.R @ g.sym_R
        tg = g.t + g.sym_t @ g.R.T
        k = int(np.argmin(_distances(g.points, Rg, tg, d.R, d.t)))
        R, t = Rg[k], tg[k]
    else:
        R, t = g.R, g.t
    return float(np.linalg.norm(d.t - t)), rotation_error_deg(d.R, R)


# ----------------------------------------------------------------------------------------------
# Results


def _percent(v: float | None) -> float | None:
    """A fraction as a JSON percentage (None for nan)."""
    return None if v is None or math.isnan(v) else 100.0 * v


def _bin_name(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g}"


@dataclass(frozen=True, eq=False)
class MetricScore:
    """One metric on one category.

    ``ap`` in [0, 1] (nan without counted ground truth); ``precision`` / ``recall`` after each
    ranked detection that is not ignored; ``n_ground_truth`` counted objects, ``n_ignored``
    ignored ones; ``n_detections`` ranked detections (ignored ones left out), ``n_true_positive``;
    ``recall_by_visib`` bin name -> (recall or nan, objects in the bin); ``ap_by_visib`` bin name ->
    AP with only that bin's objects counted; ``median_translation_m`` / ``median_rotation_deg``
    over the true positives (None when there are none, or for boxes without poses): for every
    metric but ``6d`` against the symmetric pose of the object closest to the detection.
    """

    metric: str
    category: str
    ap: float
    precision: np.ndarray
    recall: np.ndarray
    n_ground_truth: int
    n_ignored: int
    n_detections: int
    n_true_positive: int
    recall_by_visib: dict[str, tuple[float, int]]
    ap_by_visib: dict[str, float]
    median_translation_m: float | None
    median_rotation_deg: float | None

    @property
    def final_recall(self) -> float:
        """Recall of the counted objects over all detections (nan without counted objects)."""
        return self.n_true_positive / self.n_ground_truth if self.n_ground_truth else float("nan")

    def to_dict(self) -> dict:
        """JSON-ready, percentages 0-100, None for nan."""
        return {"ap": _percent(self.ap), "recall": _percent(self.final_recall),
                "n_ground_truth": self.n_ground_truth, "n_ignored": self.n_ignored,
                "n_detections": self.n_detections, "n_true_positive": self.n_true_positive,
                "recall_by_visib": {k: {"recall": _percent(r), "n": n} for k, (r, n) in self.recall_by_visib.items()},
                "ap_by_visib": {k: _percent(v) for k, v in self.ap_by_visib.items()},
                "median_translation_m": self.median_translation_m, "median_rotation_deg": self.median_rotation_deg}


@dataclass(frozen=True, eq=False)
class Scores:
    """:func:`evaluate`'s answer: ``metrics[category][metric]`` a :class:`MetricScore`, or None
    where the metric does not apply (6D without poses); ``outcome[f][i]`` metric -> "tp", "fp" or
    "ignored" for detection ``i`` of frame ``f`` (None where the metric does not apply)."""

    categories: list[str]
    metrics: dict[str, dict[str, MetricScore | None]]
    outcome: list[list[dict[str, str | None]]]
    n_frames: int
    min_visib: float
    z: float

    def ap_percent(self, metric: str) -> dict[str, float | None]:
        out = {}
        for c in self.categories:
            m = self.metrics[c][metric]
            out[c] = None if m is None or math.isnan(m.ap) else 100.0 * m.ap
        return out

    def to_dict(self) -> dict:
        return {"n_frames": self.n_frames, "min_visib": self.min_visib, "z": self.z, "metrics": list(METRICS),
                "visib_bins": [_bin_name(*b) for b in VISIB_BINS], "categories": self.categories,
                "per_category": {c: {m: (None if s is None else s.to_dict()) for m, s in ms.items()}
                                 for c, ms in self.metrics.items()}}


# ----------------------------------------------------------------------------------------------
# Matching


def _greedy(order, det_frame, det_row, S, thr, ignore):
    """VOC's greedy match of ranked detections. ``S[f]`` (detections x targets of frame f),
    ``ignore[f]`` (targets,) bool. Returns per ranked detection "tp" / "fp" / "ignored" and per
    frame the rank of the detection matched to each target (-1: none; ignored targets included)."""
    matched = [np.full(s.shape[1], -1) for s in S]
    out = []
    for k, d in enumerate(order):
        f = det_frame[d]
        row = S[f][det_row[d]] if S[f].shape[1] else np.zeros(0)
        if row.size == 0:
            out.append("fp")
            continue
        j = int(np.argmax(row))
        if row[j] < thr:
            out.append("fp")
        elif ignore[f][j]:
            out.append("ignored")
            if matched[f][j] < 0:
                matched[f][j] = k
        elif matched[f][j] < 0:
            out.append("tp")
            matched[f][j] = k
        else:
            out.append("fp")
    return out, matched


def _ap(outcome: Sequence[str], n_gt: int) -> tuple[float, np.ndarray, np.ndarray]:
    tp = np.array([o == "tp" for o in outcome if o != "ignored"], dtype=bool)
    ctp, cfp = np.cumsum(tp), np.cumsum(~tp)
    precision = ctp / np.maximum(ctp + cfp, 1)
    recall = ctp / n_gt if n_gt else np.zeros(len(tp))
    return (voc_ap(recall, precision) if n_gt else float("nan")), precision, recall


def _in_bin(v: float, lo: float, hi: float) -> bool:
    return lo <= v < hi or (hi >= 1.0 and v == hi)


def evaluate(ground_truth: Sequence[Sequence], detections: Sequence[Sequence], gravity: Sequence | None = None,
             categories: Sequence[str] | None = None, min_visib: float = MIN_VISIB, z: float = Z) -> Scores:
    """Score ``detections[f]`` against ``ground_truth[f]`` over all frames, per category (see the
    module docstring). ``gravity[f]``: the frame's camera-to-upright rotation (None: level camera),
    used for the boxes; ``categories``: those scored (default: every category in either list)."""
    if len(ground_truth) != len(detections):
        raise InvalidValueError(f"evaluate: {len(detections)} detection lists for {len(ground_truth)} frames")
    gravity = [None] * len(ground_truth) if gravity is None else list(gravity)
    if len(gravity) != len(ground_truth):
        raise InvalidValueError(f"evaluate: {len(gravity)} gravity rotations for {len(ground_truth)} frames")
    if not 0 <= min_visib <= 1:
        raise InvalidValueError(f"min_visib: must be in [0, 1], got {min_visib}")
    grav = [LEVEL_GRAVITY if g is None else _rot(g, f"gravity[{f}]") for f, g in enumerate(gravity)]
    cache: dict = {}
    targets = [[_target(g, grav[f], cache) for g in frame] for f, frame in enumerate(ground_truth)]
    cands = [[_candidate(d, grav[f]) for d in frame] for f, frame in enumerate(detections)]
    if categories is None:
        categories = sorted({x.category for fr in targets + cands for x in fr})
    categories = list(categories)
    outcome: list[list[dict]] = [[{m: None for m in METRICS} for _ in fr] for fr in cands]
    results: dict[str, dict[str, MetricScore | None]] = {}
    for cat in categories:
        tg = [[g for g in fr if g.category == cat] for fr in targets]
        idx = [[i for i, d in enumerate(fr) if d.category == cat] for fr in cands]
        cd = [[fr[i] for i in ix] for fr, ix in zip(cands, idx)]
        has_pose = all(g.R is not None for fr in tg for g in fr) and all(d.R is not None for fr in cd for d in fr)
        entries = [(d.score, f, r) for f, fr in enumerate(cd) for r, d in enumerate(fr)]
        order = sorted(range(len(entries)), key=lambda k: -entries[k][0])  # stable: ties keep input order
        det_frame = [e[1] for e in entries]
        det_row = [e[2] for e in entries]
        visib = [np.array([g.visib for g in fr], dtype=float) for fr in tg]
        results[cat] = {}
        for m in METRICS:
            if m.startswith("6d"):
                if not has_pose:
                    results[cat][m] = None
                    continue
                S = [_pose_agreement(cd[f], tg[f], m == "6d_sym", z) for f in range(len(tg))]
                thr = -z
            else:
                S = [iou_matrix([d.box for d in cd[f]], [g.box for g in tg[f]]) for f in range(len(tg))]
                thr = IOU_THRESHOLDS[m]
            results[cat][m], ranked_outcome = _score(cat, m, order, det_frame, det_row, S, thr, visib, min_visib, cd,
                                                     tg, has_pose)
            for k, d in enumerate(order):
                outcome[det_frame[d]][idx[det_frame[d]][det_row[d]]][m] = ranked_outcome[k]
    return Scores(categories, results, outcome, len(ground_truth), min_visib, z)


def _ignored(visib: Sequence[np.ndarray], lo: float, hi: float) -> list[np.ndarray]:
    """Objects outside [lo, hi] visibility (unknown visibility: never ignored)."""
    out = []
    for v in visib:
        known = np.isfinite(v)
        inside = (v >= lo) & ((v < hi) | (hi >= 1.0))
        out.append(known & ~inside)
    return out


def _score(cat, metric, order, det_frame, det_row, S, thr, visib, min_visib, cd, tg,
           has_pose) -> tuple[MetricScore, list[str]]:
    ign = _ignored(visib, min_visib, 1.0)
    ranked, matched = _greedy(order, det_frame, det_row, S, thr, ign)
    n_gt = int(sum((~i).sum() for i in ign))
    ap, precision, recall = _ap(ranked, n_gt)
    rec_bins, ap_bins = {}, {}
    for lo, hi in VISIB_BINS:
        name = _bin_name(lo, hi)
        inb = [np.array([_in_bin(x, lo, hi) for x in v], dtype=bool) for v in visib]
        n = int(sum(b.sum() for b in inb))
        hit = int(sum(((m >= 0) & b).sum() for m, b in zip(matched, inb)))
        rec_bins[name] = (hit / n if n else float("nan"), n)
        bin_ign = [~b for b in inb]
        bin_ranked, _ = _greedy(order, det_frame, det_row, S, thr, bin_ign)
        ap_bins[name] = _ap(bin_ranked, n)[0]
    t_err, r_err = [], []
    for k, o in enumerate(ranked):
        if o != "tp":
            continue
        d = order[k]
        f = det_frame[d]
        j = int(np.argmax(S[f][det_row[d]]))
        c, g = cd[f][det_row[d]], tg[f][j]
        if has_pose:
            te, re = _pose_errors(c, g, metric != "6d")  # a box does not see a symmetric turn either
            t_err.append(te)
            r_err.append(re)
        else:
            t_err.append(float(np.linalg.norm(c.box.centre - g.box.centre)))
    score = MetricScore(metric, cat, ap, precision, recall, n_gt, int(sum(i.sum() for i in ign)),
                        sum(o != "ignored" for o in ranked), sum(o == "tp" for o in ranked), rec_bins, ap_bins,
                        float(np.median(t_err)) if t_err else None, float(np.median(r_err)) if r_err else None)
    return score, ranked

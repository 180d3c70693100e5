"""Privileged part annotations (paper Sec. 3.2) and the training arrays handed to the Rust forest.

For every rendered view of an instance:

- the instance's template-matched skeleton is projected with the view's pose and intrinsics;
- ``a``: the angle each projected link (node i -> node k, as listed in the template) makes with
  the image x axis, ``atan2(dv, du)`` in [-pi, pi) (v grows downwards, as in the image). Angles are
  circular: a link along -x is at +-pi, so statistics must be taken on ``(cos a, sin a)``
  (:func:`angle_embedding`), which is what the core does;
- for every part centre ``c = (u, v, depth)``: ``s`` = the offsets to every projected node,
  ``(u_n - u, v_n - v)`` in pixels and ``z_n - depth`` in metres (node minus part);
- ``offsets`` (Delta x): the SSC minus the part's back-projected 3D point, camera frame, metres;
- ``rotations`` (theta): the object's rotation R as a unit quaternion (w, x, y, z), w >= 0.

:func:`build_training_set` turns rendered frames into the arrays of the DESIGN.md contract, all
vectorised over parts (a million parts take seconds).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from isa.camera import Intrinsics, metres_to_mm
from isa.exceptions import InvalidTypeError, InvalidValueError
from isa.skeleton_graph import SkeletonGraph

__all__ = [
    "project_skeleton", "link_angles", "angle_embedding", "circular_difference", "node_offsets", "rotation_quaternion",
    "quaternion_to_matrix", "Frame", "TrainingSet", "build_training_set",
]

# ---------------------------------------------------------------------------------------------
# Per-view geometry
# ---------------------------------------------------------------------------------------------


def project_skeleton(skeleton: SkeletonGraph, R, t, intrinsics: Intrinsics) -> np.ndarray:
    """Object-frame skeleton nodes -> (N, 3) ``[u px, v px, z m]`` in the view of pose (R, t)."""
    R = np.asarray(R, float).reshape(3, 3)
    t = np.asarray(t, float).reshape(3)
    X = skeleton.nodes @ R.T + t
    if np.any(X[:, 2] <= 0):
        raise InvalidValueError("skeleton: a node is at or behind the camera (z <= 0) for this pose (R, t)")
    uv = intrinsics.project(X)
    return np.concatenate([uv, X[:, 2:3]], axis=1)


def link_angles(node_uv: np.ndarray, links: np.ndarray) -> np.ndarray:
    """Angles (radians, [-pi, pi)) of projected links with the image x axis, ``atan2(dv, du)``.

    ``node_uv`` (..., N, >=2) pixel coordinates (batched over leading axes), ``links`` (L, 2).
    A link seen end-on (zero length in the image) gets angle 0.
    """
    node_uv = np.asarray(node_uv, float)
    links = np.asarray(links, np.int64).reshape(-1, 2)
    d = node_uv[..., links[:, 1], :2] - node_uv[..., links[:, 0], :2]
    a = np.arctan2(d[..., 1], d[..., 0])
    return np.where(a >= np.pi, a - 2 * np.pi, a)  # arctan2 gives (-pi, pi]; make it [-pi, pi)


def angle_embedding(a: np.ndarray) -> np.ndarray:
    """``(..., L)`` circular angles -> ``(..., 2L)`` ``[cos a_1, sin a_1, cos a_2, ...]`` (no jump at +-pi)."""
    a = np.asarray(a, float)
    return np.stack([np.cos(a), np.sin(a)], axis=-1).reshape(*a.shape[:-1], 2 * a.shape[-1])


def circular_difference(a, b) -> np.ndarray:
    """``a - b`` wrapped into [-pi, pi)."""
    return (np.asarray(a, float) - np.asarray(b, float) + np.pi) % (2 * np.pi) - np.pi


def node_offsets(parts_uvz: np.ndarray, nodes_uvz: np.ndarray) -> np.ndarray:
    """``s`` for parts (P, 3) ``[u, v, depth]`` and projected nodes (N, 3) or per part (P, N, 3).

    Returns (P, 3N) float32 ``[du_1, dv_1, dz_1, du_2, ...]``, node minus part.
    """
    c = np.asarray(parts_uvz, np.float32)
    n = np.asarray(nodes_uvz, np.float32)
    if n.ndim == 2:
        n = n[None]
    return (n - c[:, None, :]).reshape(len(c), -1)


def rotation_quaternion(R) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) (w, x, y, z) with w >= 0.

    Shepperd's method (numerically safe for every rotation, including 180-degree ones).
    """
    R = np.asarray(R, float)
    if R.shape[-2:] != (3, 3):
        raise InvalidValueError(f"R: expected (..., 3, 3), got {R.shape}")
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.diagonal(m, axis1=1, axis2=2)
    choice = np.argmax(np.concatenate([tr[:, None], diag], axis=1), axis=1)
    q = np.empty((len(m), 4))
    # Case w largest.
    s = np.sqrt(np.maximum(1.0 + tr, 1e-300)) * 2
    q_w = np.stack([s / 4, (m[:, 2, 1] - m[:, 1, 2]) / s, (m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 1, 0] - m[:, 0, 1]) / s], 1)
    cases = [q_w]
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(np.maximum(1.0 + m[:, i, i] - m[:, j, j] - m[:, k, k], 1e-300)) * 2
        qi = np.empty((len(m), 4))
        qi[:, 0] = (m[:, k, j] - m[:, j, k]) / s
        qi[:, 1 + i] = s / 4
        qi[:, 1 + j] = (m[:, j, i] + m[:, i, j]) / s
        qi[:, 1 + k] = (m[:, k, i] + m[:, i, k]) / s
        cases.append(qi)
    for c in range(4):
        sel = choice == c
        q[sel] = cases[c][sel]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return q.reshape(*R.shape[:-2], 4)


def quaternion_to_matrix(q) -> np.ndarray:
    """Unit quaternions (..., 4) (w, x, y, z) -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


# ---------------------------------------------------------------------------------------------
# Training set
# ---------------------------------------------------------------------------------------------


@dataclass
class Frame:
    """One rendered training view: depth (H, W) float32 metres (0 = missing), object mask, pose,
    intrinsics, the instance's template-matched skeleton and its SSC, both in the object frame.

    With the object frame's origin at the SSC (docs/DESIGN.md), ``ssc`` is (0, 0, 0).
    """

    depth: np.ndarray
    mask: np.ndarray
    R: np.ndarray
    t: np.ndarray
    intrinsics: Intrinsics
    skeleton: SkeletonGraph
    ssc: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class TrainingSet:
    """The DESIGN.md contract (see ``isa.forest.model``), plus where each crop came from.

    ``crops`` (F, 2) int: the (u0, v0) of each crop in its full image, so full-image pixel =
    crop pixel + crop origin.
    """

    images: list[np.ndarray]
    parts: np.ndarray
    offsets: np.ndarray
    rotations: np.ndarray
    link_angles: np.ndarray
    node_offsets: np.ndarray
    crops: np.ndarray

    def __len__(self) -> int:
        return len(self.parts)

    def arrays(self) -> dict:
        """The six arrays of the contract, by name."""
        return {
            "images": self.images,
            "parts": self.parts,
            "offsets": self.offsets,
            "rotations": self.rotations,
            "link_angles": self.link_angles,
            "node_offsets": self.node_offsets,
        }


def _check_frame(i: int, f: Frame) -> None:
    d = np.asarray(f.depth)
    if d.ndim != 2:
        raise InvalidValueError(f"frames[{i}].depth: expected a 2D array, got shape {d.shape}")
    if np.asarray(f.mask).shape != d.shape:
        raise InvalidValueError(f"frames[{i}].mask: shape {np.asarray(f.mask).shape} differs from depth {d.shape}")
    if np.asarray(f.R).shape != (3, 3) or np.asarray(f.t).reshape(-1).shape != (3,):
        raise InvalidValueError(f"frames[{i}]: R must be (3, 3) and t (3,)")
    if not isinstance(f.intrinsics, Intrinsics):
        raise InvalidTypeError(f"frames[{i}].intrinsics: expected isa.camera.Intrinsics, got {type(f.intrinsics).__name__}")
    if not isinstance(f.skeleton, SkeletonGraph):
        raise InvalidTypeError(f"frames[{i}].skeleton: expected a SkeletonGraph, got {type(f.skeleton).__name__}")


def build_training_set(
    frames: Iterable[Frame],
    stride: int = 4,
    margin: int = 8,
    nodes: Sequence[int] | None = None,
    links: np.ndarray | None = None,
    context: bool = False,
) -> TrainingSet:
    """Depth crops and per-part targets from rendered frames (the arrays for the forest).

    Each frame's depth is cropped to the object mask's bounding box plus ``margin`` pixels
    (clipped to the image), set to 0 outside the mask (foreground-only training, as in the paper)
    and converted to uint16 millimetres. Parts are the foreground pixels on a ``stride`` grid of the
    full image (so crops of the same view always agree). ``nodes`` selects which template nodes
    are projected (the paper projects 11 of 19; default all) and ``links`` which links give
    ``a`` (default: the skeleton's links between selected nodes).

    ``frames`` is read once, in order, and only each frame's crop is kept, so it may be a
    generator over views read from disk (:class:`isa.data.bop.FrameSequence`). Every frame's skeleton
    must have the same nodes count and links (one category template).

    ``context``: views of the object in a room (:mod:`isa.scenes.context`): the depth around the
    mask is kept and the crop is the whole image, so probes that leave the object read the room;
    the parts are still the mask's pixels only.
    """
    if int(stride) < 1:
        raise InvalidValueError(f"stride: must be >= 1, got {stride}")
    if int(margin) < 0:
        raise InvalidValueError(f"margin: must be >= 0, got {margin}")
    stride, margin = int(stride), int(margin)
    ref = None
    images: list[np.ndarray] = []
    crop_list: list[tuple[int, int]] = []
    per_u, per_v, per_z, per_f = [], [], [], []
    uvz_list, ssc_list, R_list, intr_list = [], [], [], []  # per frame: nodes (u, v, z), SSC, R, (fx, fy, cx, cy)
    for i, f in enumerate(frames):
        _check_frame(i, f)
        if ref is None:
            ref = f.skeleton
            n_all = len(ref.nodes)
            sel = np.arange(n_all) if nodes is None else np.asarray(nodes, np.int64).reshape(-1)
            if sel.size == 0 or sel.min() < 0 or sel.max() >= n_all:
                raise InvalidValueError(f"nodes: indices must be in [0, {n_all}), got {sel.tolist()}")
            if links is None:
                links_used = ref.links[np.isin(ref.links, sel).all(1)]
            else:
                links_used = np.asarray(links, np.int64).reshape(-1, 2)
                if links_used.size and (links_used.min() < 0 or links_used.max() >= n_all):
                    raise InvalidValueError(f"links: node index out of range [0, {n_all})")
        elif len(f.skeleton.nodes) != n_all or not np.array_equal(f.skeleton.links, ref.links):
            raise InvalidValueError(f"frames[{i}].skeleton: differs in nodes/links from frames[0]; match all to one template")
        depth = np.asarray(f.depth, np.float32)
        mask = np.asarray(f.mask, bool)
        K = f.intrinsics
        R = np.asarray(f.R, float)
        t = np.asarray(f.t, float).reshape(3)
        R_list.append(R)
        intr_list.append((K.fx, K.fy, K.cx, K.cy))
        uvz_list.append(project_skeleton(f.skeleton, R, t, K))
        ssc_list.append(R @ np.asarray(f.ssc, float).reshape(3) + t)
        # Bounding box from the boolean mask first (cheap), depth work only inside it.
        rows = np.flatnonzero(mask.any(1))
        cols = np.flatnonzero(mask.any(0)) if len(rows) else rows
        if len(rows):
            d = depth[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
            fgb = mask[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] & (d > 0) & np.isfinite(d)
            r2, c2 = np.flatnonzero(fgb.any(1)), np.flatnonzero(fgb.any(0))
            rows, cols = (rows[0] + r2, cols[0] + c2) if len(r2) else (r2, r2)
        if len(rows) == 0:  # an empty view contributes an empty crop and no parts
            images.append(np.zeros((1, 1), np.uint16))
            crop_list.append((0, 0))
            continue
        h, w = depth.shape
        if context:
            v0, v1, u0, u1 = 0, h, 0, w
        else:
            v0, v1 = max(0, rows[0] - margin), min(h, rows[-1] + 1 + margin)
            u0, u1 = max(0, cols[0] - margin), min(w, cols[-1] + 1 + margin)
        crop_list.append((u0, v0))
        d = depth[v0:v1, u0:u1]
        seen = (d > 0) & np.isfinite(d)
        fg = mask[v0:v1, u0:u1] & seen
        mm = metres_to_mm(np.where(seen if context else fg, d, 0))
        crop = np.ascontiguousarray(np.clip(mm, 0, 65535).astype(np.uint16))
        images.append(crop)
        # Grid in full-image coordinates: the first grid row/column at or after the crop origin.
        gv = np.arange(-(-v0 // stride) * stride, v1, stride)
        gu = np.arange(-(-u0 // stride) * stride, u1, stride)
        sub = crop[np.ix_(gv - v0, gu - u0)]
        vv, uu = np.nonzero((sub > 0) & fg[np.ix_(gv - v0, gu - u0)])
        per_u.append(gu[uu])
        per_v.append(gv[vv])
        per_z.append(sub[vv, uu].astype(np.float64) / 1000.0)  # the depth the core will see
        per_f.append(np.full(len(vv), i, np.int64))
    if ref is None:
        raise InvalidValueError("frames: need at least one frame")
    F = len(images)
    crops = np.array(crop_list, np.int64).reshape(F, 2)
    node_uvz = np.array(uvz_list, float).reshape(F, n_all, 3)
    ssc_cam = np.array(ssc_list, float).reshape(F, 3)
    Rs = np.array(R_list, float).reshape(F, 3, 3)
    intr = np.array(intr_list, float).reshape(F, 4)
    if per_f:
        fi = np.concatenate(per_f)
        u = np.concatenate(per_u).astype(np.float64)
        v = np.concatenate(per_v).astype(np.float64)
        z = np.concatenate(per_z)
    else:
        fi = np.zeros(0, np.int64)
        u = v = z = np.zeros(0)
    P = len(fi)
    parts = np.empty((P, 3), np.int32)
    parts[:, 0] = fi
    parts[:, 1] = u - crops[fi, 0]
    parts[:, 2] = v - crops[fi, 1]
    fx, fy, cx, cy = intr[fi].T
    X = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], 1)
    offsets = (ssc_cam[fi] - X).astype(np.float32)
    rot = rotation_quaternion(Rs).astype(np.float32)[fi]
    ang = link_angles(node_uvz, links_used).astype(np.float32).reshape(F, len(links_used))[fi]
    c = np.stack([u, v, z], 1).astype(np.float32)
    # s: gather each part's frame nodes, then subtract in place (one (P, N, 3) float32 buffer:
    # ~230 MB for a million parts and 19 nodes).
    s = np.take(node_uvz[:, sel].astype(np.float32), fi, axis=0)  # (measured faster than fancy indexing)
    s -= c[:, None, :]
    s = s.reshape(P, 3 * len(sel))
    return TrainingSet(
        images,
        np.ascontiguousarray(parts),
        np.ascontiguousarray(offsets),
        np.ascontiguousarray(rot),
        np.ascontiguousarray(ang),
        s,
        crops,
    )

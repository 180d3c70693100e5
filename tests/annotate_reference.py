"""The straightforward per-part Python loop that ``build_training_set`` vectorises: the reference of
tests/test_annotate.py and the baseline of benches/bench_skeleton.py (one copy for both)."""

from __future__ import annotations

import math

import numpy as np


def loop_annotations(frame, stride: int, limit: int | None = None) -> list[tuple]:
    """Per foreground pixel on the ``stride`` grid (row-major, full-image coordinates), up to
    ``limit`` parts: ``(u, v, offset to the SSC, node offsets, link angles)``."""
    K, R, t = frame.intrinsics, frame.R, frame.t
    Xn = frame.skeleton.nodes @ R.T + t
    nodes = [(K.fx * X[0] / X[2] + K.cx, K.fy * X[1] / X[2] + K.cy, X[2]) for X in Xn]
    ssc = R @ frame.ssc + t
    out = []
    h, w = frame.depth.shape
    for v in range(0, h, stride):
        for u in range(0, w, stride):
            if not frame.mask[v, u] or frame.depth[v, u] <= 0:
                continue
            z = round(float(frame.depth[v, u]) * 1000) / 1000  # the millimetre depth the core sees
            X = np.array([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z])
            s = []
            for nu, nv, nz in nodes:
                s += [nu - u, nv - v, nz - z]
            angles = [math.atan2(nodes[k][1] - nodes[i][1], nodes[k][0] - nodes[i][0]) for i, k in frame.skeleton.links]
            angles = [a - 2 * math.pi if a >= math.pi else a for a in angles]  # [-pi, pi)
            out.append((u, v, ssc - X, s, angles))
            if limit is not None and len(out) >= limit:
                return out
    return out

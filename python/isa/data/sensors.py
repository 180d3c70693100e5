"""Depth frames as real sensors' datasets store them, read to float32 metres (0 = missing) with
their intrinsics where the dataset gives them: the formats of ``../shared/data/real_unannotated``
(its README) beside SUN RGB-D's own readers (:mod:`isa.data.sunrgbd`).

* TUM RGB-D: uint16 PNG, 5000 units per metre (:func:`read_tum_depth`; in ``Forest.predict``
  the raw PNG with ``depth_scale=0.2`` is the same).
* NYU Depth v2, Metric3D's copy: uint16 millimetre PNGs, intrinsics in ``test_annotations.json``
  (``cam_in`` = fx, fy, cx, cy) (:func:`read_nyu_annotated`).
* NYU Depth v2 raw Kinect frames (``.pgm``, as in Open3D's test data): 11-bit disparity, little
  endian, 2047 = no reading, depth = 351.3 / (1092.5 - d) metres, the NYU toolbox's
  ``depth_rel2depth_abs`` (:func:`read_nyu_pgm`).
* SUN RGB-D PNGs (bit-rotated millimetres): :func:`isa.data.sunrgbd.decode_sun_depth`; whole
  frames: :func:`isa.data.sunrgbd.read_native` / :func:`~isa.data.sunrgbd.read_processed`.

:func:`read_depth` picks the reader by name. Each raises :class:`isa.DataError` naming the file.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from isa.camera import Intrinsics
from isa.data.sunrgbd import _read_png16, decode_sun_depth
from isa.exceptions import DataError, DataNotFoundError

__all__ = [
    "TUM_UNITS_PER_METRE", "NYU_DISPARITY", "NYU_NO_READING", "NYU_MAX_DEPTH_M", "read_tum_depth", "read_nyu_pgm", "read_nyu_annotated",
    "read_depth",
]

#: TUM RGB-D's depth PNGs: units per metre.
TUM_UNITS_PER_METRE = 5000.0
#: NYU Depth v2's raw disparity to metres (the NYU toolbox's ``depth_rel2depth_abs``), its
#: "no reading" value and the toolbox's far clip.
NYU_DISPARITY = (351.3, 1092.5)
NYU_NO_READING = 2047
NYU_MAX_DEPTH_M = 10.0


def _exists(path: str | Path, what: str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise DataNotFoundError(f"{what} {p} does not exist")
    return p


def read_tum_depth(path: str | Path) -> np.ndarray:
    """A TUM RGB-D depth PNG (5000 units per metre) in float32 metres."""
    p = _exists(path, "TUM depth image")
    return (_read_png16(p) / TUM_UNITS_PER_METRE).astype(np.float32)


def read_nyu_pgm(path: str | Path) -> np.ndarray:
    """A raw NYU Depth v2 Kinect frame (binary PGM of 16-bit disparities) in float32 metres."""
    p = _exists(path, "NYU raw depth frame")
    b = p.read_bytes()
    m = re.match(rb"P5\s+(\d+)\s+(\d+)\s+(\d+)\s", b)
    if m is None or int(m[3]) < 256:
        raise DataError(f"NYU raw depth frame {p}: not a 16-bit binary PGM (P5 header)")
    w, h = int(m[1]), int(m[2])
    if len(b) - m.end() < 2 * w * h:
        raise DataError(f"NYU raw depth frame {p}: truncated ({len(b) - m.end()} bytes for {w}x{h} 16-bit pixels)")
    raw = np.frombuffer(b, dtype="<u2", count=w * h, offset=m.end()).reshape(h, w).astype(np.float64)
    a, c = NYU_DISPARITY
    with np.errstate(divide="ignore"):
        d = a / (c - raw)
    d[(raw >= NYU_NO_READING) | ~np.isfinite(d) | (d < 0)] = 0.0
    return np.minimum(d, NYU_MAX_DEPTH_M).astype(np.float32)


def read_nyu_annotated(folder: str | Path) -> list[tuple[Path, np.ndarray, Intrinsics]]:
    """Every frame of a Metric3D-style NYU folder (``test_annotations.json`` with ``cam_in`` and
    ``depth`` per file; ``depth_scale`` there is units per metre): (depth path, float32 metres,
    intrinsics), in the file's order."""
    root = Path(folder)
    ann = _exists(root / "test_annotations.json", "NYU annotation file")
    try:
        files = json.loads(ann.read_text())["files"]
    except (ValueError, KeyError, TypeError) as e:
        raise DataError(f"NYU annotation file {ann}: expected {{'files': [...]}}: {e}") from e
    out = []
    for i, f in enumerate(files):
        try:
            fx, fy, cx, cy = (float(v) for v in f["cam_in"])
            name = Path(f["depth"])
            per_metre = float(f.get("depth_scale", 1000.0))
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"NYU annotation file {ann}: files[{i}]: needs cam_in (4 numbers) and depth: {e}") from e
        path = _exists(root / "depth" / name.name, "NYU depth image")
        raw = _read_png16(path)
        k = Intrinsics(fx, fy, cx, cy, raw.shape[1], raw.shape[0])
        out.append((path, (raw / per_metre).astype(np.float32), k))
    return out


def read_depth(path: str | Path, kind: str) -> np.ndarray:
    """A depth file in float32 metres by ``kind``: ``"mm"`` (uint16 millimetre PNG: Kinect, NYU,
    BOP with depth_scale 1), ``"tum"``, ``"nyu-pgm"`` or ``"sun"`` (SUN RGB-D's bit-rotated PNG)."""
    readers = {
        "mm": lambda p: (_read_png16(_exists(p, "depth image")) / 1000.0).astype(np.float32),
        "tum": read_tum_depth,
        "nyu-pgm": read_nyu_pgm,
        "sun": lambda p: decode_sun_depth(_read_png16(_exists(p, "SUN depth image")), p),
    }
    if kind not in readers:
        raise DataError(f"read_depth: unknown kind {kind!r}; known: {sorted(readers)}")
    return readers[kind](path)

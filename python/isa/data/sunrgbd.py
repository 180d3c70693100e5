"""SUN RGB-D readers (which include the NYU Depth v2 / RMRC frames): native and processed layouts.

Both readers return a :class:`SceneFrame`:

* ``depth``: (H, W) float32 metres, 0 = missing, in the OpenCV camera frame of ``intrinsics``;
* ``intrinsics``: :class:`isa.camera.Intrinsics` with 0-based pixel centres (SUN RGB-D's MATLAB
  ``K`` counts pixels from 1, so ``cx``/``cy`` here are SUN's minus one; back-projecting ``depth``
  with them gives exactly SUN's point cloud);
* ``R_gravity``: 3x3, camera to upright, ``X_up = R_gravity @ X_cam``;
* ``boxes``: ground truth :class:`isa.evaluation.boxes3d.Box3D`, in the upright frame.

**Upright frame** (SUN RGB-D's "upright depth" frame, used by Sliding Shapes, Deep Sliding Shapes,
VoteNet, mmdetection3d): origin at the camera centre, ``z`` up against gravity, ``y`` the camera's
viewing direction levelled to the horizontal, ``x`` to its right (right-handed). Box yaw is about
``+z``, counter-clockwise from ``+x`` (see :mod:`isa.evaluation.boxes3d`).

Layouts (see ``../shared/data/README.md``):

* native ``SUNRGBD/<sensor>/<dataset>/<frame>/``: ``depth/*.png`` (or ``depth_bfx/*.png``,
  hole-filled) uint16 with SUN's bit rotation ``d = (v >> 3) | (v << 13)`` millimetres;
  ``intrinsics.txt`` (3x3 row-major); ``extrinsics/*.txt`` (3x4, the last file in name order as
  in the SUN RGB-D toolbox: rotation from the camera to the upright frame, both y down);
  ``annotation3Dfinal/index.json`` (per object a footprint polygon ``X``, ``Z`` and heights
  ``Ymin``..``Ymax``, upright frame with y down). Boxes follow the toolbox's
  ``readframeSUNRGBD``: centre at the midpoint of corners 0 and 2, the heading pointing from the
  centre to the middle of edge 0-1, classes ``name:detail`` reduced to ``name``, wall/floor/ceiling
  dropped. So both layouts give the same boxes for the same frame.
* processed ``sunrgbd_trainval/`` (VoteNet / mmdetection3d): ``depth/NNNNNN.mat`` (``instance``,
  N x 6 float32: upright points x, y, z then rgb), ``calib/NNNNNN.txt`` (``Rtilt`` and ``K``, 9
  numbers each, column-major), ``label/NNNNNN.txt`` (``class x y w h cx cy cz hw hl hh ox oy``).
  The depth image is rebuilt by projecting the points back into the camera: each point lands on
  an integer pixel (checked), so the image is exactly the one the cloud was made from.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from isa.camera import Intrinsics
from isa.evaluation.boxes3d import Box3D
from isa.exceptions import DataError, DataNotFoundError

__all__ = [
    "SceneFrame",
    "UPRIGHT_FROM_CAMERA_AXES",
    "read_native",
    "read_processed",
    "list_native",
    "list_processed",
    "iter_processed",
    "decode_sun_depth",
    "NON_OBJECT_CLASSES",
]

#: Axis permutation from the OpenCV camera frame (x right, y down, z forward) to the same axes
#: named as in the upright frame (x right, y forward, z up): the upright frame of a level camera.
UPRIGHT_FROM_CAMERA_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

#: Annotated "objects" that the SUN RGB-D toolbox leaves out of the 3D ground truth.
NON_OBJECT_CLASSES = frozenset({"wall", "floor", "ceiling"})

# A processed-layout point must project within this many pixels of an integer pixel (the calib
# files round Rtilt to 5 digits, which moves points by ~0.003 px).
_PIXEL_TOLERANCE = 0.05

# Native depth: share of valid pixels allowed to decode beyond 8.191 m. SUN's rotation leaves the
# low 3 bits of the stored value zero below that depth; a plain millimetre PNG sets them in ~7/8
# of the pixels.
_MAX_FAR_FRACTION = 0.05


@dataclass(frozen=True, eq=False)
class SceneFrame:
    """One real depth frame with its calibration and ground truth (see the module docstring).

    ``name``: the frame folder's name or the processed frame id; ``depth`` (H, W) float32 metres,
    0 = missing; ``intrinsics`` 0-based; ``R_gravity`` (3, 3) with ``X_up = R_gravity @ X_cam``;
    ``boxes`` ground-truth :class:`Box3D` in the upright frame; ``source`` the folder or .mat read.
    """

    name: str
    depth: np.ndarray
    intrinsics: Intrinsics
    R_gravity: np.ndarray
    boxes: tuple[Box3D, ...]
    source: Path

    def points_camera(self) -> np.ndarray:
        """Camera-frame points (N, 3) of the valid pixels, row-major pixel order."""
        return self.intrinsics.backproject(self.depth)[self.depth > 0]

    def points_upright(self) -> np.ndarray:
        """Upright-frame points (N, 3) of the valid pixels, row-major pixel order."""
        # einsum, not matmul: a (N, 3) @ (3, 3) BLAS call is slow on a busy machine.
        return np.einsum("ij,nj->ni", self.R_gravity, self.points_camera())

    def boxes_of(self, category: str) -> list[Box3D]:
        return [b for b in self.boxes if b.category == category]


# ----------------------------------------------------------------------------------------------
# Small readers with clear errors


def _load_matrix(path: Path, n: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise DataNotFoundError(f"{path}: missing {what}")
    try:
        values = np.array(path.read_text().split(), dtype=float)
    except ValueError as exc:
        raise DataError(f"{path}: {what} is not numeric ({exc})") from None
    if values.size != n or not np.all(np.isfinite(values)):
        raise DataError(f"{path}: {what} needs {n} finite numbers, found {values.size}")
    return values


def _check_rotation(R: np.ndarray, path: Path, what: str) -> None:
    # Files round to ~5 digits, so allow that much; anything worse is not a rotation.
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-3) and np.linalg.det(R) > 0):
        raise DataError(f"{path}: {what} is not a rotation matrix:\n{R}")


def decode_sun_depth(raw: np.ndarray, path: Path | str = "<array>") -> np.ndarray:
    """SUN RGB-D's stored uint16 depth -> float32 metres (0 = missing).

    The stored value is the millimetre depth rotated left by 3 bits; undo it with
    ``(v >> 3) | (v << 13)`` on 16 bits. Raises :class:`DataError` when the image is not uint16
    or does not carry the rotation (e.g. an already-decoded millimetre PNG).
    """
    raw = np.asarray(raw)
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise DataError(f"{path}: depth must be a single-channel uint16 image, got {raw.dtype} {raw.shape}")
    mm = (raw >> 3) | (raw << 13)  # uint16 arithmetic wraps, which is the rotation
    valid = raw > 0
    n = int(valid.sum())
    if n:
        far = int(np.count_nonzero(raw[valid] & 7))
        if far > _MAX_FAR_FRACTION * n:
            raise DataError(
                f"{path}: {100.0 * far / n:.0f}% of the pixels decode beyond 8.19 m: this is not "
                "SUN RGB-D's bit-rotated depth (a plain millimetre PNG?)"
            )
    return (mm.astype(np.float32) / np.float32(1000.0)).astype(np.float32)


def _read_png16(path: Path) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(path) as im:
            mode = im.mode
            arr = np.array(im)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read the depth PNG ({exc})") from None
    if mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise DataError(f"{path}: depth must be a 16-bit greyscale PNG, got mode {mode}")
    if arr.dtype != np.uint16:
        if arr.min() < 0 or arr.max() > 65535:
            raise DataError(f"{path}: depth values out of the uint16 range")
        arr = arr.astype(np.uint16)
    return arr


def _class_name(name: str) -> str:
    # SUN RGB-D toolbox getclassname: "chair:office" or "chair :office" -> "chair".
    name = name.split(":", 1)[0]
    return name.rstrip(" _")


# ----------------------------------------------------------------------------------------------
# Native layout


def _first_file(folder: Path, pattern: str, what: str, last: bool = False) -> Path:
    files = sorted(folder.glob(pattern)) if folder.is_dir() else []
    if not files:
        raise DataError(f"{folder}: no {what} ({pattern})")
    return files[-1] if last else files[0]


def _polygon_box(obj: dict, index: int, path: Path) -> Box3D:
    name = obj.get("name")
    if not isinstance(name, str) or not name:
        raise DataError(f"{path}: object {index} has no name")
    poly = obj["polygon"][0]
    if not isinstance(poly, dict):
        raise DataError(f"{path}: object {index} ({name}): polygon entry is {poly!r}, not an object")
    missing = [k for k in ("X", "Z", "Ymin", "Ymax") if k not in poly]
    if missing:
        raise DataError(f"{path}: object {index} ({name}): polygon lacks {', '.join(missing)}")
    nulls = [k for k in ("X", "Z", "Ymin", "Ymax")
             if poly[k] is None or (isinstance(poly[k], list) and any(v is None for v in poly[k]))]
    if nulls:
        raise DataError(f"{path}: object {index} ({name}): null polygon coordinates in {', '.join(nulls)}")
    try:
        X = np.array(poly["X"], dtype=float).reshape(-1)
        Z = np.array(poly["Z"], dtype=float).reshape(-1)
        ymin, ymax = float(poly["Ymin"]), float(poly["Ymax"])
    except (TypeError, ValueError):
        raise DataError(
            f"{path}: object {index} ({name}): non-numeric polygon coordinates "
            f"(X={poly['X']!r}, Z={poly['Z']!r}, Ymin={poly['Ymin']!r}, Ymax={poly['Ymax']!r})"
        ) from None
    if X.shape != Z.shape or X.size < 3 or not np.all(np.isfinite(np.r_[X, Z, ymin, ymax])):
        raise DataError(f"{path}: object {index} ({name}): footprint needs >= 3 finite (X, Z) corners, got {X.size}/{Z.size}")
    # Upright frame (y down) to ours: x = X, y = Z, z = -Y.
    xy = np.column_stack([X, Z])
    z0, z1 = -ymax, -ymin
    if not z1 > z0:
        raise DataError(f"{path}: object {index} ({name}): empty height range Ymin={ymin}, Ymax={ymax}")
    if len(xy) == 4:
        # SUN RGB-D toolbox rule (readframeSUNRGBD): corners 0-1-2 span the rectangle.
        centre = 0.5 * (xy[0] + xy[2])
        e01 = np.linalg.norm(xy[1] - xy[0])
        e12 = np.linalg.norm(xy[2] - xy[1])
        front = 0.5 * (xy[0] + xy[1]) - centre
        if e01 <= 0 or e12 <= 0 or np.linalg.norm(front) == 0:
            raise DataError(f"{path}: object {index} ({name}): degenerate footprint {xy.tolist()}")
        yaw = math.atan2(front[1], front[0])
        length, width = e12, e01
    else:
        centre, length, width, yaw = _min_area_rectangle(xy)
    return Box3D(_class_name(name), [centre[0], centre[1], 0.5 * (z0 + z1)], [length, width, z1 - z0], yaw,
                 meta={"object_index": index})


def _min_area_rectangle(xy: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Smallest-area enclosing rectangle of a non-4-corner footprint (one edge on the convex hull)."""
    from scipy.spatial import ConvexHull

    hull = xy[ConvexHull(xy).vertices]
    best = None
    for i in range(len(hull)):
        e = hull[(i + 1) % len(hull)] - hull[i]
        yaw = math.atan2(e[1], e[0])
        c, s = math.cos(yaw), math.sin(yaw)
        local = hull @ np.array([[c, -s], [s, c]])
        lo, hi = local.min(0), local.max(0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            mid = 0.5 * (lo + hi)
            best = (area, np.array([c * mid[0] - s * mid[1], s * mid[0] + c * mid[1]]), hi[0] - lo[0], hi[1] - lo[1], yaw)
    return best[1], best[2], best[3], best[4]


def _read_annotation(path: Path) -> tuple[Box3D, ...]:
    if not path.is_file():
        raise DataNotFoundError(f"{path}: missing 3D annotation (annotation3Dfinal/index.json); "
                        "pass annotations=False to read the frame without boxes")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot parse the annotation JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("objects"), list):
        raise DataError(f"{path}: annotation must be an object with an 'objects' list, got {type(data).__name__}")
    boxes = []
    for i, obj in enumerate(data["objects"]):
        # Null objects and objects without a 3D polygon are deleted or 2D-only labels in SUN's
        # annotation tool; the toolbox skips them, and so do we. Nulls *inside* a polygon are errors.
        if obj is None:
            continue
        if not isinstance(obj, dict):
            raise DataError(f"{path}: object {i} is {obj!r}, not an object")
        if not obj.get("polygon"):
            continue
        if not isinstance(obj["polygon"], list):
            raise DataError(f"{path}: object {i}: 'polygon' must be a list, got {obj['polygon']!r}")
        box = _polygon_box(obj, i, path)
        if box.category not in NON_OBJECT_CLASSES:
            boxes.append(box)
    return tuple(boxes)


def read_native(folder: str | Path, filled: bool = False, annotations: bool = True) -> SceneFrame:
    """Read one frame folder of the native SUN RGB-D layout (e.g. ``kv1/NYUdata/NYU0001``).

    ``filled``: read ``depth_bfx`` (SUN's hole-filled depth) instead of the raw ``depth`` (the
    processed VoteNet layout is made from the raw one: its clouds keep the holes). Depth is not
    clipped; SUN's toolbox clips it at 8 m when it builds point clouds.
    ``annotations``: read ``annotation3Dfinal/index.json`` (required then); False gives no boxes.
    Raises :class:`DataError` naming the file for anything missing or malformed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataNotFoundError(f"{folder}: SUN RGB-D frame folder not found")
    depth_path = _first_file(folder / ("depth_bfx" if filled else "depth"), "*.png", "depth PNG")
    depth = decode_sun_depth(_read_png16(depth_path), depth_path)
    K = _load_matrix(folder / "intrinsics.txt", 9, "intrinsics (3x3)").reshape(3, 3)
    ext_path = _first_file(folder / "extrinsics", "*.txt", "extrinsics file", last=True)
    ext = _load_matrix(ext_path, 12, "extrinsics (3x4)").reshape(3, 4)[:, :3]
    _check_rotation(ext, ext_path, "extrinsics rotation")
    h, w = depth.shape
    intr = _intrinsics_from_sun_K(K, w, h, folder / "intrinsics.txt")
    # The extrinsics rotate the y-down camera frame into the y-down upright frame.
    R_gravity = UPRIGHT_FROM_CAMERA_AXES @ ext
    boxes = _read_annotation(folder / "annotation3Dfinal" / "index.json") if annotations else ()
    return SceneFrame(folder.name, depth, intr, R_gravity, boxes, folder)


def _intrinsics_from_sun_K(K: np.ndarray, width: int, height: int, path: Path) -> Intrinsics:
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1]) and K[1, 0] == 0 and K[0, 1] == 0):
        raise DataError(f"{path}: not a pinhole K [[fx 0 cx] [0 fy cy] [0 0 1]]:\n{K}")
    # SUN's K is for 1-based MATLAB pixel indices (read_3d_pts_general uses meshgrid(1:W)).
    return Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) - 1.0, float(K[1, 2]) - 1.0, int(width), int(height))


def list_native(root: str | Path) -> list[Path]:
    """All native frame folders under ``root`` (folders holding an ``intrinsics.txt``), sorted."""
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(f"{root}: SUN RGB-D folder not found")
    return sorted(p.parent for p in root.rglob("intrinsics.txt"))


# ----------------------------------------------------------------------------------------------
# Processed (VoteNet / mmdetection3d) layout


def _frame_id(index: int | str) -> str:
    return f"{int(index):06d}" if isinstance(index, (int, np.integer)) or str(index).isdigit() else str(index)


def _read_points(path: Path) -> np.ndarray:
    if not path.is_file():
        raise DataNotFoundError(f"{path}: missing point cloud")
    from scipy.io import loadmat

    try:
        mat = loadmat(path, variable_names=["instance"])
    except NotImplementedError:
        raise DataError(f"{path}: MATLAB v7.3 (HDF5) file; isa reads the v5 .mat files of the VoteNet export") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read the .mat file ({exc})") from None
    pts = mat.get("instance")
    if pts is None:
        raise DataError(f"{path}: no 'instance' array")
    pts = np.asarray(pts)
    if pts.ndim != 2 or pts.shape[1] < 3 or not np.issubdtype(pts.dtype, np.floating):
        raise DataError(f"{path}: 'instance' must be a float N x 6 array, got {pts.dtype} {pts.shape}")
    return pts


def _read_labels(path: Path) -> tuple[Box3D, ...]:
    if not path.is_file():
        raise DataNotFoundError(f"{path}: missing label file")
    boxes = []
    for ln, line in enumerate(path.read_text().splitlines(), 1):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) < 13:
            raise DataError(f"{path}:{ln}: expected 'class x y w h cx cy cz hw hl hh ox oy', got {line!r}")
        # Class names may hold spaces; the 12 numbers are always last.
        name = " ".join(tokens[:-12])
        try:
            v = np.array(tokens[-12:], dtype=float)
        except ValueError:
            raise DataError(f"{path}:{ln}: non-numeric box values in {line!r}") from None
        cx, cy, cz, hw, hl, hh, ox, oy = v[4:]
        if not (np.all(np.isfinite(v)) and hw > 0 and hl > 0 and hh > 0 and (ox or oy)):
            raise DataError(f"{path}:{ln}: invalid box (half sizes must be > 0, orientation non-zero): {line!r}")
        # Toolbox export: hw is half the edge 0-1, hl half the edge 1-2 along the orientation
        # vector (ox, oy), the heading (VoteNet's heading angle is -atan2(oy, ox), clockwise).
        boxes.append(Box3D(name, [cx, cy, cz], [2 * hl, 2 * hw, 2 * hh], math.atan2(oy, ox), meta={"line": ln}))
    return tuple(boxes)


def read_processed(root: str | Path, index: int | str) -> SceneFrame:
    """Read frame ``index`` (e.g. ``1`` or ``"000001"``) of a processed ``sunrgbd_trainval`` folder,
    or of a folder holding one frame's files side by side (``calib_000005.txt``,
    ``depth_000005.mat``, ``images_000005.jpg``).

    The depth image is rebuilt from the point cloud: each upright point goes back to the camera
    frame (inverse of ``Rtilt``, then axes to OpenCV) and is projected with ``K``; it must land on
    an integer pixel inside the image, one point per pixel. The image size is the JPEG's in
    ``image/`` when present, else the smallest one holding every point and the principal point.
    """
    root = Path(root)
    fid = _frame_id(index)
    # The trainval layout (calib/000005.txt, depth/000005.mat, ...) or one frame's files side by
    # side (calib_000005.txt, depth_000005.mat, images_000005.jpg, as in real_unannotated).
    side_by_side = not (root / "calib").is_dir() and (root / f"calib_{fid}.txt").is_file()
    where = {k: root / (f"{k if k != 'image' else 'images'}_{fid}.{x}" if side_by_side else f"{k}/{fid}.{x}")
             for k, x in (("calib", "txt"), ("depth", "mat"), ("image", "jpg"), ("label", "txt"))}
    calib_path = where["calib"]
    if not calib_path.is_file():
        raise DataError(f"{calib_path}: missing calibration (Rtilt and K) for frame {fid}")
    lines = [ln.split() for ln in calib_path.read_text().splitlines() if ln.strip()]
    if len(lines) < 2 or len(lines[0]) != 9 or len(lines[1]) != 9:
        raise DataError(f"{calib_path}: expected two lines of 9 numbers (Rtilt, K column-major)")
    try:
        Rtilt = np.array(lines[0], dtype=float).reshape(3, 3, order="F")
        K = np.array(lines[1], dtype=float).reshape(3, 3, order="F")
    except ValueError:
        raise DataError(f"{calib_path}: non-numeric calibration") from None
    _check_rotation(Rtilt, calib_path, "Rtilt")
    R_gravity = Rtilt @ UPRIGHT_FROM_CAMERA_AXES

    mat_path = where["depth"]
    pts = _read_points(mat_path)[:, :3].astype(np.float64)
    # Invert rather than transpose: the rounded Rtilt is not exactly orthogonal, and the same
    # matrix must be used both ways for the reconstruction to reproduce the cloud.
    cam = np.einsum("ij,nj->ni", np.linalg.inv(R_gravity), pts)
    if np.any(cam[:, 2] <= 0):
        raise DataError(f"{mat_path}: {int(np.sum(cam[:, 2] <= 0))} points behind the camera (wrong Rtilt?)")
    u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2] - 1.0  # 1-based MATLAB pixels -> 0-based
    v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2] - 1.0
    ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    off = np.maximum(np.abs(u - ui), np.abs(v - vi))
    if off.size and off.max() > _PIXEL_TOLERANCE:
        raise DataError(
            f"{mat_path}: points project up to {off.max():.3f} px away from integer pixels with {calib_path.name}: "
            "not a full-frame SUN RGB-D cloud (subsampled or augmented?) or the wrong calibration"
        )
    width, height = _image_size(where["image"], K, ui, vi)
    if ui.size and (ui.min() < 0 or vi.min() < 0 or ui.max() >= width or vi.max() >= height):
        raise DataError(f"{mat_path}: points project outside the {width}x{height} image")
    depth = np.zeros((height, width), dtype=np.float32)
    flat = vi * width + ui
    if np.unique(flat).size != flat.size:
        raise DataError(f"{mat_path}: several points project onto the same pixel; not a single depth image")
    depth.reshape(-1)[flat] = cam[:, 2]
    intr = _intrinsics_from_sun_K(K, width, height, calib_path)
    # Unannotated frames (a side-by-side folder without a label file) have no boxes.
    boxes = () if side_by_side and not where["label"].is_file() else _read_labels(where["label"])
    return SceneFrame(fid, depth, intr, R_gravity, boxes, mat_path)


def _image_size(jpg: Path, K: np.ndarray, ui: np.ndarray, vi: np.ndarray) -> tuple[int, int]:
    if jpg.is_file():
        from PIL import Image

        try:
            with Image.open(jpg) as im:
                return im.size
        except OSError as exc:
            raise DataError(f"{jpg}: cannot read the image ({exc})") from None
    # Without the image, guess a principal point at the image centre, (W - 1) / 2 in 0-based
    # pixels, and never crop a point.
    w = max(int(ui.max()) + 1 if ui.size else 0, int(round(2 * (K[0, 2] - 1) + 1)))
    h = max(int(vi.max()) + 1 if vi.size else 0, int(round(2 * (K[1, 2] - 1) + 1)))
    return w, h


def list_processed(root: str | Path) -> list[str]:
    """Frame ids (``"000001"``, ...) of a processed folder that have a calibration file."""
    root = Path(root)
    if not (root / "calib").is_dir():
        raise DataError(f"{root}: no calib/ folder; not a processed sunrgbd_trainval layout")
    return sorted(p.stem for p in (root / "calib").glob("*.txt"))


def iter_processed(root: str | Path) -> Iterator[SceneFrame]:
    """Every frame of a processed folder, in id order."""
    for fid in list_processed(root):
        yield read_processed(root, fid)

"""BOP scenewise format: write and read (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md).

Layout written here (readable by other BOP tools)::

    <root>/models/obj_000001.ply          mesh in millimetres (object frame)
    <root>/models/models_info.json        {"1": {"diameter", "min_x", "size_x", ...}} in mm
    <root>/models/models_isa.json         isa's extras per object (category, source, scale, skeleton)
    <root>/<split>/<scene:06d>/scene_camera.json   {"0": {"cam_K": [9], "depth_scale": s}}
    <root>/<split>/<scene:06d>/scene_gt.json       {"0": [{"cam_R_m2c": [9], "cam_t_m2c": [3] mm, "obj_id": k}]}
    <root>/<split>/<scene:06d>/scene_gt_info.json  {"0": [{"bbox_obj": [x, y, w, h], "px_count_all": n, ...}]}
    <root>/<split>/<scene:06d>/depth/000000.png    uint16, depth_mm = value * depth_scale
    <root>/<split>/<scene:06d>/mask/000000_000000.png   uint8 0/255, <image>_<gt index>

Every file is written atomically (:mod:`isa.atomic`), so a crash never leaves a half-written
file; a scene's stale temporary files go when its writer opens. ``scene_gt.json`` is the commit record of a frame: a frame counts as written
only when its entry is there and its PNGs exist.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from isa import atomic
from isa.camera import Intrinsics, metres_to_mm
from isa.exceptions import DataError, DataNotFoundError, InvalidValueError

__all__ = [
    "MAX_DEPTH_UNITS", "write_json", "read_json", "depth_to_png", "png_to_depth", "model_info", "model_path", "write_model", "read_model",
    "BopFrame", "scene_dir", "SceneWriter", "list_scenes", "list_frames", "read_frame", "read_scene", "FrameSequence", "MappedFrames",
    "frame_obj_ids", "write_models_info", "read_models_info",
]

#: Largest depth a uint16 PNG holds with ``depth_scale`` = 1 (millimetres).
MAX_DEPTH_UNITS = 65535


# ---------------------------------------------------------------------------------------------
# Atomic file helpers
# ---------------------------------------------------------------------------------------------


def _atomic_write(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path`` (:mod:`isa.atomic`; a scene's folders are
    cleaned of stale temporary files once, by :class:`SceneWriter`)."""
    atomic.write_with(path, write, parents=True, clean=False)


def write_json(path: str | Path, data) -> None:
    """Write ``data`` as JSON atomically (floats keep their exact repr, so reading gives them back)."""
    text = json.dumps(data, indent=1, sort_keys=False)
    _atomic_write(Path(path), lambda tmp: Path(tmp).write_text(text))


def read_json(path: str | Path):
    """Read a JSON file; ``DataError`` naming the file when it is missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"BOP file not found: {path}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"BOP file {path} is not valid JSON: {exc}") from exc


def write_png(path: Path, array: np.ndarray) -> None:
    """Write a uint8/uint16 image as PNG atomically (temporary name, then rename)."""
    # compress_level=1: PNG stays lossless; level 1 is ~2x faster than the default for depth maps.
    _atomic_write(path, lambda tmp: Image.fromarray(array).save(tmp, format="PNG", compress_level=1))


def read_png(path: Path) -> np.ndarray:
    """Read a PNG; ``DataError`` naming it when missing or corrupt."""
    if not path.is_file():
        raise DataNotFoundError(f"BOP image not found: {path}")
    try:
        with Image.open(path) as im:
            return np.asarray(im)
    except Exception as exc:
        raise DataError(f"BOP image {path} is corrupt: {exc}") from exc


# ---------------------------------------------------------------------------------------------
# Depth encoding
# ---------------------------------------------------------------------------------------------


def depth_to_png(depth_m: np.ndarray, depth_scale: float = 1.0) -> np.ndarray:
    """float metres -> uint16 PNG values (``value * depth_scale`` = millimetres; 0 = missing).

    Raises ``ValueError`` when a depth does not fit in uint16 at this scale.
    """
    v = metres_to_mm(np.asarray(depth_m, dtype=np.float64), depth_scale)
    if v.size and v.max() > MAX_DEPTH_UNITS:
        raise InvalidValueError(f"depth {v.max() * depth_scale / 1000:.2f} m exceeds uint16 at depth_scale={depth_scale}")
    return np.where(np.isfinite(v) & (v > 0), v, 0).astype(np.uint16)


def png_to_depth(values: np.ndarray, depth_scale: float = 1.0) -> np.ndarray:
    """uint16 PNG values -> float32 metres."""
    return (np.asarray(values, dtype=np.float64) * (depth_scale / 1000.0)).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Models
# ---------------------------------------------------------------------------------------------


def model_info(mesh_m: trimesh.Trimesh) -> dict:
    """BOP ``models_info`` entry (millimetres) of a mesh given in metres."""
    v = np.asarray(mesh_m.vertices) * 1000.0
    lo, hi = v.min(0), v.max(0)
    # The diameter is attained between convex-hull vertices: exact and O(h^2) instead of O(n^2).
    try:
        hv = mesh_m.convex_hull.vertices * 1000.0
    except Exception:  # flat/degenerate meshes have no 3D hull
        hv = v
    if len(hv) > 4000:
        hv = hv[np.random.default_rng(0).choice(len(hv), 4000, replace=False)]
    diam = max(float(np.sqrt(((hv[i] - hv[i:]) ** 2).sum(1)).max()) for i in range(len(hv)))
    return {
        "diameter": diam,
        "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
        "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2]),
    }


def model_path(root: str | Path, obj_id: int) -> Path:
    return Path(root) / "models" / f"obj_{obj_id:06d}.ply"


def write_model(root: str | Path, obj_id: int, mesh_m: trimesh.Trimesh) -> Path:
    """Write ``mesh_m`` (metres) as ``models/obj_<id>.ply`` in millimetres; returns the path."""
    path = model_path(root, obj_id)
    mm = mesh_m.copy()
    mm.apply_scale(1000.0)
    _atomic_write(path, lambda tmp: mm.export(tmp, file_type="ply"))
    return path


def read_model(root: str | Path, obj_id: int) -> trimesh.Trimesh:
    """Read ``models/obj_<id>.ply`` back in metres."""
    from isa.data.meshes import load_mesh

    mesh = load_mesh(model_path(root, obj_id))
    mesh.apply_scale(0.001)
    return mesh


# ---------------------------------------------------------------------------------------------
# Frames
# ---------------------------------------------------------------------------------------------


@dataclass
class BopFrame:
    """One image of a scene with its single object: depth float32 m, mask bool, pose in metres."""

    scene_id: int
    im_id: int
    depth: np.ndarray
    mask: np.ndarray
    intrinsics: Intrinsics
    R: np.ndarray
    t: np.ndarray
    obj_id: int
    depth_scale: float = 1.0


def scene_dir(root: str | Path, split: str, scene_id: int) -> Path:
    return Path(root) / split / f"{scene_id:06d}"


def _bbox(mask: np.ndarray) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


class SceneWriter:
    """Writes the frames of one BOP scene; frames already on disk are reported by :meth:`has_frame`.

    JSON files are flushed every ``flush_every`` frames and on :meth:`close` (also when used as a
    context manager), atomically; a crash loses at most the unflushed frames, which are simply
    rendered again on resume. :meth:`write_frame` may be called from several threads.
    """

    def __init__(self, root: str | Path, split: str, scene_id: int, depth_scale: float = 1.0, flush_every: int = 16):
        self.dir = scene_dir(root, split, scene_id)
        self.scene_id = scene_id
        self.depth_scale = float(depth_scale)
        self.flush_every = flush_every
        (self.dir / "depth").mkdir(parents=True, exist_ok=True)
        (self.dir / "mask").mkdir(parents=True, exist_ok=True)
        for d in (self.dir, self.dir / "depth", self.dir / "mask"):
            atomic.clean_stale_in(d)  # a killed run's half-written frames
        self.camera = read_json(self.dir / "scene_camera.json") if (self.dir / "scene_camera.json").is_file() else {}
        self.gt = read_json(self.dir / "scene_gt.json") if (self.dir / "scene_gt.json").is_file() else {}
        self.gt_info = read_json(self.dir / "scene_gt_info.json") if (self.dir / "scene_gt_info.json").is_file() else {}
        self._pending = 0
        self._lock = threading.Lock()

    def depth_path(self, im_id: int) -> Path:
        return self.dir / "depth" / f"{im_id:06d}.png"

    def mask_path(self, im_id: int, gt_index: int = 0) -> Path:
        return self.dir / "mask" / f"{im_id:06d}_{gt_index:06d}.png"

    def has_frame(self, im_id: int) -> bool:
        """True when frame ``im_id`` is committed (JSON entries and PNGs all present)."""
        k = str(im_id)
        return k in self.gt and k in self.camera and self.depth_path(im_id).is_file() and self.mask_path(im_id).is_file()

    def write_frame(self, im_id: int, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, R, t_m, obj_id: int) -> None:
        """Write one frame: depth (float metres), mask (bool), pose R (3x3) / t (metres)."""
        mask = np.asarray(mask, dtype=bool)
        write_png(self.depth_path(im_id), depth_to_png(depth_m, self.depth_scale))
        write_png(self.mask_path(im_id), mask.astype(np.uint8) * 255)
        k = str(im_id)
        n = int(mask.sum())
        bb = _bbox(mask)
        cam = {"cam_K": [float(x) for x in intrinsics.K.reshape(-1)], "depth_scale": self.depth_scale,
               "width": int(intrinsics.width), "height": int(intrinsics.height)}
        gt = [{
            "cam_R_m2c": [float(x) for x in np.asarray(R, dtype=float).reshape(-1)],
            "cam_t_m2c": [float(x) * 1000.0 for x in np.asarray(t_m, dtype=float).reshape(-1)],
            "obj_id": int(obj_id),
        }]
        # Single-object, clutter-free frames: everything rendered is visible.
        info = [{"bbox_obj": bb, "bbox_visib": bb, "px_count_all": n, "px_count_valid": n,
                 "px_count_visib": n, "visib_fract": 1.0 if n else 0.0}]
        with self._lock:
            self.camera[k], self.gt[k], self.gt_info[k] = cam, gt, info
            self._pending += 1
            if self._pending >= self.flush_every:
                self._flush_locked()

    def flush(self) -> None:
        """Write the JSON files now (atomically)."""
        with self._lock:
            self._flush_locked()

    def _flush_locked(self) -> None:
        order = lambda d: {k: d[k] for k in sorted(d, key=int)}  # noqa: E731
        write_json(self.dir / "scene_camera.json", order(self.camera))
        write_json(self.dir / "scene_gt_info.json", order(self.gt_info))
        # scene_gt.json last: it is the commit record.
        write_json(self.dir / "scene_gt.json", order(self.gt))
        self._pending = 0

    def close(self) -> None:
        """Flush what is pending (the writer holds no open files)."""
        if self._pending:
            self.flush()

    def __enter__(self) -> "SceneWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def list_scenes(root: str | Path, split: str) -> list[int]:
    """Scene ids present under ``<root>/<split>`` (folders with a ``scene_gt.json``)."""
    d = Path(root) / split
    if not d.is_dir():
        raise DataNotFoundError(f"BOP split folder not found: {d}")
    return sorted(int(p.name) for p in d.iterdir() if p.is_dir() and p.name.isdigit() and (p / "scene_gt.json").is_file())


def list_frames(root: str | Path, split: str, scene_id: int) -> list[int]:
    """Image ids committed in a scene (keys of ``scene_gt.json``), sorted."""
    return sorted(int(k) for k in read_json(scene_dir(root, split, scene_id) / "scene_gt.json"))


def read_frame(root: str | Path, split: str, scene_id: int, im_id: int, _cache: dict | None = None) -> BopFrame:
    """Read one frame (the first ground-truth object of the image) back from disk."""
    d = scene_dir(root, split, scene_id)
    cams = _cache["camera"] if _cache else read_json(d / "scene_camera.json")
    gts = _cache["gt"] if _cache else read_json(d / "scene_gt.json")
    k = str(im_id)
    if k not in gts or k not in cams:
        raise DataError(f"BOP scene {d}: image {im_id} is not in scene_gt.json / scene_camera.json")
    cam, gt = cams[k], gts[k][0]
    scale = float(cam.get("depth_scale", 1.0))
    values = read_png(d / "depth" / f"{im_id:06d}.png")
    if "width" in cam:
        w, h = int(cam["width"]), int(cam["height"])
    else:
        h, w = values.shape
    mask = read_png(d / "mask" / f"{im_id:06d}_000000.png") > 0
    return BopFrame(
        scene_id=scene_id, im_id=im_id, depth=png_to_depth(values, scale), mask=mask,
        intrinsics=Intrinsics.from_K(cam["cam_K"], w, h),
        R=np.array(gt["cam_R_m2c"], dtype=float).reshape(3, 3),
        t=np.array(gt["cam_t_m2c"], dtype=float) / 1000.0,
        obj_id=int(gt["obj_id"]), depth_scale=scale,
    )


def read_scene(root: str | Path, split: str, scene_id: int) -> list[BopFrame]:
    """All committed frames of a scene, in image-id order."""
    d = scene_dir(root, split, scene_id)
    cache = {"camera": read_json(d / "scene_camera.json"), "gt": read_json(d / "scene_gt.json")}
    return [read_frame(root, split, scene_id, i, cache) for i in sorted(int(k) for k in cache["gt"])]


class _LazyFrames(Sequence):
    """A sequence of frames made when indexed; ``obj_ids`` (one per frame) is known up front."""

    obj_ids: list[int]

    def __len__(self) -> int:
        return len(self.obj_ids)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._frame(k) for k in range(*i.indices(len(self)))]
        return self._frame(i)

    def _frame(self, i: int) -> BopFrame:
        raise NotImplementedError


class FrameSequence(_LazyFrames):
    """The frames of a BOP split, each read from disk when it is asked for and not kept.

    A training set of thousands of 640x480 views (1.5 MB each in memory) then never sits in
    memory whole; :func:`isa.privileged.annotate.build_training_set` keeps only each view's crop. Frames come in
    scene then image order, as :func:`read_scene` gives them; ``obj_ids`` lists each frame's
    object from the scenes' ``scene_gt.json`` without reading an image.
    """

    def __init__(self, root: str | Path, split: str) -> None:
        self.root, self.split = Path(root), split
        self._keys: list[tuple[int, int]] = []
        self._cache: dict[int, dict] = {}
        self.obj_ids = []
        for sid in list_scenes(root, split):
            d = scene_dir(root, split, sid)
            cache = {"camera": read_json(d / "scene_camera.json"), "gt": read_json(d / "scene_gt.json")}
            self._cache[sid] = cache
            for im in sorted(int(k) for k in cache["gt"]):
                self._keys.append((sid, im))
                self.obj_ids.append(int(cache["gt"][str(im)][0]["obj_id"]))

    @property
    def keys(self) -> list[tuple[int, int]]:
        """``(scene id, image id)`` of every frame, in order."""
        return list(self._keys)

    def _frame(self, i: int) -> BopFrame:
        sid, im = self._keys[i]
        return read_frame(self.root, self.split, sid, im, self._cache[sid])


class MappedFrames(_LazyFrames):
    """Frames computed on access from another sequence: item ``k`` is ``fn(base[i])`` for
    ``(i, fn) = items[k]`` (``base[i]`` itself when ``fn`` is None). Mirrored or relabelled copies
    of a training set (:mod:`isa.privileged.mirror`, :mod:`isa.privileged.symmetry`) then cost no memory until used."""

    def __init__(self, base: Sequence[BopFrame], items: list[tuple[int, Callable[[BopFrame], BopFrame] | None]]) -> None:
        self.base, self.items = base, items
        ids = frame_obj_ids(base)
        self.obj_ids = [ids[i] for i, _ in items]

    def _frame(self, k: int) -> BopFrame:
        i, fn = self.items[k]
        f = self.base[i]
        return f if fn is None else fn(f)


def frame_obj_ids(frames: Sequence[BopFrame]) -> list[int]:
    """Each frame's ``obj_id``, without reading images when ``frames`` is lazy."""
    ids = getattr(frames, "obj_ids", None)
    return list(ids) if ids is not None else [f.obj_id for f in frames]


def write_models_info(root: str | Path, infos: dict[int, dict]) -> None:
    """Write ``models/models_info.json`` ({obj_id: model_info}) atomically."""
    write_json(Path(root) / "models" / "models_info.json", {str(k): infos[k] for k in sorted(infos)})


def read_models_info(root: str | Path) -> dict[int, dict]:
    return {int(k): v for k, v in read_json(Path(root) / "models" / "models_info.json").items()}

"""Scenes to disk in the BOP format (the layout of docs/scenes, readable by bop_toolkit):
multi-object ``scene_gt.json``, ``scene_gt_info.json`` computed as bop_toolkit's
``scripts/calc_gt_info.py`` does, ``mask/`` and ``mask_visib/`` per instance, ``models/`` with
``models_info.json`` (diameter, extents, turn symmetries) and ``camera.json``.

What bop_toolkit does and is done here the same way: each instance is rendered alone; its mask
is where that render has depth; ``px_count_all`` counts its whole silhouette, also outside the
image (rendered on a canvas 3x the image when the object is cut by the image border);
``px_count_valid`` the silhouette's pixels where the stored depth is valid; the visible mask
is where the instance's distance (along the pixel's ray) is at most ``DELTA_MM`` = 15 mm behind
the scene's (the "bop19" rule); ``visib_fract`` = visible / all; boxes ``(x, y, w, h)`` with
``w = x_max - x_min`` as its ``calc_2d_bbox``, ``[-1, -1, -1, -1]`` when nothing is visible.
One deliberate difference: visibility is tested against the clean rendered scene, not the noisy
stored depth, because Kinect noise at 3-4 m (sigma 2-3 cm) exceeds the 15 mm tolerance and would
count visible surface as hidden; with ``noise=False`` the two are the same depth.

Writing is resumable and never leaves a half-written frame: every file is written to a temporary
name and renamed; a frame's PNGs come first and its JSON entries last (``scene_gt.json`` last of
all: it is the commit record). A rerun skips committed frames; scenes and their views are drawn
from ``(seed, scene_id)`` alone, so a rerun, a resumed run and a fresh run give the same bytes.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from tqdm.auto import tqdm

from isa.data import bop
from isa.camera import Intrinsics
from isa.render.dataset import ObjectSpec
from isa.exceptions import DataError
from isa.render.noise import KinectNoise, apply_kinect_noise
from isa.scenes.cameras import Camera, CameraRig, sample_camera
from isa.scenes.rooms import Room, RoomParams, make_room
from isa.privileged.symmetry import YawSymmetry, find_yaw_symmetry

#: bop_toolkit's visibility tolerance (calc_gt_info.py ``delta``), millimetres.
DELTA_MM = 15.0
#: Settings file of a split: a resumed run must use the same ones.
SETTINGS_FILE = "isa_scenes.json"


# ---------------------------------------------------------------------------------------------
# What a scene holds
# ---------------------------------------------------------------------------------------------


@dataclass(eq=False)
class SceneObject:
    """A BOP model: ``size`` (3,) and ``box_min`` (3,) the axis-aligned box in its object frame
    (metres), the mesh when there is one (written as ``models/obj_<id>.ply``), its turn symmetry."""

    obj_id: int
    category: str
    source: str
    size: np.ndarray
    box_min: np.ndarray
    mesh: trimesh.Trimesh | None = None
    symmetry: YawSymmetry | None = None

    @classmethod
    def from_spec(cls, obj: ObjectSpec) -> "SceneObject":
        lo, hi = obj.mesh.bounds
        return cls(obj.obj_id, obj.category, obj.source, hi - lo, lo, obj.mesh, _symmetry(obj.mesh))


_SYMMETRIES: dict[tuple[int, int], YawSymmetry] = {}


def _symmetry(mesh: trimesh.Trimesh) -> YawSymmetry:
    """find_yaw_symmetry, once per mesh content (the search takes seconds; every dataset root
    a source's instances go to asks again)."""
    key = (hash(mesh), len(mesh.vertices))  # trimesh's content hash
    if key not in _SYMMETRIES:
        if len(_SYMMETRIES) > 512:
            _SYMMETRIES.clear()
        _SYMMETRIES[key] = find_yaw_symmetry(mesh)
    return _SYMMETRIES[key]


def symmetries_entry(sym: YawSymmetry | None) -> dict:
    """A turn group as BOP writes it: ``symmetries_discrete`` (4x4 row-major, mm; the identity
    left out) or ``symmetries_continuous`` (axis and a point on it, mm); ``{}`` for none."""
    if sym is None or not sym.is_symmetric:
        return {}
    c = np.asarray(sym.centre, float)
    if sym.order == 0:
        return {"symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": (1000.0 * c).tolist()}]}
    out = []
    for a in sym.angles()[1:]:
        T = np.eye(4)
        T[:3, :3] = [[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
        T[:3, 3] = 1000.0 * (c - T[:3, :3] @ c)  # the turn about the vertical axis through c
        out.append([float(x) for x in T.reshape(-1)])
    return {"symmetries_discrete": out}


def models_info_entry(o: SceneObject) -> dict:
    """``models_info.json`` entry: BOP's fields (mm) plus ``isa_category`` and ``isa_source``."""
    if o.mesh is not None:
        info = bop.model_info(o.mesh)
    else:  # a box only: its diagonal is the diameter
        lo, s = 1000.0 * np.asarray(o.box_min, float), 1000.0 * np.asarray(o.size, float)
        info = {"diameter": float(np.linalg.norm(s)), "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
                "size_x": float(s[0]), "size_y": float(s[1]), "size_z": float(s[2])}
    info.update(symmetries_entry(o.symmetry))
    info["isa_category"] = o.category
    info["isa_source"] = o.source
    return info


@dataclass(eq=False)
class Placement:
    """An instance in a scene: its model, the pose object -> world (``X_w = R @ X_obj + t``,
    metres) and the world-frame mesh rendered alone for its masks (the model moved into place;
    for a scan, the scan's own faces of that object)."""

    obj_id: int
    R: np.ndarray
    t: np.ndarray
    mesh: trimesh.Trimesh


@dataclass(eq=False)
class SceneSpec:
    """Everything one BOP scene needs: the world-frame mesh the camera sees, the instances, views."""

    mesh: trimesh.Trimesh
    placements: list[Placement]
    cameras: list[Camera]
    #: the models: a :class:`SceneObject`, or an ObjectSpec made into one when first written
    objects: dict[int, SceneObject | ObjectSpec] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# Ground-truth info, as bop_toolkit computes it
# ---------------------------------------------------------------------------------------------


def ray_factor(K: Intrinsics) -> np.ndarray:
    """Per pixel, distance along the ray / depth (bop_toolkit's depth_im_to_dist_im)."""
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    return np.sqrt(1.0 + ((u - K.cx) / K.fx) ** 2 + ((v - K.cy) / K.fy) ** 2)


def bbox(mask: np.ndarray, dx: int = 0, dy: int = 0) -> list[int]:
    """bop_toolkit's ``calc_2d_bbox``: (x, y, w, h) with w = x_max - x_min; offsets move a large
    canvas' pixels back into image coordinates."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()) - dx, int(ys.min()) - dy
    return [x0, y0, int(xs.max()) - dx - x0, int(ys.max()) - dy - y0]


def gt_info(scene_depth: np.ndarray, stored_depth: np.ndarray, alone_depth: np.ndarray, factor: np.ndarray,
            full_mask: np.ndarray | None = None, full_offset: tuple[int, int] = (0, 0)) -> tuple[dict, np.ndarray, np.ndarray]:
    """One instance's ``scene_gt_info`` entry and its ``mask`` / ``mask_visib`` (bool).

    ``scene_depth``: the clean scene (metres) the visibility is tested against; ``stored_depth``:
    what is written (``px_count_valid`` counts its valid pixels); ``alone_depth``: the instance
    rendered alone; ``full_mask``: its silhouette on a larger canvas whose image corner is at
    ``full_offset`` (None: it is not cut by the image border, the image mask is all of it).
    """
    mask = alone_depth > 0
    d_diff = (alone_depth.astype(np.float64) - scene_depth) * factor * 1000.0
    visib = mask & ((d_diff <= DELTA_MM) | (scene_depth == 0))
    full = mask if full_mask is None else full_mask
    n_all, n_visib = int(full.sum()), int(visib.sum())
    info = {
        "bbox_obj": bbox(full, *full_offset) if n_visib > 0 else [-1, -1, -1, -1],
        "bbox_visib": bbox(visib),
        "px_count_all": n_all,
        "px_count_valid": int((stored_depth[mask] > 0).sum()),
        "px_count_visib": n_visib,
        "visib_fract": n_visib / n_all if n_all > 0 else 0.0,
    }
    return info, mask, visib


def _cut_by_border(mesh: trimesh.Trimesh, cam: Camera, znear: float) -> bool:
    """Whether any of the mesh's hull vertices projects outside the image (or lies behind the
    near plane): only then can the silhouette extend beyond the image."""
    try:
        v = np.asarray(mesh.convex_hull.vertices)
    except Exception:
        v = np.asarray(mesh.vertices)
    X = v @ cam.R.T + cam.t
    if np.any(X[:, 2] <= znear):
        return True
    K = cam.intrinsics
    u, w = K.fx * X[:, 0] / X[:, 2] + K.cx, K.fy * X[:, 1] / X[:, 2] + K.cy
    return bool(np.any(u < -0.5) or np.any(u > K.width - 0.5) or np.any(w < -0.5) or np.any(w > K.height - 0.5))


class _Renderers:
    """The image-sized renderer and the 3x canvas one (sharing the process's GL context)."""

    ZNEAR = 0.05

    def __init__(self, K: Intrinsics) -> None:
        from isa.render.renderer import DepthRenderer

        self.K = K
        self.image = DepthRenderer(K, znear=self.ZNEAR, cache_size=16)
        self.big_K = Intrinsics(K.fx, K.fy, K.cx + K.width, K.cy + K.height, 3 * K.width, 3 * K.height)
        self.big = DepthRenderer(self.big_K, znear=self.ZNEAR, cache_size=16)
        self.factor = ray_factor(K)

    def close(self) -> None:
        self.image.close()
        self.big.close()


def render_frame(spec: SceneSpec, cam: Camera, r: _Renderers, noise: KinectNoise | None, noise_seed) -> tuple:
    """One view: stored depth (uint16 mm), and per instance in the image: its index in
    ``spec.placements``, info, mask, visible mask."""
    scene, _ = r.image.render(spec.mesh, cam.R, cam.t)
    depth = apply_kinect_noise(scene, cam.intrinsics, noise_seed, noise) if noise is not None else scene
    stored = bop.depth_to_png(depth)
    stored_m = bop.png_to_depth(stored)
    out = []
    for k, p in enumerate(spec.placements):
        alone, mask = r.image.render(p.mesh, cam.R, cam.t)
        if not mask.any():
            continue
        full = None
        if _cut_by_border(p.mesh, cam, r.ZNEAR):
            _, full = r.big.render(p.mesh, cam.R, cam.t)
        info, m, visib = gt_info(scene, stored_m, alone, r.factor, full, (cam.intrinsics.width, cam.intrinsics.height))
        out.append((k, info, m, visib))
    return stored, out


# ---------------------------------------------------------------------------------------------
# A scene folder, frame by frame
# ---------------------------------------------------------------------------------------------


def _mm(x) -> list[float]:
    return [float(v) * 1000.0 for v in np.asarray(x, float).reshape(-1)]


def _flat(R) -> list[float]:
    return [float(v) for v in np.asarray(R, float).reshape(-1)]


class SceneFolder:
    """One BOP scene folder: which frames are committed, and committing one more."""

    def __init__(self, root: Path, split: str, scene_id: int) -> None:
        self.dir = bop.scene_dir(root, split, scene_id)
        read = lambda name: bop.read_json(self.dir / name) if (self.dir / name).is_file() else {}  # noqa: E731
        self.camera, self.gt, self.info = read("scene_camera.json"), read("scene_gt.json"), read("scene_gt_info.json")

    def _paths(self, im_id: int, n_gt: int) -> list[Path]:
        p = [self.dir / "depth" / f"{im_id:06d}.png"]
        for k in range(n_gt):
            p += [self.dir / d / f"{im_id:06d}_{k:06d}.png" for d in ("mask", "mask_visib")]
        return p

    def has_frame(self, im_id: int) -> bool:
        k = str(im_id)
        if k not in self.gt or k not in self.camera or k not in self.info:
            return False
        return all(p.is_file() for p in self._paths(im_id, len(self.gt[k])))

    def commit(self, im_id: int, stored: np.ndarray, cam: Camera, spec: SceneSpec, found: list) -> None:
        paths = self._paths(im_id, len(found))
        bop.write_png(paths[0], stored)
        for j, (_, _, m, v) in enumerate(found):
            bop.write_png(paths[1 + 2 * j], m.astype(np.uint8) * 255)
            bop.write_png(paths[2 + 2 * j], v.astype(np.uint8) * 255)
        k = str(im_id)
        self.camera[k] = {"cam_K": _flat(cam.intrinsics.K), "depth_scale": 1.0,
                          "cam_R_w2c": _flat(cam.R), "cam_t_w2c": _mm(cam.t), "isa_gravity": _flat(cam.gravity)}
        gts = []
        for idx, _, _, _ in found:
            p = spec.placements[idx]
            R = cam.R @ p.R
            gts.append({"cam_R_m2c": _flat(R), "cam_t_m2c": _mm(cam.R @ p.t + cam.t), "obj_id": int(p.obj_id)})
        self.gt[k] = gts
        self.info[k] = [info for _, info, _, _ in found]
        order = lambda d: {i: d[i] for i in sorted(d, key=int)}  # noqa: E731
        bop.write_json(self.dir / "scene_camera.json", order(self.camera))
        bop.write_json(self.dir / "scene_gt_info.json", order(self.info))
        bop.write_json(self.dir / "scene_gt.json", order(self.gt))  # last: the commit record


def write_models(root: Path, objects: dict[int, SceneObject | ObjectSpec]) -> None:
    """Add the ``objects`` not there yet to ``models/`` (meshes as PLY in mm) and to
    ``models_info.json`` (an ObjectSpec's symmetry is searched only then)."""
    path = root / "models" / "models_info.json"
    infos = bop.read_models_info(root) if path.is_file() else {}
    new = [o for k, o in sorted(objects.items())
           if k not in infos or (o.mesh is not None and not bop.model_path(root, k).is_file())]
    if not new:
        return
    for o in new:
        if isinstance(o, ObjectSpec):
            o = SceneObject.from_spec(o)
        if o.mesh is not None:
            bop.write_model(root, o.obj_id, o.mesh)
        infos[o.obj_id] = models_info_entry(o)
    bop.write_models_info(root, infos)


def write_camera(root: Path, K: Intrinsics) -> None:
    """``camera.json`` (BOP's dataset camera); refuses a root written with another camera."""
    cam = {"cx": K.cx, "cy": K.cy, "depth_scale": 1.0, "fx": K.fx, "fy": K.fy, "height": K.height, "width": K.width}
    path = root / "camera.json"
    if path.is_file():
        if bop.read_json(path) != cam:
            raise DataError(f"{path} holds another camera ({bop.read_json(path)}); use a new dataset root")
        return
    bop.write_json(path, cam)


def check_settings(path: Path, settings: dict) -> None:
    """Refuse to resume into a split made with other settings (frames would be mixed)."""
    settings = _jsonable(settings)
    if path.is_file():
        old = bop.read_json(path)
        if old != settings:
            raise DataError(f"{path} was written with other settings ({old}); use a new output folder or delete it")
    else:
        bop.write_json(path, settings)


def _jsonable(x):
    import json

    return json.loads(json.dumps(x, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


@dataclass
class ScenesSummary:
    """What a run did: frames rendered now, frames already on disk, seconds, scene ids."""

    rendered: int = 0
    skipped: int = 0
    seconds: float = 0.0
    scenes: list[int] = field(default_factory=list)


def write_scenes(out_root, split: str, scenes, n_frames: int, noise: KinectNoise | None, seed: int,
                 intrinsics: Intrinsics, progress: bool = True, desc: str = "scenes") -> ScenesSummary:
    """Render and commit every view of ``scenes``: an iterable of ``(scene_id, n_views, build)``
    where ``build()`` returns the :class:`SceneSpec` (called only when a view is missing).
    Noise is seeded per frame from ``(seed, scene_id, im_id)``."""
    t0 = time.perf_counter()
    root = Path(out_root)
    write_camera(root, intrinsics)
    summary = ScenesSummary()
    renderers = None
    try:
        with tqdm(total=n_frames, desc=desc, unit="frame", disable=not progress) as bar:
            for scene_id, n_views, build in scenes:
                summary.scenes.append(scene_id)
                folder = SceneFolder(root, split, scene_id)
                todo = [i for i in range(n_views) if not folder.has_frame(i)]
                summary.skipped += n_views - len(todo)
                bar.update(n_views - len(todo))
                if not todo:
                    continue
                spec = build()
                write_models(root, spec.objects)
                if renderers is None:
                    renderers = _Renderers(intrinsics)
                for im_id in todo:
                    cam = spec.cameras[im_id]
                    stored, found = render_frame(spec, cam, renderers, noise, [seed, scene_id, im_id, 2])
                    folder.commit(im_id, stored, cam, spec, found)
                    summary.rendered += 1
                    bar.update(1)
    finally:
        if renderers is not None:
            renderers.close()
    summary.seconds = time.perf_counter() - t0
    return summary


# ---------------------------------------------------------------------------------------------
# Synthetic rooms
# ---------------------------------------------------------------------------------------------


def room_scene(room: Room, rng: np.random.Generator, n_views: int, rig: CameraRig = CameraRig()) -> SceneSpec:
    """A room as a :class:`SceneSpec`: its instances, and ``n_views`` cameras looking at them."""
    placements = [Placement(i.obj.obj_id, i.R, i.t, i.world_mesh) for i in room.instances]
    mesh = trimesh.util.concatenate([room.static, *(p.mesh for p in placements)])
    targets = [i.centre for i in room.instances] or [np.array([0.0, 0.0, 0.5])]
    cams = [sample_camera(rng, np.array(targets), room.is_free, rig) for _ in range(n_views)]
    objects = {i.obj.obj_id: i.obj for i in room.instances}
    return SceneSpec(mesh, placements, cams, objects)


def make_scenes(
    out_root,
    split: str,
    source,
    n_scenes: int,
    views_per_scene: int,
    seed: int = 0,
    noise: bool | KinectNoise = True,
    n_instances: tuple[int, int] = (1, 6),
    room: RoomParams = RoomParams(),
    rig: CameraRig = CameraRig(),
    progress: bool = True,
) -> ScenesSummary:
    """Write ``n_scenes`` synthetic rooms x ``views_per_scene`` views to ``<out_root>/<split>/``
    (BOP; scene ids 0..n_scenes-1) with instances from ``source``
    (:mod:`isa.scenes.sources`). Room ``s`` and its views are drawn from ``(seed, s)``; the sensor
    noise (``noise=True``: :class:`isa.render.noise.KinectNoise` defaults) from ``(seed, s, view)``.
    Resumable: committed frames are skipped; other settings in the same folder raise ``DataError``.
    """
    if n_scenes < 0 or views_per_scene < 1:
        raise DataError(f"make_scenes: need n_scenes >= 0 and views_per_scene >= 1, got {n_scenes}, {views_per_scene}")
    params = KinectNoise() if noise is True else (noise or None)
    root = Path(out_root)
    (root / split).mkdir(parents=True, exist_ok=True)
    check_settings(root / split / SETTINGS_FILE, {
        "kind": "rooms", "source": source.name, "categories": list(source.categories), "seed": seed,
        "views_per_scene": views_per_scene, "noise": asdict(params) if params else None,
        "n_instances": list(n_instances), "room": asdict(room), "rig": asdict(rig)})

    def build(s: int):
        def f() -> SceneSpec:
            r = make_room(np.random.default_rng([seed, s]), source, n_instances, room)
            return room_scene(r, np.random.default_rng([seed, s, 1]), views_per_scene, rig)
        return f

    scenes = ((s, views_per_scene, build(s)) for s in range(n_scenes))
    return write_scenes(root, split, scenes, n_scenes * views_per_scene, params, seed, rig.intrinsics, progress,
                        desc=f"scenes {split}")

"""Reading a scene dataset (what :mod:`isa.scenes.writer` and :mod:`isa.scenes.scan2cad` write,
or any BOP dataset with ``models_info.json``) into frames with their ground truth, for scoring.

Units on the way in: BOP's millimetres become metres; depth PNG values times ``depth_scale`` are
millimetres. Poses are ``X_cam = R @ X_obj + t`` as everywhere in isa.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from isa.data import bop
from isa.camera import Intrinsics
from isa.exceptions import DataError

#: ``GroundTruth.symmetries`` of an object with a continuous turn symmetry about its z axis.
CONTINUOUS_Z = "continuous-z"


@dataclass(eq=False)
class GroundTruth:
    """One annotated object in a frame (metres, camera frame).

    ``size``: the axis-aligned extents in the object frame; ``symmetries``: the turn group as a
    list of 3x3 rotations about the vertical axis through ``symmetry_centre`` (object frame),
    the identity first (``[I]`` for none), or :data:`CONTINUOUS_Z`; ``points``: the (N, 3) model
    points of Eq. 14 in the object frame (surface samples and vertices of the mesh; the box's 8
    corners and centre when the object has no mesh). A symmetric pose of the object is
    ``R @ g``, ``t + R @ (c - g @ c)`` for ``g`` in the group and ``c = symmetry_centre``.
    """

    obj_id: int
    category: str
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    visib_fract: float
    symmetries: list | str
    points: np.ndarray
    symmetry_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    px_count_visib: int = 0
    bbox_visib: tuple[int, int, int, int] = (-1, -1, -1, -1)


@dataclass(eq=False)
class SceneFrame:
    """One view: depth (float32 m, 0 = missing), intrinsics, ``gravity`` (camera to upright, 3x3,
    ``X_up = gravity @ X_cam``, or None) and the ground truth. ``R_gravity`` is the same rotation
    under the name :mod:`isa.detection` reads."""

    scene_id: int
    im_id: int
    depth: np.ndarray
    intrinsics: Intrinsics
    gravity: np.ndarray | None
    gt: list[GroundTruth]
    path: Path | None = None

    @property
    def R_gravity(self) -> np.ndarray | None:
        return self.gravity


@dataclass(frozen=True)
class ModelTruth:
    """What a frame's ground truth needs of one model (read once per dataset)."""

    category: str
    size: np.ndarray
    symmetries: list | str
    centre: np.ndarray
    points: np.ndarray


def _symmetries(info: dict, where: str) -> tuple[list | str, np.ndarray]:
    cont = info.get("symmetries_continuous") or []
    if cont:
        axis = np.asarray(cont[0]["axis"], float)
        if not np.allclose(np.abs(axis / np.linalg.norm(axis)), [0, 0, 1], atol=1e-6):
            raise DataError(f"{where}: continuous symmetry about {axis.tolist()}, only the z axis is supported")
        return CONTINUOUS_Z, np.asarray(cont[0].get("offset", [0, 0, 0]), float) / 1000.0
    group = [np.eye(3)]
    centre = np.zeros(3)
    for i, s in enumerate(info.get("symmetries_discrete") or []):
        T = np.asarray(s, float).reshape(4, 4)
        group.append(T[:3, :3])
        if i == 0:  # t = c - g c: the axis' point c (its z is free: 0)
            c, *_ = np.linalg.lstsq(np.eye(3)[:2] @ (np.eye(3) - T[:3, :3])[:, :2], T[:2, 3] / 1000.0, rcond=None)
            centre = np.array([c[0], c[1], 0.0])
    return group, centre


def box_points(box_min, size) -> np.ndarray:
    """The 8 corners and the centre of an axis-aligned box (the points of a model without mesh)."""
    lo, s = np.asarray(box_min, float), np.asarray(size, float)
    corners = lo + s * np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    return np.vstack([corners, lo + s / 2])


def read_models(root: str | Path) -> dict[int, ModelTruth]:
    """Every model of ``models/models_info.json`` with its category (``isa_category``), size,
    symmetries and Eq. 14 points."""
    from isa.evaluation.pose_metrics import model_points

    root = Path(root)
    out = {}
    for obj_id, info in bop.read_models_info(root).items():
        where = f"{root}/models/models_info.json obj {obj_id}"
        try:
            size = np.array([info["size_x"], info["size_y"], info["size_z"]], float) / 1000.0
            lo = np.array([info["min_x"], info["min_y"], info["min_z"]], float) / 1000.0
        except KeyError as exc:
            raise DataError(f"{where}: missing {exc}") from None
        syms, centre = _symmetries(info, where)
        if bop.model_path(root, obj_id).is_file():
            pts = model_points(bop.read_model(root, obj_id))
        else:
            pts = box_points(lo, size)
        out[obj_id] = ModelTruth(info.get("isa_category", str(obj_id)), size, syms, centre, pts)
    return out


def read_scene_dataset(root: str | Path, split: str) -> list[SceneFrame]:
    """Every frame of ``<root>/<split>`` in scene then image order, with its ground truth.

    ``DataError`` naming the file when the split, a scene file or an image is missing or corrupt.
    """
    root = Path(root)
    scenes = bop.list_scenes(root, split)
    if not scenes:
        raise DataError(f"{root / split}: no scenes (no <scene>/scene_gt.json)")
    models = read_models(root)
    frames = []
    for sid in scenes:
        d = bop.scene_dir(root, split, sid)
        cams = bop.read_json(d / "scene_camera.json")
        gts = bop.read_json(d / "scene_gt.json")
        infos = bop.read_json(d / "scene_gt_info.json") if (d / "scene_gt_info.json").is_file() else {}
        for k in sorted(gts, key=int):
            im = int(k)
            if k not in cams:
                raise DataError(f"{d / 'scene_camera.json'}: no entry for image {im}")
            cam = cams[k]
            png = d / "depth" / f"{im:06d}.png"
            values = bop.read_png(png)
            K = Intrinsics.from_K(cam["cam_K"], values.shape[1], values.shape[0])
            depth = bop.png_to_depth(values, float(cam.get("depth_scale", 1.0)))
            grav = np.asarray(cam["isa_gravity"], float).reshape(3, 3) if "isa_gravity" in cam else None
            gt = []
            for j, g in enumerate(gts[k]):
                oid = int(g["obj_id"])
                if oid not in models:
                    raise DataError(f"{d / 'scene_gt.json'} image {im}: obj_id {oid} is not in models_info.json")
                m = models[oid]
                info = infos.get(k, [{}] * len(gts[k]))[j] if k in infos else {}
                gt.append(GroundTruth(oid, m.category, np.asarray(g["cam_R_m2c"], float).reshape(3, 3),
                                      np.asarray(g["cam_t_m2c"], float) / 1000.0, m.size,
                                      float(info.get("visib_fract", 1.0)), m.symmetries, m.points, m.centre,
                                      int(info.get("px_count_visib", 0)), tuple(info.get("bbox_visib", (-1, -1, -1, -1)))))
            frames.append(SceneFrame(sid, im, depth, K, grav, gt, png))
    return frames

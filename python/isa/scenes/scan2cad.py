"""The real ScanNet scan with Scan2CAD's furniture poses as a scene: virtual depth views of the
scan mesh from hand-held cameras inside the room, with the chairs' and the table's 6D pose in
our object frame.

Conventions taken from the data (``../shared/data/README.md``, checked on scene0470_00):

- Scan2CAD's ``trs``: translation, quaternion **(w, x, y, z)**, per-axis scale;
  ``M(trs) = [R diag(s) | t]``, and a CAD model's frame maps into the scan's by
  ``inv(M(top-level trs)) @ M(model trs)``. ``bbox`` is the CAD box's half size and ``center``
  its centre, in the CAD (ShapeNet) frame before scaling.
- ShapeNet's frame is y up (it maps onto the scan's z) and its chairs face -z: on all five
  chairs the scan's chair vertices in the upper part of the box (the back rest) lie at +z. Our
  object frame (z up, front -y, docs/DESIGN.md) is then ``x = -x_cad, y = z_cad, z = y_cad``
  (:data:`CAD_TO_OBJECT`, a rotation).
- There is no CAD mesh, so an object is its box: ``size`` = 2 ``bbox`` x scale in our axes. Its
  origin follows the category's rule as closely as a box allows: the box centre moved by the
  category's median origin offset relative to its box (a fraction of the extents per axis),
  measured on reference instances prepared as training prepares them
  (:func:`relative_origin`; procedural ones by default), so that a forest's origin (centre of
  mass for chairs, the SSC for tables) and the ground truth's agree on average.
- Instance masks come from the scan itself: the faces whose three vertices carry the object's
  label (ScanNet's NYU40 ids in ``.labels.ply``: chair 5, table 7) and lie in its aligned box
  (grown by :data:`BOX_MARGIN`); a face in two boxes goes to the one it is deeper in. An
  instance rendered alone is then its scanned surface: ``px_count_all`` counts that, and
  ``mask_visib`` what of it the full scan leaves visible. The trash bin is ignored.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from shapely.geometry import MultiPoint, Point

from isa.exceptions import DataError
from isa.render.noise import KinectNoise
from isa.scenes.cameras import CameraRig, sample_camera
from isa.scenes.writer import Placement, SceneObject, SceneSpec, check_settings, write_scenes
from isa.privileged.symmetry import YawSymmetry

#: ShapeNet category ids of the objects kept, and their category.
CATEGORIES = {"03001627": "chair", "04379243": "table"}
#: ScanNet's NYU40 label of each category's vertices in ``.labels.ply``.
LABELS = {"chair": 5, "table": 7}
#: Scan2CAD's symmetry tags -> turn group order (0 = continuous).
SYMMETRY_ORDER = {"__SYM_NONE": 1, "__SYM_ROTATE_UP_2": 2, "__SYM_ROTATE_UP_4": 4, "__SYM_ROTATE_UP_INF": 0}
#: Rows: our object axes in CAD coordinates (x = -x_cad, y = z_cad, z = y_cad).
CAD_TO_OBJECT = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
#: How much a box is grown (relative, and metres) when its scan faces are collected.
BOX_MARGIN = (0.05, 0.02)
#: Views of the scan: a small room, so closer than the synthetic rooms' cameras.
SCAN_RIG = CameraRig(distance=(1.0, 2.5))


@dataclass(eq=False)
class ScanObject:
    """One annotated object: pose object -> scan (``X_scan = R @ X_obj + t``), its box in the
    object frame (``box_min``, ``size``, metres), its turn symmetry, and the aligned CAD box
    (``A`` CAD -> scan, ``center``, ``half``) that selects its scan faces."""

    category: str
    cad_id: str
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    box_min: np.ndarray
    symmetry: YawSymmetry
    A: np.ndarray
    center: np.ndarray
    half: np.ndarray


def _trs(trs: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w, x, y, z = trs["rotation"]
    return Rotation.from_quat([x, y, z, w]).as_matrix(), np.asarray(trs["scale"], float), np.asarray(trs["translation"], float)


def _matrix(trs: dict) -> np.ndarray:
    R, s, t = _trs(trs)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R @ np.diag(s), t
    return M


def relative_origin(source, category: str) -> np.ndarray:
    """The category's origin relative to its box centre, as a fraction of the extents: the
    median over ``source``'s (prepared) instances (their meshes are origin-centred)."""
    fr = []
    for i in range(source.count(category)):
        lo, hi = source.instance(category, i).mesh.bounds
        fr.append(-(lo + hi) / 2 / (hi - lo))
    return np.median(np.array(fr), axis=0)


def scan_objects(annotation_path: str | Path, origins: dict[str, np.ndarray]) -> list[ScanObject]:
    """The chairs and tables of a Scan2CAD annotation (``example_annotation.json``) in our object
    frame; ``origins``: category -> :func:`relative_origin`."""
    path = Path(annotation_path)
    try:
        ann = json.loads(path.read_text())
        ann = ann[0] if isinstance(ann, list) else ann
        top = _matrix(ann["trs"])
        models = ann["aligned_models"]
    except (OSError, json.JSONDecodeError, KeyError, IndexError, TypeError) as exc:
        raise DataError(f"Scan2CAD annotation {path}: unreadable ({type(exc).__name__}: {exc})") from None
    out = []
    for m in models:
        cat = CATEGORIES.get(m.get("catid_cad"))
        if cat is None:
            continue
        A = np.linalg.inv(top) @ _matrix(m["trs"])
        s = np.linalg.norm(A[:3, :3], axis=0)  # the per-axis scale (the top-level trs has none)
        R_cad = A[:3, :3] / s  # CAD axes -> scan
        center, half = np.asarray(m["center"], float), np.asarray(m["bbox"], float)
        size = np.abs(CAD_TO_OBJECT) @ (2 * half * s)
        rel = np.asarray(origins[cat], float)
        o_cad = s * center + CAD_TO_OBJECT.T @ (rel * size)  # the origin in metric CAD coordinates
        R = R_cad @ CAD_TO_OBJECT.T
        t = R_cad @ o_cad + A[:3, 3]
        box_centre = -rel * size
        order = SYMMETRY_ORDER.get(m.get("sym", "__SYM_NONE"), 1)
        sym = YawSymmetry(np.array([box_centre[0], box_centre[1], 0.0]), order, 0.0)
        out.append(ScanObject(cat, m.get("id_cad", ""), R, t, size, box_centre - size / 2, sym, A, center, half))
    if not out:
        raise DataError(f"Scan2CAD annotation {path}: no chair or table")
    return out


def load_labelled_scan(scan_dir: str | Path) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The scan mesh (``*_vh_clean_2.labels.ply``, metres, z up) and its per-vertex NYU40 labels."""
    scan_dir = Path(scan_dir)
    files = sorted(scan_dir.glob("*_vh_clean_2.labels.ply"))
    if not files:
        raise DataError(f"{scan_dir}: no *_vh_clean_2.labels.ply (ScanNet's labelled scan mesh)")
    try:
        mesh = trimesh.load(files[0], process=False)
        labels = np.asarray(mesh.metadata["_ply_raw"]["vertex"]["data"]["label"], int)
    except Exception as exc:
        raise DataError(f"{files[0]}: not a labelled ScanNet mesh ({type(exc).__name__}: {exc})") from None
    return mesh, labels


def _cad_coords(obj: ScanObject, X: np.ndarray) -> np.ndarray:
    return (np.linalg.inv(obj.A) @ np.c_[X, np.ones(len(X))].T).T[:, :3]


def instance_faces(mesh: trimesh.Trimesh, labels: np.ndarray, objects: list[ScanObject]) -> list[np.ndarray]:
    """Per object, the indices of the scan faces that are its surface (see the module docstring)."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rel, m = BOX_MARGIN
    depth = np.full((len(objects), len(F)), np.inf)  # how deep a face is in each box (<= 1: inside)
    for k, o in enumerate(objects):
        q = np.abs(_cad_coords(o, V) - o.center) / (o.half * (1 + rel) + m / np.linalg.norm(o.A[:3, :3], axis=0))
        vdepth = np.where(labels == LABELS[o.category], q.max(1), np.inf)
        depth[k] = vdepth[F].max(1)
    best = depth.argmin(0)
    inside = depth.min(0) <= 1.0
    return [np.flatnonzero(inside & (best == k)) for k in range(len(objects))]


def _free_space(mesh: trimesh.Trimesh, labels: np.ndarray, clearance: float = 0.3):
    """``is_free(eye)``: inside the scanned floor's outline (shrunk by ``clearance``) and no scan
    vertex within ``clearance`` of the eye."""
    V = np.asarray(mesh.vertices)
    floor = V[labels == 2] if np.any(labels == 2) else V
    outline = MultiPoint([tuple(p) for p in floor[:, :2]]).convex_hull.buffer(-clearance)
    tree = cKDTree(V)

    def is_free(eye) -> bool:
        return outline.contains(Point(float(eye[0]), float(eye[1]))) and not tree.query_ball_point(eye, clearance)

    return is_free


def scan_scene(scan_dir: str | Path, n_views: int, rng: np.random.Generator, origins: dict[str, np.ndarray],
               rig: CameraRig = SCAN_RIG, first_obj_id: int = 1) -> SceneSpec:
    """The scan as a :class:`SceneSpec`: one placement per chair / table, ``n_views`` cameras."""
    scan_dir = Path(scan_dir)
    mesh, labels = load_labelled_scan(scan_dir)
    objs = scan_objects(scan_dir / "example_annotation.json", origins)
    faces = instance_faces(mesh, labels, objs)
    placements, objects = [], {}
    name = scan_dir.name
    for k, (o, f) in enumerate(zip(objs, faces)):
        if len(f) == 0:
            raise DataError(f"{scan_dir}: no scan faces of {o.category} {k} in its box")
        oid = first_obj_id + k
        placements.append(Placement(oid, o.R, o.t, mesh.submesh([f], append=True)))
        objects[oid] = SceneObject(oid, o.category, f"scan2cad:{name}:{o.cad_id}", o.size, o.box_min, None, o.symmetry)
    targets = np.array([o.R @ (o.box_min + o.size / 2) + o.t for o in objs])
    is_free = _free_space(mesh, labels)
    cams = [sample_camera(rng, targets, is_free, rig) for _ in range(n_views)]
    return SceneSpec(mesh, placements, cams, objects)


def make_scan2cad_scenes(out_root, scan_dir, n_views: int, seed: int = 0, noise: bool | KinectNoise = True,
                         split: str = "test", reference=None, rig: CameraRig = SCAN_RIG,
                         progress: bool = True):
    """Write ``n_views`` views of the scan as BOP scene 0 of ``<out_root>/<split>`` (no model
    meshes: ``models_info.json`` holds each object's box and symmetry). ``reference``: the
    :class:`isa.scenes.sources.MeshSource` whose instances set each category's origin offset
    (default: procedural chairs and tables, seed 0). Resumable and reproducible as
    :func:`isa.scenes.writer.make_scenes`."""
    from isa.scenes.sources import procedural

    scan_dir = Path(scan_dir)
    if not (scan_dir / "example_annotation.json").is_file():
        raise DataError(f"{scan_dir}: no example_annotation.json (Scan2CAD's alignment of the scan)")
    reference = reference or procedural(tuple(LABELS), seed=0)
    origins = {c: relative_origin(reference, c) for c in LABELS}
    params = KinectNoise() if noise is True else (noise or None)
    root = Path(out_root)
    (root / split).mkdir(parents=True, exist_ok=True)
    check_settings(root / split / "isa_scenes.json", {
        "kind": "scan2cad", "scan": scan_dir.name, "seed": seed, "views": n_views, "reference": reference.name,
        "noise": asdict(params) if params else None, "rig": asdict(rig)})
    scenes = [(0, n_views, lambda: scan_scene(scan_dir, n_views, np.random.default_rng([seed, 0, 1]), origins, rig))]
    return write_scenes(root, split, scenes, n_views, params, seed, rig.intrinsics, progress, desc="scan2cad views")

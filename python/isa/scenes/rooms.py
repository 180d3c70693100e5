"""Synthetic rooms: a floor, two or three walls, 1-6 category instances standing on the floor at
random yaw, packed close enough to hide each other, and clutter of no category (boxes,
cylinders, shelves against a wall, small things on the tables' tops).

World frame as in :mod:`isa.scenes.cameras` (z up, floor at z = 0); the room spans
``[-W/2, W/2] x [-D/2, D/2]``, the back wall at ``y = D/2`` and side walls at ``x = -+W/2``.
Footprints (the convex hull of what stands on the floor, seen from above) never overlap, so no
two things interpenetrate; instances come from a :class:`isa.scenes.sources.MeshSource` already
scaled to real size and centred on the category's origin, as training has them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh
from shapely import affinity
from shapely.geometry import MultiPoint, Point, Polygon
from shapely.geometry import box as shapely_box

from isa.camera import Intrinsics
from isa.evaluation.boxes3d import rot_z
from isa.exceptions import InvalidParameterError
from isa.render.dataset import ObjectSpec, hull_points

WALL_HEIGHT = 2.6
WALL_THICKNESS = 0.1


@dataclass(eq=False)
class Instance:
    """A category instance in the room: its (prepared) object and the pose object -> world."""

    obj: ObjectSpec
    R: np.ndarray
    t: np.ndarray
    footprint: Polygon

    @property
    def world_mesh(self) -> trimesh.Trimesh:
        m = self.obj.mesh.copy()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        m.apply_transform(T)
        return m

    @property
    def centre(self) -> np.ndarray:
        """The world position of the instance's bounding-box centre (what cameras look at)."""
        return self.R @ self.obj.mesh.bounds.mean(0) + self.t


@dataclass(eq=False)
class Room:
    """A generated room: ``size`` (W, D) metres, which ``walls`` stand ("back", "left", "right"),
    the static geometry (floor, walls, clutter: one world-frame mesh) and the instances."""

    size: tuple[float, float]
    walls: tuple[str, ...]
    static: trimesh.Trimesh
    instances: list[Instance]
    clutter: list[str] = field(default_factory=list)  # the kind of each clutter item
    clutter_meshes: list[trimesh.Trimesh] = field(default_factory=list)  # each item, world frame
    footprints: list[Polygon] = field(default_factory=list)  # everything standing on the floor

    def scene_mesh(self) -> trimesh.Trimesh:
        """Everything in the room, world frame: what the camera sees."""
        return trimesh.util.concatenate([self.static, *(i.world_mesh for i in self.instances)])

    def is_free(self, eye, margin: float = 0.3) -> bool:
        """Whether a camera at ``eye`` stands inside the walls and clear of everything on the floor."""
        W, D = self.size
        x, y = float(eye[0]), float(eye[1])
        if y > D / 2 - margin or ("left" in self.walls and x < -W / 2 + margin) or ("right" in self.walls and x > W / 2 - margin):
            return False
        if abs(x) > W / 2 + 1.0 or y < -D / 2 - 1.0:  # through an open side: not much further
            return False
        p = Point(x, y)
        return all(f.distance(p) > margin for f in self.footprints)


@dataclass(frozen=True)
class RoomParams:
    """Ranges the room is drawn from (metres)."""

    width: tuple[float, float] = (3.5, 6.0)
    depth: tuple[float, float] = (3.5, 6.0)
    walls: tuple[int, int] = (2, 3)
    gap: tuple[float, float] = (0.03, 0.5)  # between neighbouring footprints
    floor_clutter: tuple[int, int] = (1, 5)
    shelves: tuple[int, int] = (0, 2)
    table_clutter: tuple[int, int] = (0, 3)  # per table instance
    placement_attempts: int = 60


def _hull_xy(mesh: trimesh.Trimesh) -> Polygon:
    """The footprint: the mesh's convex hull seen from above."""
    return MultiPoint([tuple(p) for p in hull_points(mesh)[:, :2]]).convex_hull


def _inside(poly: Polygon, size: tuple[float, float], margin: float = 0.05) -> bool:
    W, D = size
    return shapely_box(-W / 2 + margin, -D / 2 + margin, W / 2 - margin, D / 2 - margin).contains(poly)


def _slide_out(rng, shape: Polygon, anchor: Polygon | None, taken: list[Polygon], size, gap) -> tuple[float, float] | None:
    """A position for ``shape`` (footprint centred at its own origin): next to ``anchor`` in a
    random direction, moved outwards until it clears everything by a drawn gap, inside the room."""
    W, D = size
    if anchor is None:
        x, y = rng.uniform(-W / 3, W / 3), rng.uniform(-D / 4, D / 3)
        cand = affinity.translate(shape, x, y)
        return (x, y) if _inside(cand, size) and not any(cand.intersects(t) for t in taken) else None
    g = rng.uniform(*gap)
    th = rng.uniform(0, 2 * np.pi)
    c = anchor.centroid
    for r in np.arange(0.0, 4.0, 0.04):
        x, y = c.x + r * np.cos(th), c.y + r * np.sin(th)
        cand = affinity.translate(shape, x, y)
        if not any(cand.distance(t) < g for t in taken):
            return (x, y) if _inside(cand, size) else None
    return None


def _box(extents, centre, yaw: float = 0.0) -> trimesh.Trimesh:
    T = np.eye(4)
    T[:3, :3] = rot_z(yaw)
    T[:3, 3] = centre
    return trimesh.creation.box(extents=extents, transform=T)


def _cylinder(radius: float, height: float, centre) -> trimesh.Trimesh:
    T = np.eye(4)
    T[:3, 3] = centre
    return trimesh.creation.cylinder(radius=radius, height=height, sections=24, transform=T)


def _walls(rng, size, n_walls: int) -> tuple[tuple[str, ...], list[trimesh.Trimesh]]:
    W, D = size
    sides = ("back", "left", "right") if n_walls >= 3 else ("back", ("left", "right")[rng.integers(2)])
    meshes = []
    h, th = WALL_HEIGHT, WALL_THICKNESS
    for s in sides:
        if s == "back":
            meshes.append(_box((W + 2 * th, th, h), (0, D / 2 + th / 2, h / 2)))
        else:
            sx = -1 if s == "left" else 1
            meshes.append(_box((th, D + th, h), (sx * (W / 2 + th / 2), th / 2, h / 2)))
    # The floor runs on under open sides (the camera may stand in a doorway).
    x0 = -W / 2 if "left" in sides else -W / 2 - 3.0
    x1 = W / 2 if "right" in sides else W / 2 + 3.0
    y0, y1 = -D / 2 - 3.0, D / 2
    meshes.append(_box((x1 - x0, y1 - y0, 0.02), ((x0 + x1) / 2, (y0 + y1) / 2, -0.01)))
    return tuple(sides), meshes


def _floor_item(rng) -> tuple[str, trimesh.Trimesh]:
    """A box or a cylinder standing on the floor, centred at the world origin in xy."""
    if rng.random() < 0.6:
        e = (rng.uniform(0.2, 0.8), rng.uniform(0.2, 0.8), rng.uniform(0.15, 1.0))
        return "box", _box(e, (0, 0, e[2] / 2), rng.uniform(0, np.pi))
    r, h = rng.uniform(0.08, 0.3), rng.uniform(0.2, 1.1)
    return "cylinder", _cylinder(r, h, (0, 0, h / 2))


def _shelf(rng) -> trimesh.Trimesh:
    """An open shelf unit (sides, back, boards) facing -y, centred at the origin in xy."""
    w, d, h = rng.uniform(0.6, 1.4), rng.uniform(0.25, 0.4), rng.uniform(0.8, 2.0)
    t = 0.02
    parts = [_box((t, d, h), (sx * (w - t) / 2, 0, h / 2)) for sx in (-1, 1)]
    parts.append(_box((w, t, h), (0, (d - t) / 2, h / 2)))
    n = int(rng.integers(3, 6))
    for z in np.linspace(0.05, h - t / 2, n):
        parts.append(_box((w - 2 * t, d - t, t), (0, -t / 2, z)))
        if rng.random() < 0.5 and z < h - 0.2:  # something on the board
            e = (rng.uniform(0.05, 0.3), rng.uniform(0.05, d - 0.05), rng.uniform(0.05, 0.18))
            parts.append(_box(e, (rng.uniform(-(w - e[0]) / 2 + t, (w - e[0]) / 2 - t), 0, z + t / 2 + e[2] / 2)))
    return trimesh.util.concatenate(parts)


#: The top-down view that finds a table's top: pixels and metres per pixel.
_TOP_VIEW_PX, _TOP_VIEW_RES = 256, 0.01


def _heights_from_above(mesh: trimesh.Trimesh, centre_xy, top: float) -> tuple[np.ndarray, Intrinsics]:
    """A depth image of ``mesh`` seen straight down from 1 m above ``top`` over ``centre_xy``
    (the project's renderer, so no ray-casting library is needed), and its intrinsics: the
    surface height under pixel (u, v) is ``top + 1 - depth``."""
    from isa.render.renderer import DepthRenderer

    f = 1.0 / _TOP_VIEW_RES  # 1 cm per pixel at the top's height
    n = _TOP_VIEW_PX
    K = Intrinsics(fx=f, fy=f, cx=(n - 1) / 2, cy=(n - 1) / 2, width=n, height=n)
    R = np.diag([1.0, -1.0, -1.0])  # image x = world x, image down = world -y, looking down -z
    eye = np.array([centre_xy[0], centre_xy[1], top + 1.0])
    with DepthRenderer(K, znear=0.05, zfar=5.0) as r:
        depth, _ = r.render(mesh, R, -R @ eye)
    return depth, K


def _table_top_items(rng, inst: Instance, n: int) -> list[trimesh.Trimesh]:
    """Up to ``n`` small boxes and cylinders standing on a table's top, found on a depth image
    taken from above (an item is kept only where its whole footprint rests on the top surface)."""
    mesh = inst.world_mesh
    top = mesh.bounds[1, 2]
    fp = inst.footprint
    c = fp.centroid
    depth, K = _heights_from_above(mesh, (c.x, c.y), top)
    out = []
    for _ in range(4 * n):
        if len(out) == n:
            break
        s = rng.uniform(0.04, 0.14)
        h = rng.uniform(0.03, 0.3)
        minx, miny, maxx, maxy = fp.bounds
        x = c.x + rng.uniform(-0.35, 0.35) * (maxx - minx)
        y = c.y + rng.uniform(-0.35, 0.35) * (maxy - miny)
        probe = np.array([[x, y], [x - s, y - s], [x + s, y - s], [x - s, y + s], [x + s, y + s]])
        u = np.rint((probe[:, 0] - c.x) * K.fx + K.cx).astype(int)
        v = np.rint(-(probe[:, 1] - c.y) * K.fy + K.cy).astype(int)
        if np.any((u < 0) | (u >= K.width) | (v < 0) | (v >= K.height)):
            continue
        d = depth[v, u]
        if np.any(d <= 0):
            continue
        z = top + 1.0 - d
        if z.max() - z.min() > 0.01 or top - z.max() > 0.08:
            continue
        zt = float(z.max())
        if rng.random() < 0.5:
            out.append(_box((2 * s, 2 * s * rng.uniform(0.5, 1.0), h), (x, y, zt + h / 2), rng.uniform(0, np.pi)))
        else:
            out.append(_cylinder(s, h, (x, y, zt + h / 2)))
    return out


def make_room(rng: np.random.Generator, source, n_instances: tuple[int, int] = (1, 6),
              params: RoomParams = RoomParams(), include: Sequence[ObjectSpec] = ()) -> Room:
    """A room drawn from ``rng`` with ``n_instances`` (inclusive range) instances from ``source``
    (:class:`isa.scenes.sources.MeshSource`), packed into a cluster, plus clutter. ``include``:
    instances placed first (before the drawn ones, so the cluster grows around them; with
    ``n_instances`` lo = 0 they may stand alone); they come first in ``Room.instances`` when placed."""
    lo, hi = n_instances
    if not (0 <= lo <= hi) or (lo == 0 and not include):
        raise InvalidParameterError(f"n_instances: need 1 <= lo <= hi (lo 0 with include), got {n_instances}")
    size = (float(rng.uniform(*params.width)), float(rng.uniform(*params.depth)))
    walls, static = _walls(rng, size, int(rng.integers(params.walls[0], params.walls[1] + 1)))
    taken: list[Polygon] = []
    instances: list[Instance] = []
    drawn = int(rng.integers(lo, hi + 1))
    for k in range(len(include) + drawn):
        if k < len(include):
            obj = include[k]
        else:
            cat = source.categories[rng.integers(len(source.categories))]
            obj = source.instance(cat, int(rng.integers(source.count(cat))))
        yaw = rng.uniform(0, 2 * np.pi)
        R = rot_z(yaw)
        base = affinity.rotate(_hull_xy(obj.mesh), yaw, origin=(0, 0), use_radians=True)
        for _ in range(params.placement_attempts):
            anchor = taken[rng.integers(len(taken))] if taken else None
            pos = _slide_out(rng, base, anchor, taken, size, params.gap)
            if pos is not None:
                break
        if pos is None:
            continue  # no room left for it
        t = np.array([pos[0], pos[1], -obj.mesh.bounds[0, 2]])  # standing on the floor
        fp = affinity.translate(base, *pos)
        taken.append(fp)
        instances.append(Instance(obj, R, t, fp))
    clutter: list[str] = []
    items: list[trimesh.Trimesh] = []
    for _ in range(int(rng.integers(params.floor_clutter[0], params.floor_clutter[1] + 1))):
        kind, m = _floor_item(rng)
        shape = _hull_xy(m)
        anchor = taken[rng.integers(len(taken))] if taken else None
        pos = _slide_out(rng, shape, anchor, taken, size, (0.02, 0.6))
        if pos is None:
            continue
        m.apply_translation((pos[0], pos[1], 0))
        taken.append(affinity.translate(shape, *pos))
        items.append(m)
        clutter.append(kind)
    W, D = size
    for _ in range(int(rng.integers(params.shelves[0], params.shelves[1] + 1))):
        m = _shelf(rng)
        side = walls[rng.integers(len(walls))]
        hw, hd = m.extents[0] / 2, m.extents[1] / 2
        if side == "back":
            yaw, pos = 0.0, (rng.uniform(-W / 2 + hw + 0.05, W / 2 - hw - 0.05), D / 2 - hd - 0.01)
        else:  # against a side wall, facing into the room
            sx = -1 if side == "left" else 1
            yaw, pos = -sx * np.pi / 2, (sx * (W / 2 - hd - 0.01), rng.uniform(-D / 2 + hw + 0.05, D / 2 - hw - 0.05))
        m.apply_transform(trimesh.transformations.rotation_matrix(yaw, (0, 0, 1)))
        shape = _hull_xy(m)
        fp = affinity.translate(shape, *pos)
        if any(fp.intersects(t) for t in taken):
            continue
        m.apply_translation((pos[0], pos[1], 0))
        taken.append(fp)
        items.append(m)
        clutter.append("shelf")
    for inst in instances:
        if inst.obj.category == "table":
            n = int(rng.integers(params.table_clutter[0], params.table_clutter[1] + 1))
            on_top = _table_top_items(rng, inst, n) if n else []
            items.extend(on_top)
            clutter.extend(["table-top"] * len(on_top))
    return Room(size, walls, trimesh.util.concatenate(static + items), instances, clutter, items, taken)

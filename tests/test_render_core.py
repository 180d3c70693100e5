"""The core rasteriser (``isa._core.render_depth``, DepthRenderer's default backend) against
independent truths: ray casting through every pixel centre (trimesh, with embreex when it is
installed) and pyrender; its argument errors; and rendering with no GL library importable."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from isa import _core
from isa.camera import KINECT_V1, Intrinsics
from isa.data.procedural import generate
from isa.exceptions import InvalidInputError, InvalidValueError, MissingDependencyError
from isa.render.dataset import ObjectSpec, default_views
from isa.render.renderer import BACKEND_ENV, DepthRenderer, resolve_backend
from render_agreement import Agreement, depth_edges, mask_edges

# Full Kinect frames with embree; a quarter-size camera for trimesh's pure-numpy ray caster.
K = KINECT_V1 if trimesh.ray.has_embree else Intrinsics(131.25, 131.25, 79.5, 59.5, 160, 120)


def _meshes(shared_data=None) -> list[tuple[str, trimesh.Trimesh]]:
    out = [(f"procedural {c}", generate(c, 3).mesh) for c in ("chair", "table", "toilet")]
    if shared_data is not None:
        from isa.data.meshes import prepare_mesh

        mn = shared_data / "modelnet10" / "ModelNet10"
        for cat, name in (("chair", "chair_0001"), ("bed", "bed_0003"), ("toilet", "toilet_0002")):
            out.append((name, prepare_mesh(mn / cat / "train" / f"{name}.off", cat, 0)[0]))
    return out


def _views(mesh: trimesh.Trimesh, n: int = 89, every: int = 22):
    v = default_views(ObjectSpec(1, "chair", mesh, "test"), n, intrinsics=K)
    return [v[i] for i in range(0, n, every)]


def _ray_cast(mesh: trimesh.Trimesh, R, t) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the first hit along each pixel-centre ray (0 = miss) and the smallest barycentric
    coordinate of the hit in its face (how far inside the face the centre ray lands)."""
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    d = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    origins = np.repeat((-R.T @ t)[None], len(d), 0)
    tri, ray, loc = mesh.ray.intersects_id(origins, d @ R, multiple_hits=False, return_locations=True)
    depth = np.zeros(len(d))
    inside = np.full(len(d), -1.0)
    depth[ray] = (loc @ R.T + t)[:, 2]
    inside[ray] = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc).min(1)
    return depth.reshape(K.height, K.width), inside.reshape(K.height, K.width)


def _check_against_ray_casting(meshes) -> Agreement:
    agree = Agreement()
    with DepthRenderer(K, backend="core") as r:
        for name, mesh in meshes:
            for R, t in _views(mesh):
                depth, mask = r.render(mesh, R, t)
                truth, inside = _ray_cast(mesh, R, t)
                well_inside = inside > 0.05
                assert mask[well_inside].all(), f"{name}: a centre ray hits a face, the core leaves the pixel empty"
                # Equal depth, except where the ray grazes the edge of a nearer face and slips past
                # it (a mask or depth edge of the frame): there the core may only be nearer.
                edges = mask_edges(mask) | depth_edges(depth, mask)
                err = np.abs(depth - truth)[well_inside & ~edges]
                assert err.max() < 1e-5, f"{name}: depth differs from ray casting by {err.max():.2e} m"
                nearer = (depth - truth)[well_inside & edges]
                assert nearer.max(initial=0) < 1e-5, f"{name}: the core is {nearer.max():.2e} m behind the ray's hit"
                agree.add(depth, mask, truth.astype(np.float32), truth > 0)
    # The only other differences: centre rays that graze an edge (the core covers a shared edge
    # once, a ray caster may slip through or hit either face).
    s = agree.summary()
    assert s["mask_differ_off_edge_px"] <= 1e-4 * s["union_px"], s
    assert s["mask_agree_frac"] > 0.995, s
    return agree


def test_core_matches_ray_casting_on_procedural_meshes():
    _check_against_ray_casting(_meshes())


@pytest.mark.shared
def test_core_matches_ray_casting_on_modelnet_meshes(shared_data):
    _check_against_ray_casting(_meshes(shared_data)[3:])


@pytest.fixture(scope="module")
def gl():
    """A pyrender renderer, or a skip saying why there is none."""
    try:
        r = DepthRenderer(K, backend="pyrender")
        r.render(trimesh.creation.box(), np.eye(3), [0, 0, 2.0])
    except (MissingDependencyError, ImportError, OSError, RuntimeError) as e:
        pytest.skip(f"pyrender backend unavailable: {e}")
    yield r
    r.close()


def _check_against_pyrender(gl, meshes) -> None:
    agree = Agreement()
    with DepthRenderer(K, backend="core") as core:
        for _, mesh in meshes:
            for R, t in _views(mesh):
                agree.add(*core.render(mesh, R, t), *gl.render(mesh, R, t))
    s = agree.summary()
    # Mask differences only where a pixel centre lies within GL's sub-pixel rounding of an edge.
    assert s["mask_differ_off_edge_px"] == 0, s
    assert s["mask_agree_frac"] > 0.995, s
    # Depth: GL's 24-bit depth buffer against the core's f64 on smooth surfaces.
    assert s["depth_diff_median_m"] < 1e-5 and s["depth_diff_max_smooth_m"] < 1e-4, s


def test_core_matches_pyrender_on_procedural_meshes(gl):
    _check_against_pyrender(gl, _meshes())


@pytest.mark.shared
def test_core_matches_pyrender_on_modelnet_meshes(gl, shared_data):
    _check_against_pyrender(gl, _meshes(shared_data)[3:])


def _args(**kw):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    a = dict(vertices=v, faces=np.array([[0, 1, 2]], np.uint32), R=np.eye(3), t=[0, 0, 2.0], K=KINECT_V1,
             width=640, height=480, znear=0.05, zfar=20.0)
    a.update(kw)
    return a


def test_binding_returns_depth_and_mask():
    depth, mask = _core.render_depth(**_args())
    assert depth.dtype == np.float32 and mask.dtype == np.bool_ and depth.shape == mask.shape == (480, 640)
    assert mask.sum() > 1000 and np.all(depth[mask] == 2.0) and np.all(depth[~mask] == 0)
    # Any integer dtype of faces, the same frame.
    for dt in (np.int64, np.int32, np.uint64):
        np.testing.assert_array_equal(_core.render_depth(**_args(faces=np.array([[0, 1, 2]], dt)))[0], depth)


@pytest.mark.parametrize("kw, names", [
    (dict(faces=np.array([[0, 1, 3]], np.uint32)), "faces[0, 2] = 3"),
    (dict(faces=np.array([[0, -1, 2]], np.int64)), "faces[0, 1]"),
    (dict(faces=np.array([[0.0, 1.0, 2.0]])), "faces"),
    (dict(faces=np.array([0, 1, 2], np.uint32)), "faces"),
    (dict(vertices=np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0]], np.float32)), "vertices[1, 1]"),
    (dict(vertices=np.zeros((3, 3))), "vertices"),  # float64: the dtype is named
    (dict(R=np.full((3, 3), np.inf)), "R[0, 0]"),
    (dict(R=np.eye(2)), "R"),
    (dict(t=[0, 0]), "t"),
    (dict(width=0), "width"),
    (dict(height=-3), "height"),
    (dict(znear=1.0, zfar=0.5), "znear, zfar"),
    (dict(K=(0.0, 525.0, 319.5, 239.5)), "focal"),
])
def test_binding_errors_name_the_argument(kw, names):
    with pytest.raises(InvalidInputError, match=re.escape(names)):
        _core.render_depth(**_args(**kw))


def test_backend_choice(monkeypatch):
    monkeypatch.delenv(BACKEND_ENV, raising=False)
    assert resolve_backend() == "core" and DepthRenderer().backend == "core"
    monkeypatch.setenv(BACKEND_ENV, "pyrender")
    assert resolve_backend() == "pyrender" and resolve_backend("core") == "core"
    monkeypatch.setenv(BACKEND_ENV, "opengl")
    with pytest.raises(InvalidValueError, match=BACKEND_ENV):
        resolve_backend()
    with pytest.raises(InvalidValueError, match="backend"):
        DepthRenderer(backend="gl")


def test_rendering_needs_no_gl_library():
    # A fresh interpreter in which pyrender, PyOpenGL and pyglet cannot be imported, as after a
    # plain `pip install isa`: the default renderer works and loads none of them.
    code = ("import sys\n"
            "for m in ('pyrender', 'OpenGL', 'pyglet'): sys.modules[m] = None\n"
            "import numpy as np, trimesh\n"
            "from isa.render import DepthRenderer\n"
            "d, m = DepthRenderer().render(trimesh.creation.box(), np.eye(3), [0, 0, 2.0])\n"
            "print(int(m.sum()), sorted(k for k in sys.modules if k.split('.')[0] in ('pyrender', 'OpenGL', 'pyglet')"
            " and sys.modules[k] is not None))\n")
    env = {k: v for k, v in os.environ.items() if k != BACKEND_ENV}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout.split(" ", 1)
    assert int(out[0]) > 10_000 and out[1].strip() == "[]", out

"""Depth + mask rendering of meshes for an exact pose ``X_cam = R @ X_obj + t`` (OpenCV camera,
pixel centres at integers): float32 depth in metres (0 = background) and the object mask.

Two backends, the same frames up to the last bits of depth and the pixels whose centre lies
on a silhouette edge (docs/DESIGN.md, "Rendering", has the measurement):

- ``"core"`` (the default): the Rust core's z-buffer rasteriser (``isa._core.render_depth``,
  ``isa_core::render``), no OpenGL at all, so rendering works from a plain ``pip install isa``;
- ``"pyrender"``: headless pyrender (EGL or OSMesa), ``pip install 'isa[render]'`` and the
  system's GL libraries (:data:`HEADLESS_GL_APT`).

``DepthRenderer(backend=...)`` chooses; without it, the environment variable
``ISA_RENDER_BACKEND`` does, else ``"core"``.

GL facts the pyrender backend relies on (measured on the project machine, see issue #2):
- ``PYOPENGL_PLATFORM`` must be set before pyrender is imported; we default it to ``egl``.
- pyrender's pixel origin is the pixel corner, so the OpenCV principal point is passed as cx+0.5,
  cy+0.5.
- pyrender renders with 4x MSAA on EGL and copies (not resolves) the depth buffer, which moves mask
  edges by about a pixel; we force single-sample buffers, which is also faster.
- Do not fork a process that holds a GL context (use the "spawn" start method).
- pyrender culls back faces in depth-only mode whatever the material says, and ModelNet10 windings
  are inconsistent: every triangle is uploaded with both windings.
- Deleting a pyrender EGL context terminates the EGL display that every other context of the
  process shares, so all pyrender DepthRenderers share ONE GL context per process
  (:func:`release_gl` frees it).
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from isa.camera import KINECT_V1, Intrinsics
from isa.exceptions import InvalidValueError, MissingDependencyError, UsageError

__all__ = ["release_gl", "DepthRenderer", "render_depth", "resolve_backend", "BACKENDS"]

# OpenCV camera (y down, z forward) -> OpenGL camera (y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])

#: The backends of :class:`DepthRenderer`.
BACKENDS = ("core", "pyrender")
#: The environment variable that picks the backend when ``DepthRenderer`` is given none.
BACKEND_ENV = "ISA_RENDER_BACKEND"
#: The backend when neither the argument nor the environment variable names one.
DEFAULT_BACKEND = "core"

#: Debian packages that the pyrender backend needs headless (scripts/setup.sh installs them).
HEADLESS_GL_APT = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libgl1", "libxrender1", "libosmesa6")

_pyrender = None
_gl = None  # the process's shared pyrender.OffscreenRenderer


def _import_pyrender():
    """Import pyrender once, headless, with single-sample framebuffers."""
    global _pyrender
    if _pyrender is None:
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
        try:
            import pyrender
            import pyrender.renderer as prr
        except ImportError as e:
            raise MissingDependencyError(
                f"the pyrender backend needs pyrender ({e}): pip install 'isa[render]' (or bash scripts/setup.sh), "
                "and on Debian/Ubuntu the headless OpenGL libraries: "
                f"apt-get install {' '.join(HEADLESS_GL_APT)}; or render with backend='core' (the default, no OpenGL)") from e
        except OSError as e:  # a system library (libEGL, libGL, libOSMesa) failed to load
            raise MissingDependencyError(
                f"rendering could not load OpenGL ({e}); on Debian/Ubuntu: apt-get install {' '.join(HEADLESS_GL_APT)} "
                f"(PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']}; 'osmesa' is the fallback); "
                "or render with backend='core' (the default, no OpenGL)") from e

        if not getattr(prr, "_isa_single_sample", False):
            real = prr.glRenderbufferStorageMultisample

            def single_sample(target, samples, fmt, width, height):
                # 0 samples = an ordinary buffer: exact depth and mask edges, no MSAA cost.
                return real(target, 0, fmt, width, height)

            prr.glRenderbufferStorageMultisample = single_sample
            prr._isa_single_sample = True
        _pyrender = pyrender
    return _pyrender


def _shared_gl(width: int, height: int):
    """The process's one offscreen GL context, sized for the next frame."""
    global _gl
    pyrender = _import_pyrender()
    if _gl is None:
        _gl = pyrender.OffscreenRenderer(width, height)
    _gl.viewport_width, _gl.viewport_height = width, height
    return _gl


def release_gl() -> None:
    """Free the shared GL context (a later render creates a new one)."""
    global _gl
    if _gl is not None:
        _gl.delete()
        _gl = None


def resolve_backend(backend: str | None = None) -> str:
    """``backend``, else ``$ISA_RENDER_BACKEND``, else :data:`DEFAULT_BACKEND`; checked."""
    name = backend if backend is not None else (os.environ.get(BACKEND_ENV) or DEFAULT_BACKEND)
    if name not in BACKENDS:
        where = "backend" if backend is not None else BACKEND_ENV
        raise InvalidValueError(f"{where}: expected one of {', '.join(BACKENDS)}, got {name!r}")
    return name


class DepthRenderer:
    """Reusable depth renderer for one camera (any :class:`~isa.camera.Intrinsics`).

    >>> r = DepthRenderer(KINECT_V1)            # doctest: +SKIP
    >>> depth, mask = r.render(mesh, R, t)      # doctest: +SKIP
    >>> r.close()                               # doctest: +SKIP

    ``backend``: ``"core"`` (the Rust rasteriser, no OpenGL) or ``"pyrender"``; None reads
    ``$ISA_RENDER_BACKEND``, else ``"core"`` (:func:`resolve_backend`). Meshes are prepared once
    (contiguous arrays for the core, an uploaded GL mesh for pyrender) and cached by ``id`` and
    content hash (up to ``cache_size``), so rendering many views of the same mesh only moves the
    object. Both faces of every triangle are drawn (ModelNet10 windings are inconsistent).
    ``znear``/``zfar`` bound the rendered depth range in metres. All pyrender renderers of a
    process share one GL context; :meth:`close` only drops this renderer's scene and meshes.
    """

    def __init__(self, intrinsics: Intrinsics = KINECT_V1, znear: float = 0.05, zfar: float = 20.0, cache_size: int = 8,
                 backend: str | None = None):
        self.backend = resolve_backend(backend)
        self.intrinsics = intrinsics
        self.znear, self.zfar = float(znear), float(zfar)
        self._cache: dict[tuple[int, int], tuple[trimesh.Trimesh, object]] = {}
        self._cache_size = cache_size
        self._closed = False
        if self.backend == "pyrender":
            self._init_pyrender()

    def _init_pyrender(self) -> None:
        pyrender = _import_pyrender()
        intrinsics = self.intrinsics
        self._renderer = _shared_gl(intrinsics.width, intrinsics.height)
        self._scene = pyrender.Scene(bg_color=[0, 0, 0, 0], ambient_light=[1.0, 1.0, 1.0])
        cam = pyrender.IntrinsicsCamera(
            fx=intrinsics.fx, fy=intrinsics.fy, cx=intrinsics.cx + 0.5, cy=intrinsics.cy + 0.5, znear=self.znear, zfar=self.zfar
        )
        # The camera stays at the GL origin; each frame moves the object instead.
        self._scene.add(cam, pose=np.eye(4))
        self._material = pyrender.MetallicRoughnessMaterial(doubleSided=True)
        self._node = None

    def _prepared(self, mesh: trimesh.Trimesh, prepare):
        """``prepare(mesh)``, cached. hash(mesh) is trimesh's cached content hash: a mesh edited
        in place is prepared again."""
        key = (id(mesh), hash(mesh))
        if key not in self._cache:
            if len(self._cache) >= self._cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = (mesh, prepare(mesh))  # keep the mesh alive so that its id stays unique
        return self._cache[key][1]

    @staticmethod
    def _core_arrays(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
        return (np.ascontiguousarray(mesh.vertices, dtype=np.float32), np.ascontiguousarray(mesh.faces, dtype=np.uint32))

    def _gl_mesh(self, mesh: trimesh.Trimesh):
        pyrender = _pyrender
        f = np.asarray(mesh.faces, dtype=np.uint32)
        prim = pyrender.Primitive(
            positions=np.asarray(mesh.vertices, dtype=np.float32),
            indices=np.concatenate([f, f[:, ::-1]]),  # both windings: nothing is culled
            material=self._material,
            mode=pyrender.constants.GLTF.TRIANGLES,
        )
        return pyrender.Mesh([prim])

    def _mesh_node(self, mesh: trimesh.Trimesh):
        pm = self._prepared(mesh, self._gl_mesh)
        if self._node is None or self._node.mesh is not pm:
            if self._node is not None:
                self._scene.remove_node(self._node)
            self._node = self._scene.add(pm)
        return self._node

    def render(self, mesh: trimesh.Trimesh, R, t) -> tuple[np.ndarray, np.ndarray]:
        """Depth (H, W) float32 metres (0 = background) and mask (H, W) bool of ``mesh`` at pose (R, t)."""
        if self._closed:
            raise UsageError("DepthRenderer.render after close()")
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64).reshape(3)
        K = self.intrinsics
        if self.backend == "core":
            from isa import _core

            vertices, faces = self._prepared(mesh, self._core_arrays)
            return _core.render_depth(vertices, faces, R, t, K, K.width, K.height, self.znear, self.zfar)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t
        node = self._mesh_node(mesh)
        self._scene.set_pose(node, _CV_TO_GL @ T)
        gl = _shared_gl(K.width, K.height)
        depth = gl.render(self._scene, flags=_pyrender.RenderFlags.DEPTH_ONLY)
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        return depth, depth > 0

    def close(self) -> None:
        """Drop this renderer's meshes (and its GL scene; safe to call twice); the shared GL context stays."""
        if not self._closed:
            if self.backend == "pyrender" and self._node is not None:
                self._scene.remove_node(self._node)
                self._node = None
            self._renderer = None
            self._closed = True
            self._cache.clear()

    def __enter__(self) -> "DepthRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def render_depth(mesh: trimesh.Trimesh, R, t, intrinsics: Intrinsics = KINECT_V1,
                 backend: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-off render (prepares the mesh each call: use :class:`DepthRenderer` for many frames)."""
    with DepthRenderer(intrinsics, backend=backend) as r:
        return r.render(mesh, R, t)

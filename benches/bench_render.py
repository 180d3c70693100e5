"""Rendering throughput and the paper's chair training set (28 instances x 89 views) to BOP.

    python benches/bench_render.py [--frames 200] [--keep DIR]

Prints a table: frames per second at 640x480 on a real ModelNet10 chair for the pyrender depth
renderer, against exact ray casting (trimesh + embreex, the tests' oracle) as the baseline of the
same run; then the wall time to render and write the paper's chair training set into a fresh BOP
folder, and to resume it (every frame already there). Skips, saying why, when ../shared/data is
absent.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))


def _raycast_fps(mesh, views, K, n: int) -> float:
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    ri = RayMeshIntersector(mesh)
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    t0 = time.perf_counter()
    for i in range(n):
        R, t = views[i % len(views)]
        o = np.repeat((-R.T @ t)[None], len(rays), 0)
        ri.intersects_location(o, rays @ R, multiple_hits=False)
    return n / (time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200, help="frames for the throughput test")
    ap.add_argument("--keep", type=Path, default=None, help="write the chair set here instead of a temp dir")
    a = ap.parse_args()
    mn = SHARED / "modelnet10"
    if not mn.is_dir():
        print(f"SKIP bench_render: real data not found at {mn} (set ISA_SHARED_DATA or check out ../shared)")
        return 0

    from isa.camera import KINECT_V1
    from isa.data.meshes import prepare_mesh
    from isa.render.dataset import modelnet_objects, render_dataset
    from isa.render.renderer import DepthRenderer
    from isa.render.views import training_views

    K = KINECT_V1
    path = mn / "ModelNet10" / "chair" / "train" / "chair_0001.off"
    mesh, _ = prepare_mesh(path, "chair", 0)
    views = training_views(89, seed=0)
    t0 = time.perf_counter()
    r = DepthRenderer(K)
    r.render(mesh, *views[0])  # context + upload
    t_ctx = time.perf_counter() - t0
    t0 = time.perf_counter()
    for i in range(a.frames):
        r.render(mesh, *views[i % len(views)])
    fps = a.frames / (time.perf_counter() - t0)
    fps_ray = _raycast_fps(mesh, views, K, max(10, a.frames // 10))

    print(f"\nrendering throughput, {K.width}x{K.height}, {path.name} ({len(mesh.faces)} faces), {os.cpu_count()} cores")
    print("| method | frames/s | ms/frame | ratio |\n|---|---:|---:|---:|")
    print(f"| exact ray casting (embreex, baseline) | {fps_ray:.1f} | {1000 / fps_ray:.1f} | 1.0 |")
    print(f"| pyrender depth+mask (isa.render.renderer) | {fps:.1f} | {1000 / fps:.1f} | {fps / fps_ray:.1f} |")
    print(f"(first frame incl. GL context and upload: {t_ctx * 1000:.0f} ms)")

    with tempfile.TemporaryDirectory(prefix="isa_bench_") as tmp:
        out = a.keep if a.keep is not None else Path(tmp) / "chair"
        t0 = time.perf_counter()
        objs = modelnet_objects(mn, "chair", seed=0, progress=False)  # the paper's 28 instances
        t_load = time.perf_counter() - t0
        s = render_dataset(out, objs, n_views=89, renderer=r, progress=sys.stderr.isatty())
        s2 = render_dataset(out, objs, n_views=89, renderer=r, progress=False)
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    r.close()
    n = s.rendered + s.skipped
    print(f"\npaper chair training set: {len(objs)} instances x 89 views = {n} frames -> BOP ({size / 1e6:.0f} MB)")
    print("| step | seconds | frames/s |\n|---|---:|---:|")
    print(f"| load + rescale 28 meshes | {t_load:.1f} | |")
    print(f"| render + write (fresh) | {s.seconds:.1f} | {s.rendered / s.seconds:.1f} |")
    print(f"| resume (all {s2.skipped} frames present) | {s2.seconds:.1f} | |")
    print(f"aim: under 60 s -> {'met' if t_load + s.seconds < 60 else 'NOT met'} ({t_load + s.seconds:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

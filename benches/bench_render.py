"""Depth rendering: the core rasteriser against pyrender (speed and exactness), and the paper's
chair training set (28 instances x 89 views) rendered to BOP.

    python benches/bench_render.py [--frames 200] [--keep DIR] [--backend core|pyrender]
    python benches/bench_render.py --agreement 2      # core vs pyrender, 2 instances per category

Prints a table of milliseconds per 640x480 frame on a real ModelNet10 chair (a procedural one
when ../shared/data is absent) for each renderer, pyrender the baseline of the same run (exact
ray casting with trimesh + embreex, the tests' oracle, beside them); then the wall time to render
and write the paper's chair training set into a fresh BOP folder with ``--backend`` (default:
the renderer's default), and to resume it. ``--agreement N`` instead compares the two backends
on the first N training instances of bed, chair, table and toilet at their 89 training views:
pixels whose mask differs (and how many of those are off a silhouette edge), and the depth
differences on pixels both cover (tests/render_agreement.py).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))
sys.path.insert(0, str(ROOT / "tests"))  # the frame comparison is the tests' (one copy for both)

from render_agreement import Agreement, smooth_pixels  # noqa: E402


def _raycast_ms(mesh, views, K, n: int) -> float:
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    ri = RayMeshIntersector(mesh)
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    t0 = time.perf_counter()
    for i in range(n):
        R, t = views[i % len(views)]
        o = np.repeat((-R.T @ t)[None], len(rays), 0)
        ri.intersects_location(o, rays @ R, multiple_hits=False)
    return 1000 * (time.perf_counter() - t0) / n


def _renderer(backend: str, K):
    from isa.exceptions import MissingDependencyError
    from isa.render.renderer import DepthRenderer

    try:
        return DepthRenderer(K, backend=backend)
    except MissingDependencyError as e:
        print(f"({backend} unavailable: {e})")
        return None


def _ms_per_frame(r, mesh, views, n: int) -> tuple[float, float]:
    """(first frame incl. set-up and upload, then ms per frame)."""
    t0 = time.perf_counter()
    r.render(mesh, *views[0])
    first = 1000 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    for i in range(n):
        r.render(mesh, *views[i % len(views)])
    return first, 1000 * (time.perf_counter() - t0) / n


def throughput(mesh, name: str, frames: int) -> None:
    from isa.camera import KINECT_V1 as K
    from isa.render.views import training_views

    views = training_views(89, seed=0)
    rows = []
    for backend in ("pyrender", "core"):
        r = _renderer(backend, K)
        if r is not None:
            rows.append((backend, *_ms_per_frame(r, mesh, views, frames)))
            r.close()
    try:
        rows.append(("exact ray casting (embreex)", float("nan"), _raycast_ms(mesh, views, K, max(10, frames // 10))))
    except ImportError as e:
        print(f"(ray casting unavailable: {e})")
    base = rows[0][2] if rows and rows[0][0] == "pyrender" else float("nan")
    print(f"\nrendering, {K.width}x{K.height}, {name} ({len(mesh.faces)} faces), {os.cpu_count()} cores, {frames} frames")
    print("| renderer | ms/frame | frames/s | speed vs pyrender | first frame (set-up) ms |\n|---|---:|---:|---:|---:|")
    for label, first, ms in rows:
        print(f"| {label} | {ms:.2f} | {1000 / ms:.1f} | {base / ms:.2f}x | {first:.0f} |")


def agreement(mn: Path, n: int) -> dict:
    """Core vs pyrender on the first ``n`` training instances of each category, all 89 views."""
    from isa.camera import KINECT_V1 as K
    from isa.render.dataset import default_views, modelnet_objects

    core, gl = _renderer("core", K), _renderer("pyrender", K)
    if gl is None:
        return {}
    out = {}
    judged = {"pixels": 0, "core_is_ray": 0, "pyrender_is_ray": 0}
    print(f"\ncore vs pyrender, {K.width}x{K.height}, first {n} training instances x 89 training views")
    print("| category | frames | mask agrees | mask differs, px (off edges) | smooth px | |dz| median | |dz| 99.9% |"
          " |dz| max smooth | smooth px > 0.1 mm | |dz| max any |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    total = Agreement()
    for cat in ("bed", "chair", "table", "toilet"):
        a = Agreement()
        for o in modelnet_objects(mn, cat, n, progress=False):
            for R, t in default_views(o, 89):
                frames = (*core.render(o.mesh, R, t), *gl.render(o.mesh, R, t))
                a.add(*frames)
                total.add(*frames)
                _judge(o.mesh, R, t, frames, judged)
        out[cat] = s = a.summary()
        _row(cat, s)
    out["all"] = s = total.summary()
    _row("all", s)
    out["judged_by_ray_casting"] = judged
    print(f"smooth pixels whose depths differ by more than 0.1 mm: {judged['pixels']}; equal to exact ray casting"
          f" (within 1e-5 m) there: core {judged['core_is_ray']}, pyrender {judged['pyrender_is_ray']}")
    return out


def _judge(mesh, R, t, frames, judged: dict) -> None:
    """Ray casting decides the smooth pixels where the backends' depths differ by > 0.1 mm."""
    from isa.camera import KINECT_V1 as K

    dc, mc, dg, mg = frames
    bad = np.argwhere(smooth_pixels(*frames) & (np.abs(dc - dg) > 1e-4))
    if len(bad) == 0:
        return
    d = np.stack([(bad[:, 1] - K.cx) / K.fx, (bad[:, 0] - K.cy) / K.fy, np.ones(len(bad))], -1)
    origins = np.repeat((-R.T @ t)[None], len(bad), 0)
    _, ray, loc = mesh.ray.intersects_id(origins, d @ R, multiple_hits=False, return_locations=True)
    z = np.zeros(len(bad))
    z[ray] = (loc @ R.T + t)[:, 2]
    judged["pixels"] += len(bad)
    judged["core_is_ray"] += int((np.abs(dc[bad[:, 0], bad[:, 1]] - z) < 1e-5).sum())
    judged["pyrender_is_ray"] += int((np.abs(dg[bad[:, 0], bad[:, 1]] - z) < 1e-5).sum())


def _row(label: str, s: dict) -> None:
    print(f"| {label} | {s['frames']} | {100 * s['mask_agree_frac']:.3f}% | {s['mask_differ_px']} ({s['mask_differ_off_edge_px']}) |"
          f" {s['smooth_px']} | {s['depth_diff_median_m']:.1e} | {s['depth_diff_p999_m']:.1e} | {s['depth_diff_max_smooth_m']:.1e} |"
          f" {s['smooth_px_over_1e-4_m']} | {s['depth_diff_max_all_m']:.2f} |")


def chair_set(mn: Path, backend: str | None, keep: Path | None) -> None:
    from isa.render.dataset import modelnet_objects, render_dataset
    from isa.render.renderer import DepthRenderer

    r = DepthRenderer(backend=backend)
    with tempfile.TemporaryDirectory(prefix="isa_bench_") as tmp:
        out = keep if keep is not None else Path(tmp) / "chair"
        t0 = time.perf_counter()
        objs = modelnet_objects(mn, "chair", seed=0, progress=False)  # the paper's 28 instances
        t_load = time.perf_counter() - t0
        s = render_dataset(out, objs, n_views=89, renderer=r, progress=sys.stderr.isatty())
        s2 = render_dataset(out, objs, n_views=89, renderer=r, progress=False)
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    r.close()
    n = s.rendered + s.skipped
    print(f"\npaper chair training set ({r.backend}): {len(objs)} instances x 89 views = {n} frames -> BOP ({size / 1e6:.0f} MB)")
    print("| step | seconds | frames/s |\n|---|---:|---:|")
    print(f"| load + rescale 28 meshes | {t_load:.1f} | |")
    print(f"| render + write (fresh) | {s.seconds:.1f} | {s.rendered / s.seconds:.1f} |")
    print(f"| resume (all {s2.skipped} frames present) | {s2.seconds:.1f} | |")
    print(f"aim: under 60 s -> {'met' if t_load + s.seconds < 60 else 'NOT met'} ({t_load + s.seconds:.1f} s)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200, help="frames per renderer for the speed table")
    ap.add_argument("--keep", type=Path, default=None, help="write the chair set here instead of a temp dir")
    ap.add_argument("--backend", choices=("core", "pyrender"), default=None, help="renderer of the chair set")
    ap.add_argument("--agreement", type=int, default=0, metavar="N", help="compare the backends on N instances per category")
    ap.add_argument("--json", type=Path, default=None, help="also write the agreement figures here")
    a = ap.parse_args()
    mn = SHARED / "modelnet10"
    if a.agreement:
        if not mn.is_dir():
            print(f"SKIP agreement: real data not found at {mn} (set ISA_SHARED_DATA or check out ../shared)")
            return 0
        res = agreement(mn, a.agreement)
        if a.json is not None:
            a.json.write_text(json.dumps(res, indent=1))
        return 0

    if mn.is_dir():
        from isa.data.meshes import prepare_mesh

        path = mn / "ModelNet10" / "chair" / "train" / "chair_0001.off"
        mesh, name = prepare_mesh(path, "chair", 0)[0], path.name
    else:
        from isa.data.procedural import generate

        mesh, name = generate("chair", 0).mesh, "procedural chair (../shared/data absent)"
    throughput(mesh, name, a.frames)
    if mn.is_dir():
        chair_set(mn, a.backend, a.keep)
    else:
        print(f"SKIP chair set: real data not found at {mn}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

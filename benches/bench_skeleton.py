"""Skeletons, matching and SSC for the paper's 28 chairs, and the annotation of all their parts.

    python benches/bench_skeleton.py [--views 89] [--stride 4] [--figures DIR]

First prints, per category, the extracted skeletons' accuracy against the procedural ground truth
(issue #3's two claims, seeds 0-11 and held-out seeds 50-57; needs no data). Then a table of wall
times: the category template (procedural ground truth, calibrated on procedural chairs),
curve-skeleton extraction, matching and the SSC (COMs + vote) for the first 28 ModelNet10 chair
train meshes at real size (the paper's protocol), then the rendering of their
training views (another module's cost, shown for scale) and the annotation of every part of them
(``build_training_set``), against a direct per-part Python loop on a subset as the baseline of the
same run. ``--figures`` also writes the matched grid, the COM vs SSC figure and depth renders with
the projected skeleton. Skips, saying why, when ../shared/data is absent.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))
sys.path.insert(0, str(ROOT / "tests"))  # the per-part loop baseline is the tests' reference

from annotate_reference import loop_annotations  # noqa: E402


def ground_truth_table(seeds=range(12)) -> None:
    """Issue #3's claims on procedural instances: per category, (a) the mean over instances of the
    mean distance from extracted nodes to the complete true skeleton (the template's links and the
    extra members of ``skeleton.meta["members"]``; the template's links alone in brackets, for
    reference) and (b) how many instances have every template junction/endpoint within 10% of the
    diameter of an extracted node."""
    from isa.data.procedural import generate, skeleton_segments
    from isa.privileged.skeleton import extract_skeleton

    def seg_dist(P, A, B):
        d = B - A
        t = np.clip(np.einsum("nmk,mk->nm", P[:, None] - A[None], d) / np.maximum((d * d).sum(1), 1e-12), 0, 1)
        return np.linalg.norm(P[:, None] - (A[None] + t[..., None] * d[None]), axis=2).min(1)

    print("\n| category | (a) mean node distance, % diameter (template links only) | (b) key points all within 10% "
          "| worst key point (%) | s |\n|---|---:|---:|---:|---:|")
    for cat in ("chair", "table", "bed", "toilet"):
        t0 = time.perf_counter()
        means, means_t, keys = [], [], []
        for s in seeds:
            o = generate(cat, s)
            gt, g = o.skeleton, extract_skeleton(o.mesh)
            diam = float(np.linalg.norm(o.mesh.extents))
            means.append(seg_dist(g.nodes, *skeleton_segments(gt)).mean() / diam)
            means_t.append(seg_dist(g.nodes, gt.nodes[gt.links[:, 0]], gt.nodes[gt.links[:, 1]]).mean() / diam)
            deg = np.bincount(gt.links.ravel(), minlength=len(gt.nodes))
            keys.append(np.linalg.norm(gt.nodes[deg != 2][:, None] - g.nodes[None], axis=2).min(1).max() / diam)
        keys = np.array(keys)
        print(f"| {cat} (seeds {min(seeds)}-{max(seeds)}) | {np.mean(means) * 100:.1f} ({np.mean(means_t) * 100:.1f}) "
              f"| {(keys < 0.10).sum()}/{len(keys)} | {keys.max() * 100:.1f} | {time.perf_counter() - t0:.1f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--views", type=int, default=89, help="training views per instance (paper: 89)")
    ap.add_argument("--stride", type=int, default=4, help="part grid stride in pixels")
    ap.add_argument("--figures", type=Path, default=None, help="write the skeleton figures into this folder")
    a = ap.parse_args()
    ground_truth_table()
    ground_truth_table(range(50, 58))  # held out: not the tests' seeds
    mn = SHARED / "modelnet10"
    if not mn.is_dir():
        print(f"SKIP bench_skeleton: real data not found at {mn} (set ISA_SHARED_DATA or check out ../shared)")
        return 0

    from isa.camera import KINECT_V1
    from isa.data.meshes import prepare_mesh
    from isa.data.modelnet import paper_instances
    from isa.data.procedural import generate
    from isa.privileged.annotate import Frame, build_training_set
    from isa.privileged.matching import calibrate_template, match_skeleton, template_from_ground_truth
    from isa.privileged.skeleton import extract_skeleton
    from isa.privileged.ssc import select_ssc
    from isa.render.renderer import DepthRenderer
    from isa.render.views import training_views

    rows: list[tuple[str, float, str]] = []

    def step(name: str, t0: float, note: str = "") -> float:
        dt = time.perf_counter() - t0
        rows.append((name, dt, note))
        print(f"  {name}: {dt:.2f} s {note}", file=sys.stderr)
        return dt

    insts = paper_instances(mn, "chair")
    t0 = time.perf_counter()
    meshes = [prepare_mesh(inst.path, "chair", seed=i)[0] for i, inst in enumerate(insts)]
    step("load + real size (28 meshes)", t0)

    t0 = time.perf_counter()
    gt = [generate("chair", (7, i)) for i in range(20)]
    tmpl = template_from_ground_truth([o.skeleton for o in gt], [o.mesh.bounds for o in gt])
    cal = gt[:8]
    tmpl = calibrate_template(tmpl, [extract_skeleton(o.mesh) for o in cal], [o.skeleton for o in cal], [o.mesh.bounds for o in cal])
    step("template (20 procedural GT, 8 calibrated)", t0)

    t0 = time.perf_counter()
    raws = [extract_skeleton(m) for m in meshes]
    dt = step("skeleton extraction", t0, f"({len(meshes)} meshes, {np.mean([len(r.nodes) for r in raws]):.0f} nodes avg)")
    t_skel = dt
    t0 = time.perf_counter()
    matched = [match_skeleton(r, tmpl) for r in raws]
    t_match = step("matching to the template", t0, f"({np.mean([np.mean(m.meta['matched']) for m in matched]) * 100:.0f}% nodes matched)")
    t0 = time.perf_counter()
    coms = np.array([r.meta["com"] for r in raws])  # the extraction's solid, as centre_of_mass()
    ssc = select_ssc(matched, coms)
    sscs = np.array([ssc.point(m) for m in matched])
    t_ssc = step("COMs + SSC vote", t0, f"(SSC = {', '.join(tmpl.names[i] for i in ssc.nodes)}; votes {ssc.votes.max()}/{len(meshes)})")
    rows.append(("= skeletons + matching + SSC", t_skel + t_match + t_ssc, ""))

    # Object frames at the SSC (what the lead wires into meshes/dataset).
    centred, skels = [], []
    for m, sk, c in zip(meshes, matched, sscs):
        mm = m.copy()
        mm.apply_translation(-c)
        centred.append(mm)
        skels.append(sk.transformed(np.eye(3), -c))

    t0 = time.perf_counter()
    frames = []
    with DepthRenderer(KINECT_V1) as r:
        for i, (m, sk) in enumerate(zip(centred, skels)):
            views = training_views(a.views, seed=i, fit_points=m.convex_hull.vertices)
            for R, t in views:
                depth, mask = r.render(m, R, t)
                frames.append(Frame(depth, mask, R, t, KINECT_V1, sk))
    step("render training views (not annotation)", t0, f"({len(frames)} frames)")

    t0 = time.perf_counter()
    ts = build_training_set(frames, stride=a.stride)
    t_ann = step("annotate all parts (vectorised)", t0, f"({len(ts):,} parts, {len(tmpl.nodes)} nodes, {ts.link_angles.shape[1]} links)")
    sub = frames[:: max(1, len(frames) // 20)]
    t0 = time.perf_counter()
    n_loop = sum(len(loop_annotations(f, a.stride, 2000)) for f in sub)
    t_loop = time.perf_counter() - t0
    loop_rate = n_loop / t_loop
    vec_rate = len(ts) / t_ann

    print("\n| step | wall time (s) | note |\n|---|---:|---|")
    for name, dt, note in rows:
        print(f"| {name} | {dt:.2f} | {note} |")
    print("\n| annotation | parts/s | x baseline |\n|---|---:|---:|")
    print(f"| per-part Python loop (baseline, {n_loop:,} parts) | {loop_rate:,.0f} | 1.0 |")
    print(f"| build_training_set | {vec_rate:,.0f} | {vec_rate / loop_rate:.0f} |")
    print(f"\nall {len(ts):,} parts: {t_ann:.1f} s vectorised vs {len(ts) / loop_rate:.0f} s by the loop (extrapolated)")

    if a.figures is not None:
        from isa.report.figures.skeletons import com_vs_ssc, depth_with_skeleton, matched_grid

        names = [i.name for i in insts]
        print(matched_grid(meshes, matched, a.figures / "chair_matched_grid.png", titles=names))
        pick = [0, 3, 6, 9, 12, 20]
        print(com_vs_ssc([meshes[i] for i in pick], coms[pick], sscs[pick], a.figures / "chair_com_vs_ssc.png",
                         matched=[matched[i] for i in pick], titles=[names[i] for i in pick]))
        fs = [frames[k] for k in (0, 30, 60, a.views + 10, 2 * a.views + 40, 5 * a.views + 70)]
        print(depth_with_skeleton([f.depth for f in fs], [f.skeleton for f in fs], [(f.R, f.t) for f in fs], KINECT_V1,
                                  a.figures / "chair_depth_skeleton.png", columns=3))
    return 0


if __name__ == "__main__":
    sys.exit(main())

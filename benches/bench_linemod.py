"""Linemod's per-frame matching time at 640x480 with a whole category's templates (issue #5).

    python benches/bench_linemod.py [--category chair] [--instances 28] [--views 89] [--frames 20]
                                    [--thresholds 0 80] [--repeats 3] [--distance 1.5 4]
                                    [--recall [--test-images 264] [--template-distance 2.2 2.8]]

Builds ONE detector (isa.evaluation.linemod.LinemodDetector) holding the training views of the category's
first ``--instances`` training instances (ModelNet10 from ../shared/data, or procedural objects
when it is absent or with ``--procedural``), renders ``--frames`` test images of unseen test
instances from random non-training views, and prints per-frame matching time for each match
threshold: the whole ``match`` call (float metres in, pose out) and OpenCV's ``match`` alone.
The fastest setting (highest threshold) is Linemod's best case against which ISA's inference time
is compared; :func:`linemod_timings` returns the numbers so that another bench can put ISA's
time beside them in the same run.

With ``--recall`` it also runs the paper's protocol on ``--test-images`` test images: one detector
per training instance, recall at z = 0.1 of the SSC average-distance metric (origin: the object
frame's origin) with Linemod's own translation and with the true translation substituted (about
5 minutes for the chairs; see isa/linemod.py for the numbers measured).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))


@dataclass
class Frame:
    """A test image: float32 depth (m), the true pose, and which test object it shows."""

    depth: np.ndarray
    R: np.ndarray
    t: np.ndarray
    obj: int


def load_objects(category: str, n_train: int, n_test: int | None, procedural: bool, seed: int = 0):
    """(train objects, test objects, source name): ModelNet10 when present, else procedural."""
    from isa.render.dataset import modelnet_objects, procedural_objects

    mn = SHARED / "modelnet10"
    if not procedural and mn.is_dir():
        train = modelnet_objects(mn, category, n_train, "train", seed=seed, progress=False)
        test = modelnet_objects(mn, category, n_test, "test", seed=seed, progress=False)
        return train, test, "ModelNet10"
    train = procedural_objects(category, n_train, seed=seed)
    test = procedural_objects(category, n_test or 25, seed=seed + 1000, first_obj_id=1000)
    return train, test, "procedural"


def build_detector(objects, renderer, n_views: int = 89, seed: int = 0, distance=None, **params):
    """One LinemodDetector holding ``n_views`` training views of every object in ``objects``:
    the dataset's training views (``isa.render.dataset.default_views``, 1.5-4 m), or with ``distance``
    (min, max) metres the same directions at distances drawn from that range."""
    from isa.evaluation.linemod import LinemodDetector
    from isa.render.dataset import default_views, hull_points
    from isa.render.views import ViewBand, training_views

    det = LinemodDetector(renderer.intrinsics, **params)
    for obj in objects:
        if distance is None:
            views = default_views(obj, n_views, seed=seed, intrinsics=renderer.intrinsics)
        else:
            views = training_views(n_views, seed=[seed, obj.obj_id], band=ViewBand(distance=tuple(distance)),
                                   fit_points=hull_points(obj.mesh), intrinsics=renderer.intrinsics)
        for R, t in zip(views.R, views.t):
            depth, mask = renderer.render(obj.mesh, R, t)
            det.add_view(depth, mask, R, t)
    return det


def render_test_frames(objects, renderer, n: int, seed: int = 1, distance=(1.5, 4.0)) -> list[Frame]:
    """``n`` test images cycling over ``objects``, each from a random view that is not a training
    view of that object (3 degrees away at least), the whole object in the image."""
    from isa.render.dataset import default_views, hull_points
    from isa.render.views import ViewBand, sample_test_views

    per = [n // len(objects) + (i < n % len(objects)) for i in range(len(objects))]
    frames = []
    for obj, k in zip(objects, per):
        if k == 0:
            continue
        views = sample_test_views(
            k, seed=[seed, obj.obj_id], exclude=default_views(obj, intrinsics=renderer.intrinsics),
            band=ViewBand(distance=tuple(distance)), fit_points=hull_points(obj.mesh), intrinsics=renderer.intrinsics,
        )
        for R, t in zip(views.R, views.t):
            frames.append(Frame(renderer.render(obj.mesh, R, t)[0], R, t, obj.obj_id))
    return frames


def linemod_timings(detector, depths: Sequence[np.ndarray], thresholds=(0, 80), repeats: int = 1) -> dict:
    """Per-frame Linemod matching times of ``detector`` on ``depths`` (float32 m) per threshold.

    Returns ``{threshold: {"match_ms": array, "opencv_ms": array, "matched": fraction}}`` where
    ``match_ms`` times :meth:`LinemodDetector.match` (metres -> mm, OpenCV, pose of the best
    match) and ``opencv_ms`` OpenCV's ``match`` alone on the ready uint16 image; each frame's time
    is its fastest of ``repeats`` runs.
    """
    from isa.evaluation.linemod import depth_to_mm

    mms = [depth_to_mm(d) for d in depths]
    out = {}
    for th in thresholds:
        full = np.full((len(depths), repeats), np.inf)
        raw = np.full((len(depths), repeats), np.inf)
        matched = 0
        for i, (d, mm) in enumerate(zip(depths, mms)):
            for r in range(repeats):
                t0 = time.perf_counter()
                m = detector.match(d, th)
                full[i, r] = time.perf_counter() - t0
                t0 = time.perf_counter()
                detector.match_raw(mm, th)
                raw[i, r] = time.perf_counter() - t0
            matched += m is not None
        out[th] = {"match_ms": full.min(1) * 1e3, "opencv_ms": raw.min(1) * 1e3, "matched": matched / len(depths)}
    return out


def print_timings(timings: dict, detector, title: str) -> None:
    print(f"\n{title}")
    print("| threshold | match() median ms | p90 ms | OpenCV match median ms | frames with a match |")
    print("|---:|---:|---:|---:|---:|")
    for th, r in timings.items():
        print(
            f"| {th:g} | {np.median(r['match_ms']):.1f} | {np.percentile(r['match_ms'], 90):.1f} | "
            f"{np.median(r['opencv_ms']):.1f} | {100 * r['matched']:.0f} % |"
        )


def print_isa_ratio(model: Path, depths: Sequence[np.ndarray], intrinsics, timings: dict, repeats: int) -> None:
    """ISA's whole-frame inference (``Forest.predict``: parts, every tree, votes, modes) on the
    same images, each frame's fastest of ``repeats`` runs after one warm-up call, and Linemod's
    time per frame divided by it."""
    from isa.forest.model import Forest

    forest = Forest.load(model)
    forest.predict(depths[0], intrinsics)
    ms = np.full((len(depths), max(1, repeats)), np.inf)
    for i, d in enumerate(depths):
        for r in range(ms.shape[1]):
            t0 = time.perf_counter()
            forest.predict(d, intrinsics)
            ms[i, r] = (time.perf_counter() - t0) * 1e3
    isa_ms = float(np.median(ms.min(1)))
    print(f"\nISA {model.name} ({forest.n_trees} trees, deepest {max(forest.depths)}), same images: "
          f"median {isa_ms:.1f} ms per frame")
    print("| Linemod threshold | Linemod match() median ms | ISA median ms | Linemod / ISA |\n|---:|---:|---:|---:|")
    for th, t in timings.items():
        lm = float(np.median(t["match_ms"]))
        print(f"| {th:g} | {lm:.1f} | {isa_ms:.1f} | {lm / isa_ms:.2f}x |")


def recall_protocol(train, frames, test_objects, renderer, n_views: int, z: float = 0.1, seed: int = 0, distance=None):
    """The paper's Linemod protocol on the given frames: returns (recall with Linemod's translation,
    recall with the true translation substituted), both :class:`isa.evaluation.linemod.LinemodRecall`."""
    import trimesh

    from isa.evaluation.linemod import linemod_recall
    from isa.evaluation.pose_metrics import average_distance, model_diameter

    pts = {}
    for o in test_objects:
        X = trimesh.sample.sample_surface(o.mesh, 2000, seed=0)[0]
        pts[o.obj_id] = (X, model_diameter(o.mesh.convex_hull.vertices))

    def correct(R_est, t_est, f):
        X, phi = pts[f.obj]
        return average_distance(X, f.R, f.t, R_est, t_est) <= z * phi

    def with_true_t(R_est, t_est, f):
        return correct(R_est, f.t, f)

    def detectors():
        for o in train:
            yield Path(o.source).stem, lambda o=o: build_detector([o], renderer, n_views, seed, distance)

    est = linemod_recall(detectors(), frames, correct, progress=sys.stderr.isatty())
    return est, est.rescore(with_true_t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--category", default="chair")
    ap.add_argument("--instances", type=int, default=28, help="training instances in the one detector (paper: chair 28)")
    ap.add_argument("--views", type=int, default=89, help="training views per instance (paper: 89)")
    ap.add_argument("--frames", type=int, default=20, help="test images to time")
    ap.add_argument("--repeats", type=int, default=1, help="runs per frame (the fastest counts)")
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0, 80], help="match similarity thresholds (%%)")
    ap.add_argument("--procedural", action="store_true", help="procedural objects even when ModelNet10 is present")
    ap.add_argument("--recall", action="store_true", help="also run the paper's per-instance recall protocol")
    ap.add_argument("--model", type=Path, default=None,
                    help="an ISA model (.isa, e.g. out/paper/models/chair-Q1Q2Q3.isa): time its whole-frame "
                         "inference on the same test images and print the ratio to Linemod")
    ap.add_argument("--test-images", type=int, default=264, help="test images for --recall (paper: 264)")
    ap.add_argument("--distance", type=float, nargs=2, default=[1.5, 4.0], metavar=("MIN", "MAX"),
                    help="camera distance range of the test images, metres (default 1.5-4 as the training views)")
    ap.add_argument("--template-distance", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                    help="camera distance range of the templates for --recall (default: the dataset's training views)")
    a = ap.parse_args(argv)

    import cv2

    from isa.camera import KINECT_V1
    from isa.render.renderer import DepthRenderer

    train, test, source = load_objects(a.category, a.instances, None, a.procedural)
    r = DepthRenderer(KINECT_V1)
    t0 = time.perf_counter()
    det = build_detector(train, r, a.views)
    t_build = time.perf_counter() - t0
    frames = render_test_frames(test, r, a.frames, distance=tuple(a.distance))
    print(
        f"Linemod (OpenCV {cv2.__version__}, depth modality, pyramid {det.params['pyramid']}), "
        f"{KINECT_V1.width}x{KINECT_V1.height}, {os.cpu_count()} cores, cv2 threads {cv2.getNumThreads()}"
    )
    print(
        f"one detector: {source} {a.category}, {len(train)} training instances x {a.views} views = {det.n_views} views, "
        f"{det.n_templates} accepted, {len(det.refused)} refused; built (render + addTemplate) in {t_build:.1f} s"
    )
    timings = linemod_timings(det, [f.depth for f in frames], a.thresholds, a.repeats)
    print_timings(timings, det, f"per-frame matching time on {len(frames)} test images of unseen {a.category}s")
    del det
    if a.model is not None:
        print_isa_ratio(a.model, [f.depth for f in frames], KINECT_V1, timings, a.repeats)

    if a.recall:
        t0 = time.perf_counter()
        frames = render_test_frames(test, r, a.test_images, distance=tuple(a.distance))
        est, true_t = recall_protocol(train, frames, test, r, a.views, distance=a.template_distance)
        print(
            f"\nthe paper's protocol: {len(train)} detectors x {a.views} views, {len(frames)} test images of "
            f"{len(test)} unseen {a.category}s at {a.distance[0]:g}-{a.distance[1]:g} m, templates at "
            f"{'1.5-4 m (dataset views)' if a.template_distance is None else '%g-%g m' % tuple(a.template_distance)}, recall at z = 0.1 "
            f"({time.perf_counter() - t0:.0f} s)"
        )
        print("| translation | min % | max % | mean (all) % |\n|---|---:|---:|---:|")
        for name, res in (("Linemod's (matched position + depth)", est), ("true (rotation only)", true_t)):
            print(f"| {name} | {100 * res.min:.1f} | {100 * res.max:.1f} | {100 * res.mean:.1f} |")
        refused = sum(est.refused.values())
        per = ", ".join(f"{n} {est.refused[n]}" for n in est.names if est.refused[n])
        print(f"refused views: {refused} of {len(train) * a.views}" + (f" ({per})" if per else ""))
    r.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

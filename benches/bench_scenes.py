"""Scene generation speed at 640x480: synthetic rooms written to BOP (rooms, cameras, per-instance
renders for masks and visibility, noise, PNGs and JSON), against the plain single-object renderer
(``isa.dataset.render_dataset``, one object per frame) as the baseline of the same run.

    python benches/bench_scenes.py [--scenes 4] [--views 5] [--categories chair,table] [--no-noise]

Both run on procedural instances (no ``../shared`` needed). The rooms run twice into fresh
folders: the first pays the one-off costs (preparing the instances: skeleton template, origin;
their turn-symmetry search), the second is the steady state a long run settles into.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--categories", default="chair,table")
    ap.add_argument("--no-noise", action="store_true", help="rooms without the sensor noise")
    a = ap.parse_args()

    from isa.render.dataset import procedural_objects, render_dataset
    from isa.render.noise import KinectNoise
    from isa.scenes import make_scenes
    from isa.scenes.sources import procedural

    cats = tuple(a.categories.split(","))
    n = a.scenes * a.views
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        objs = procedural_objects(cats[0], 4, seed=1)
        s = render_dataset(f"{tmp}/single", objs, split="test", n_views=max(1, n // len(objs)), progress=False,
                           noise=None if a.no_noise else KinectNoise())
        rows.append(("render_dataset, one object per frame (baseline)", s.rendered, s.seconds))
        src = procedural(cats, seed=0)
        for label in ("rooms, first run (prepares instances)", "rooms, second run (steady state)"):
            t0 = time.perf_counter()
            s = make_scenes(f"{tmp}/{len(rows)}", "test", src, a.scenes, a.views, seed=0, noise=not a.no_noise,
                            progress=False)
            rows.append((label, s.rendered, time.perf_counter() - t0))
    base = rows[0][1] / rows[0][2]
    print(f"\nScene generation at 640x480, {'clean' if a.no_noise else 'with Kinect noise'}, categories {','.join(cats)}\n")
    print(f"| {'what':<48} | frames | seconds | frames/s | vs baseline |")
    print(f"|{'-' * 50}|-------:|--------:|---------:|------------:|")
    for label, frames, sec in rows:
        fps = frames / sec
        print(f"| {label:<48} | {frames:>6} | {sec:>7.1f} | {fps:>8.2f} | {fps / base:>10.2f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

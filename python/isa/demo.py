"""The demo: the whole ISA pipeline on procedural furniture that the project generates itself.

Generates beds, chairs, tables and toilets (isa.data.procedural), extracts and matches their skeletons,
finds each category's SSC, renders training and test depth images (BOP format), trains a Q1 and a
Q1+Q2+Q3 forest per category, predicts the 6D pose of unseen instances, runs the Linemod
baseline, and writes ``<out>/report.md`` with pictures and ``<out>/results.json``.

A small version of ``python -m isa experiment`` (same code), sized to run in minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from isa.categories import CATEGORIES
from isa.experiment import ExperimentConfig, run
from isa.forest.model import ForestParams

#: Real SUN RGB-D frames, when the developers' shared data sits beside the checkout: the demo then
#: adds the real-data section (it runs fully without them).
SHARED_SUNRGBD = Path(__file__).resolve().parents[3] / "shared" / "data" / "sunrgbd"


def demo_config(seed: int = 0, categories=CATEGORIES, real: str | None = None) -> ExperimentConfig:
    return ExperimentConfig(
        categories=tuple(categories), modelnet=None, train_instances=6, test_instances=3, views=30,
        test_images=24, qualities=("Q1", "Q1+Q2+Q3"), stride=6,
        forest=ForestParams(n_trees=4, max_depth=14, n_candidates=40, seed=seed),
        linemod=True, linemod_instances=2, ground_truth_skeletons=False, real=real, seed=seed, samples=8,
        scenes=3, scene_views=2)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m isa demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    p.add_argument("--real", default=str(SHARED_SUNRGBD) if SHARED_SUNRGBD.is_dir() else None,
                   help="SUN RGB-D folder for the real-data section (default: ../shared/data/sunrgbd if present)")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    path = run(demo_config(a.seed, a.categories, a.real), a.out, title="isa demo: category-level 6D pose on procedural furniture")
    print(f"demo finished in {(time.perf_counter() - t0) / 60:.1f} min; open {path}")


if __name__ == "__main__":
    main()

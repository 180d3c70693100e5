"""Models without any dataset: one deterministic procedural model per category, built once on a
fresh machine and cached (issue 19 item 2; ``python -m isa models``).

Each model is :func:`isa.forest.build.train_category` on :data:`SETTINGS` procedural instances
(:mod:`isa.data.procedural`, real size, z up), written as ``<dir>/<category>.isa`` with its shape
library ``<category>.shapes.isl`` beside it (the training meshes' surface samples, so that
:func:`isa.detection.detect` and ``isa detect`` verify and size what they find). The settings
and seed are fixed, so every machine builds the same bytes; docs/experiments.md has the commands
that measure them on ModelNet10's test instances against ModelNet-trained forests of the same size.

The folder is ``$ISA_MODELS`` if set, else ``~/.cache/isa/models``. A model already there is kept
(``force`` rebuilds); renders and skeletons are cached in ``<dir>/cache`` so an interrupted build
resumes.

>>> from isa.forest import procedural_models     # doctest: +SKIP
>>> path = procedural_models.get("chair")        # builds it the first time (minutes)
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Iterable

from isa.categories import CATEGORIES
from isa.exceptions import DataError

__all__ = ["SETTINGS", "model_dir", "model_path", "build", "get", "main"]

#: The training of every procedural model (keywords of :func:`isa.forest.build.train_category`).
SETTINGS: dict = {"procedural": 28, "views": 12, "stride": 8, "trees": 6, "quality": "Q1+Q2+Q3", "seed": 0}


def model_dir(root: str | os.PathLike | None = None) -> Path:
    """``root``, else ``$ISA_MODELS``, else ``~/.cache/isa/models``."""
    if root is not None:
        return Path(root)
    env = os.environ.get("ISA_MODELS")
    return Path(env) if env else Path.home() / ".cache" / "isa" / "models"


def model_path(category: str, root: str | os.PathLike | None = None) -> Path:
    return model_dir(root) / f"{category}.isa"


def _check(categories: Iterable[str]) -> list[str]:
    cats = list(categories)
    bad = [c for c in cats if c not in CATEGORIES]
    if bad or not cats:
        raise DataError(f"categories: procedural models exist for {', '.join(CATEGORIES)}; got {bad or cats}")
    return cats


def build(categories: Iterable[str] = CATEGORIES, root: str | os.PathLike | None = None, *, force: bool = False,
          progress: bool = True, settings: dict | None = None) -> dict[str, Path]:
    """Build the missing models of ``categories`` (all with ``force``); returns category -> path.
    ``settings`` overrides :data:`SETTINGS` (tests use tiny ones)."""
    from isa.detection.shapes import bop_shape_library
    from isa.forest.build import train_category

    cats = _check(categories)
    folder = model_dir(root)
    cfg = {**SETTINGS, **(settings or {})}
    out = {}
    for c in cats:
        path = model_path(c, folder)
        shapes = path.with_suffix(".shapes.isl")
        if force or not (path.is_file() and shapes.is_file()):
            cache = folder / "cache" / c
            train_category(None, c, path, cache=cache, progress=progress, **cfg)
            renders = sorted((cache / "renders").glob(f"{c}-*"))
            if len(renders) != 1:  # the cache is ours: one render set per category
                raise DataError(f"{cache / 'renders'}: expected one render set of {c}, found {len(renders)}")
            bop_shape_library(renders[0], c, "train").save(shapes)
        out[c] = path
    return out


def get(category: str, root: str | os.PathLike | None = None, *, progress: bool = True) -> Path:
    """The path of ``category``'s procedural model, built first if missing."""
    return build([category], root, progress=progress)[category]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m isa models", description=__doc__.split("\n\n")[0])
    p.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    p.add_argument("--dir", type=Path, help="model folder (default $ISA_MODELS or ~/.cache/isa/models)")
    p.add_argument("--force", action="store_true", help="rebuild models already there")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    a = p.parse_args(argv)
    for c, path in build(a.categories, a.dir, force=a.force, progress=not a.quiet).items():
        print(f"{c}\t{path}")


if __name__ == "__main__":
    main()

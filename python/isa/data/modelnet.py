"""ModelNet10 adapter: instances per category and split in the original layout, and the paper's protocol.

Layout: ``<root>/<category>/{train,test}/<category>_NNNN.off``. ``root`` may be the
``ModelNet10`` folder itself or a folder containing it (e.g. ``../shared/data/modelnet10``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from isa.categories import CATEGORIES, PAPER_INSTANCES, check_category
from isa.exceptions import DataError, DataNotFoundError

__all__ = ["SPLITS", "Instance", "find_root", "list_instances", "paper_instances", "VALIDATION_INSTANCES", "validation_instances"]

SPLITS: tuple[str, ...] = ("train", "test")


@dataclass(frozen=True)
class Instance:
    """One ModelNet10 model: its category, split, name (file stem, e.g. ``chair_0001``) and path."""

    category: str
    split: str
    name: str
    path: Path


def find_root(root: str | Path) -> Path:
    """The ModelNet10 folder at or directly under ``root``; ``DataError`` naming ``root`` if neither."""
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(f"ModelNet10 root not found: {root}")
    for cand in (root, root / "ModelNet10"):
        if any((cand / c).is_dir() for c in CATEGORIES):
            return cand
    raise DataError(f"{root} is not a ModelNet10 root: no {'/'.join(CATEGORIES)} folder in it or in {root / 'ModelNet10'}")


def list_instances(root: str | Path, category: str, split: str = "train") -> list[Instance]:
    """All instances of ``category`` in ``split``, sorted by name.

    Raises ``DataError`` for an unknown category or split, a missing root, or a missing
    ``<category>/<split>`` folder.
    """
    check_category(category)
    if split not in SPLITS:
        raise DataError(f"unknown ModelNet10 split {split!r}; expected one of {', '.join(SPLITS)}")
    base = find_root(root)
    folder = base / category / split
    if not folder.is_dir():
        raise DataNotFoundError(f"ModelNet10 folder not found: {folder}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".off" and p.is_file())
    return [Instance(category, split, p.stem, p) for p in files]


def paper_instances(root: str | Path, category: str, n: int | None = None) -> list[Instance]:
    """The paper's training protocol: the first ``n`` train instances in name order (Table 1:
    2 bed, 28 chair, 8 table, 7 toilet when ``n`` is None). ``DataError`` if fewer exist."""
    n = PAPER_INSTANCES[check_category(category)] if n is None else int(n)
    inst = list_instances(root, category, "train")
    if len(inst) < n:
        raise DataError(f"ModelNet10 {category}/train under {root} has {len(inst)} instances, the protocol needs {n}")
    return inst[:n]


#: Held-out instances for tuning: the LAST ones of the train split (never the paper's training
#: instances, which are the first ones, and never the test split).
VALIDATION_INSTANCES = 12


def validation_instances(root: str | Path, category: str, n: int | None = None, n_train: int = 0,
                         skip: int = 0) -> list[Instance]:
    """The last ``n`` (default :data:`VALIDATION_INSTANCES`) train-split instances: what
    hyper-parameters are tuned on, so test instances stay unseen. ``skip`` > 0 takes the ``n``
    before the last ``skip`` instead (held out from validation rooms made with ``n <= skip``:
    rankers fitted on them are scored on shapes they never saw). ``DataError`` if they would
    overlap the first ``n_train`` (the training instances)."""
    n = VALIDATION_INSTANCES if n is None else int(n)
    skip = int(skip)
    inst = list_instances(root, category, "train")
    if n <= 0 or skip < 0 or n_train + n + skip > len(inst):
        raise DataError(f"ModelNet10 {category}/train under {root}: {len(inst)} instances cannot hold "
                        f"{n_train} training + {n} validation instances" + (f" + {skip} skipped" if skip else ""))
    return inst[len(inst) - skip - n:len(inst) - skip]

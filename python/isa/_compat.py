"""Old flat module paths (``isa.bop``, ``isa.dataset``, ...) kept for one release.

Before the package was split into subpackages every module sat directly under ``isa``. A finder on
``sys.meta_path`` answers an import of an old path with the module at its new path (the same module
object, so state and ``isinstance`` checks are shared) and a ``DeprecationWarning`` naming the new
path. ``python -m isa.dataset`` keeps working through it too.
Names that are now subpackages (``isa.forest``, ``isa.render``, ``isa.report``, ``isa.detection``)
need no alias: the subpackage re-exports what the old module held.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: Old flat module under ``isa`` -> its new module (submodules of an old package follow it).
MOVED = {
    "annotate": "isa.privileged.annotate",
    "bop": "isa.data.bop",
    "boxes3d": "isa.evaluation.boxes3d",
    "dataset": "isa.render.dataset",
    "figures": "isa.report.figures",
    "linemod": "isa.evaluation.linemod",
    "matching": "isa.privileged.matching",
    "meshes": "isa.data.meshes",
    "mirror": "isa.privileged.mirror",
    "modelnet": "isa.data.modelnet",
    "noise": "isa.render.noise",
    "pose_metrics": "isa.evaluation.pose_metrics",
    "procedural": "isa.data.procedural",
    "published": "isa.evaluation.published",
    "skeleton": "isa.privileged.skeleton",
    "ssc": "isa.privileged.ssc",
    "sunrgbd": "isa.data.sunrgbd",
    "symmetry": "isa.privileged.symmetry",
    "views": "isa.render.views",
}


def new_name(fullname: str) -> str | None:
    """The new path of an old module path (``isa.figures.poses`` -> ``isa.report.figures.poses``),
    or None when ``fullname`` did not move."""
    parts = fullname.split(".")
    if len(parts) < 2 or parts[0] != "isa" or parts[1] not in MOVED:
        return None
    return ".".join([MOVED[parts[1]], *parts[2:]])


def _warn(old: str, new: str) -> None:
    # stacklevel 3: past this helper and the loader method; the import machinery's own frames are
    # skipped by the warnings module, so the warning points at the caller's import statement.
    warnings.warn(f"{old} moved to {new}; the old path will be removed in the next release",
                  DeprecationWarning, stacklevel=3)


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        return None  # a throw-away module; exec_module replaces it in sys.modules

    def exec_module(self, module) -> None:
        _warn(module.__name__, self.new)
        # The import system returns whatever sys.modules holds for the name after exec_module.
        sys.modules[module.__name__] = importlib.import_module(self.new)

    def get_code(self, fullname: str):
        """For ``python -m isa.<old>``: the new module's code, run as ``__main__``."""
        _warn(fullname, self.new)
        spec = importlib.util.find_spec(self.new)
        return spec.loader.get_code(self.new)


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Resolves old flat module paths to their new modules (see :data:`MOVED`)."""

    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(new))


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once): before the path finder, which would
    otherwise load a second copy of a moved package's submodules under the old name."""
    if not any(isinstance(f, MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedModuleFinder())

"""Lazy re-exports for the subpackages' ``__init__`` (polars-style flat names, loaded on first use).

A subpackage lists its modules; each module's ``__all__`` is the one list of its public names.
They are read from the modules' source (``ast``, no import), so importing a subpackage imports
none of its modules."""

from __future__ import annotations

import ast
from pathlib import Path

import lazy_loader

from isa.exceptions import DataError


def _module_all(path: Path) -> list[str]:
    # The literal `__all__ = [...]` of a module's top level (every re-exported module has one).
    for node in ast.parse(path.read_text(encoding="utf-8"), str(path)).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise DataError(f"{path}: no literal __all__ to re-export")


def lazy_reexport(package: str, modules: list[str], submodules: tuple[str, ...] = ()):
    """``(__getattr__, __dir__, __all__)`` for ``package``: every name of each module's ``__all__``
    is ``package.module.name``, imported when first used, as are the modules themselves (``modules``
    and ``submodules``). Two modules exporting one name is a ``DataError`` (the package's layout), not a silent choice."""
    import importlib.util

    root = Path(importlib.util.find_spec(package).origin).parent  # type: ignore[union-attr, arg-type]
    names: dict[str, list[str]] = {}
    owner: dict[str, str] = {}
    for mod in modules:
        path = root / f"{mod}.py"
        names[mod] = _module_all(path if path.is_file() else root / mod / "__init__.py")
        for name in names[mod]:
            if name in owner:
                raise DataError(f"{package}: {name!r} is exported by both {owner[name]} and {mod}")
            owner[name] = mod
    return lazy_loader.attach(package, submodules=[*modules, *submodules], submod_attrs=names)

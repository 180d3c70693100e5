"""Lazy re-exports for the subpackages' ``__init__`` (polars-style flat names, loaded on first use)."""

from __future__ import annotations

import lazy_loader


def lazy_reexport(package: str, names: dict[str, list[str]], submodules: tuple[str, ...] = ()):
    """``(__getattr__, __dir__, __all__)`` for ``package``: every name of ``names[module]`` is
    ``package.module.name``, imported when first used, as are the modules themselves (the keys of
    ``names`` and ``submodules``), so importing the package imports none of them."""
    return lazy_loader.attach(package, submodules=[*names, *submodules], submod_attrs=names)

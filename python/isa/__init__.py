"""isa: category-level 6D object pose in depth images (Intrinsic Structure Adaptor).

The numeric core (parts, forest training, voting) is Rust, in ``isa._core``; this package adds
the data pipeline (meshes, rendering, BOP I/O), skeletons and SSCs, datasets and evaluation.
"""

from isa._core import __version__

__all__ = ["__version__"]

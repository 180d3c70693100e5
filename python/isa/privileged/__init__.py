"""Privileged data (training only): skeletons, their matching to a category template, the SSC,
part annotation, and the symmetries (mirror, turn) of instances."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["skeleton", "matching", "ssc", "annotate", "symmetry", "mirror"])

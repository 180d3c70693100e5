"""Reports: the Markdown + PNG report (``report``) and its figures (``figures``)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["report"], submodules=("figures",))

"""The ISA forest: the Rust forest's Python face (``model``) and its training from rendered views
(``training``)."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["model", "training"])

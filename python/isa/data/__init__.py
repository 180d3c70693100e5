"""Data in: meshes, ModelNet10, procedural instances, SUN RGB-D frames, other sensors' depth
formats (TUM, NYU) and the BOP format."""

from isa._reexport import lazy_reexport

__getattr__, __dir__, __all__ = lazy_reexport(__name__, ["meshes", "modelnet", "procedural", "sunrgbd", "sensors", "bop"])

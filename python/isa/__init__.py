"""isa: category-level 6D object pose in depth images (Intrinsic Structure Adaptor).

The numeric core (parts, forest training, voting) is Rust, in ``isa._core``; this package adds,
one subpackage per step of the data flow: ``data`` (meshes, ModelNet10, procedural instances,
SUN RGB-D, the BOP format), ``render`` (depth renders and rendered datasets), ``privileged``
(skeletons, matching, SSC, annotation, symmetries), ``forest`` (the forest and its training),
``detection`` (3D detection in real scenes), ``evaluation`` (metrics, AP, the Linemod baseline,
the experiment) and ``report`` (reports and figures); ``pipeline`` runs one category end to end.
Importing ``isa`` loads none of them.
"""

from isa import _compat
from isa._core import __version__
from isa.exceptions import (
    DataError,
    DataNotFoundError,
    InvalidInputError,
    InvalidParameterError,
    InvalidTypeError,
    InvalidValueError,
    IsaError,
    IsaIOError,
    MissingDependencyError,
    ModelFormatError,
    UsageError,
)

_compat.install()

__all__ = [
    "DataError",
    "DataNotFoundError",
    "InvalidInputError",
    "InvalidParameterError",
    "InvalidTypeError",
    "InvalidValueError",
    "IsaError",
    "IsaIOError",
    "MissingDependencyError",
    "ModelFormatError",
    "UsageError",
    "__version__",
]

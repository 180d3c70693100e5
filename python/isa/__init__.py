"""isa: category-level 6D object pose in depth images (Intrinsic Structure Adaptor).

The numeric core (parts, forest training, voting) is Rust, in ``isa._core``; this package adds,
one subpackage per step of the data flow: ``data`` (meshes, ModelNet10, procedural instances,
SUN RGB-D, the BOP format), ``render`` (depth renders and rendered datasets), ``privileged``
(skeletons, matching, SSC, annotation, symmetries), ``forest`` (the forest and its training),
``detection`` (3D detection in real scenes), ``evaluation`` (metrics, AP, the Linemod baseline)
and ``report`` (reports and figures); ``pipeline`` runs one category end to end, ``experiment``
the paper's experiment and ``demo`` a small one (``python -m isa COMMAND``).
Importing ``isa`` loads none of them, and each re-exports its modules' public names lazily
(``from isa.data import FrameSequence``), importing a module when one of its names is first used.
"""

from isa import _compat, exceptions
from isa._core import __version__
from isa.exceptions import *  # noqa: F403  (every error class, listed in exceptions.__all__)

_compat.install()

__all__ = ["__version__", *exceptions.__all__]

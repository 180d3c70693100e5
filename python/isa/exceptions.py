"""Errors raised by isa.

``IsaError`` is the base class of every isa error. It is defined in the Rust extension
(``isa._core.IsaError``) so that the core's errors and the Python-side ones share it:

* ``InvalidInputError`` — an argument has the wrong dtype, shape, layout or value;
* ``InvalidParameterError`` — a hyper-parameter failed validation;
* ``ModelFormatError`` — a model file is truncated, corrupted, foreign or newer;
* ``IsaIOError`` — an operating-system I/O failure on a named file;
* ``DataError`` (Python side) — a data file or folder is missing, empty, corrupt or in the
  wrong layout.
"""

from __future__ import annotations

from isa._core import (
    InvalidInputError,
    InvalidParameterError,
    IsaError,
    IsaIOError,
    ModelFormatError,
)


class DataError(IsaError, ValueError):
    """A data file or folder is missing, empty, corrupt or in the wrong layout (names it)."""


__all__ = [
    "DataError",
    "InvalidInputError",
    "InvalidParameterError",
    "IsaError",
    "IsaIOError",
    "ModelFormatError",
]

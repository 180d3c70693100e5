"""Errors raised by isa.

``IsaError`` is the base class of every isa error. It is defined in the Rust extension
(``isa._core.IsaError``) so that the core's errors and the Python-side ones share it. Each
class is also the matching builtin, so ``except ValueError`` / ``except OSError`` catch them:

* ``InvalidInputError`` (``ValueError``) — an argument has the wrong dtype, shape, layout or value;
* ``InvalidParameterError`` (``ValueError``) — a hyper-parameter failed validation;
* ``ModelFormatError`` (``ValueError``) — a model file is truncated, corrupted, foreign or newer;
* ``IsaIOError`` (``OSError``) — an operating-system I/O failure on a named file (``filename``,
  ``errno``), raised as ``IsaFileNotFoundError`` (``FileNotFoundError``), ``IsaPermissionError``
  (``PermissionError``) or ``IsaIsADirectoryError`` (``IsADirectoryError``) when it is one;
* ``DataError`` (``ValueError``, Python side) — a data file or folder is missing, empty, corrupt
  or in the wrong layout.
"""

from __future__ import annotations

from isa._core import (
    InvalidInputError,
    InvalidParameterError,
    IsaError,
    IsaFileNotFoundError,
    IsaIOError,
    IsaIsADirectoryError,
    IsaPermissionError,
    ModelFormatError,
)


class DataError(IsaError, ValueError):
    """A data file or folder is missing, empty, corrupt or in the wrong layout (names it)."""


__all__ = [
    "DataError",
    "InvalidInputError",
    "InvalidParameterError",
    "IsaError",
    "IsaFileNotFoundError",
    "IsaIOError",
    "IsaIsADirectoryError",
    "IsaPermissionError",
    "ModelFormatError",
]

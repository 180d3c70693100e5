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
* ``DataNotFoundError`` (also ``FileNotFoundError``, Python side) — a data file or folder is missing.

``InputWarning`` (``UserWarning``) flags an input that is accepted but probably wrong: a depth
range implausible for a depth sensor in metres (a wrong ``depth_scale``), an image that looks
transposed against its intrinsics.

Argument checks raise ``InvalidValueError`` / ``InvalidTypeError`` (``InvalidInputError`` that
is also ``ValueError`` / ``TypeError``; ``InvalidTypeError`` is defined in ``isa._core``, which
raises it for an argument of the wrong type), ``MissingDependencyError``
(also ``ImportError``) for an optional dependency that is not installed, and ``UsageError`` (also
``RuntimeError``) for an object used in a state that forbids it.
"""

from __future__ import annotations

from isa._core import (
    InputWarning,
    InvalidInputError,
    InvalidParameterError,
    InvalidTypeError,
    IsaError,
    IsaFileNotFoundError,
    IsaIOError,
    IsaIsADirectoryError,
    IsaPermissionError,
    ModelFormatError,
)


class DataError(IsaError, ValueError):
    """A data file or folder is missing, empty, corrupt or in the wrong layout (names it)."""


class DataNotFoundError(DataError, FileNotFoundError):
    """A data file or folder does not exist (names it)."""


class InvalidValueError(InvalidInputError, ValueError):
    """An argument checked on the Python side has the wrong value or shape (names the argument)."""


class MissingDependencyError(IsaError, ImportError):
    """An optional dependency is not installed (names the package to install)."""


class UsageError(IsaError, RuntimeError):
    """An object is used in a state that forbids it (a renderer after ``close()``)."""


__all__ = [
    "DataError",
    "DataNotFoundError",
    "InputWarning",
    "InvalidInputError",
    "InvalidParameterError",
    "InvalidTypeError",
    "InvalidValueError",
    "IsaError",
    "IsaFileNotFoundError",
    "IsaIOError",
    "IsaIsADirectoryError",
    "IsaPermissionError",
    "MissingDependencyError",
    "ModelFormatError",
    "UsageError",
]

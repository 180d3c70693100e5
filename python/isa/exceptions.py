"""Python-side errors. The Rust core's errors arrive as subclasses of ``IsaError`` too."""

from __future__ import annotations


class IsaError(Exception):
    """Base class of every error raised by isa."""


class DataError(IsaError, ValueError):
    """A data file or folder is missing, empty, corrupt or in the wrong layout (names it)."""

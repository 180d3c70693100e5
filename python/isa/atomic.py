"""Atomic file writes for every Python writer (renders, reports, scenes, shape libraries, caches).

The same scheme as the Rust core's ``atomic`` module (``crates/isa-core/src/atomic.rs``), so the
two clean up each other's leftovers: a file is written to a unique temporary name in the target's
folder, ``.{name}.isa-tmp-{random}{extension}`` (the extension kept, so writers that pick a
format from it still work), held under an exclusive ``flock`` while it is written, synced, and
renamed onto the target; a reader sees the old file or the new one, whole. Of concurrent writers
of one path the last rename wins. A temporary file that nobody holds locked is the leftover of
a killed writer: :func:`clean_stale` / :func:`clean_stale_in` remove those (a live writer's, in
any thread or process, is left alone); :func:`write_with` runs :func:`clean_stale` on its target
unless told not to (writers of many files clean their folder once instead).

OS failures raise :class:`isa.exceptions.IsaIOError` (also ``OSError``; the ``FileNotFoundError``
/ ``PermissionError`` / ``IsADirectoryError`` subclasses when it is one) naming the target.
"""

from __future__ import annotations

import contextlib
import errno as _errno
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from isa.exceptions import IsaFileNotFoundError, IsaIOError, IsaIsADirectoryError, IsaPermissionError

try:  # POSIX; elsewhere temporary files are never judged stale (nothing is removed)
    import fcntl
except ImportError:  # pragma: no cover - not on Linux/macOS
    fcntl = None  # type: ignore[assignment]

#: What every temporary name holds after the target's name (the Rust core's ``TEMP_MARK``).
TEMP_MARK = ".isa-tmp-"

# Read once: os.umask can only be read by setting it, which would race other threads' file creation.
_UMASK = os.umask(0o022)
os.umask(_UMASK)

_BY_ERRNO = {_errno.ENOENT: IsaFileNotFoundError, _errno.EACCES: IsaPermissionError,
             _errno.EPERM: IsaPermissionError, _errno.EISDIR: IsaIsADirectoryError}


def _io_error(exc: OSError, path: Path) -> IsaIOError:
    cls = _BY_ERRNO.get(exc.errno or 0, IsaIOError)
    return cls(exc.errno, exc.strerror or str(exc), os.fspath(path))


def _prefix(path: Path) -> str:
    return f".{path.name}{TEMP_MARK}"


def _same_file(path: str | Path, fd: int) -> bool:
    try:
        a, b = os.stat(path), os.fstat(fd)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _locked_temp(path: Path) -> tuple[int, str]:
    """A new temporary file for ``path`` in its folder, locked by this writer: (fd, name)."""
    while True:
        fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=path.suffix, dir=path.parent)
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        if _same_file(tmp, fd):
            # As open() would create it (the umask applies), not mkstemp's private 0600.
            os.fchmod(fd, 0o666 & ~_UMASK)
            return fd, tmp
        os.close(fd)  # removed by a cleaner in the instant before the lock: take another name


def write_with(path: str | os.PathLike, write: Callable[[Path], Any], *, parents: bool = False,
               clean: bool = True) -> Path:
    """Write ``path`` whole or not at all: ``write(tmp)`` fills the temporary file ``tmp`` (same
    folder and extension), which is then synced and renamed onto ``path``. ``parents``: create
    missing folders; ``clean``: first remove stale temporary files of ``path``. On any error
    (``write``'s included, which propagates) the temporary file is removed and ``path`` is
    untouched. Returns ``path``."""
    path = Path(path)
    try:
        if parents:
            path.parent.mkdir(parents=True, exist_ok=True)
        if clean:
            clean_stale(path)
        fd, tmp = _locked_temp(path)
    except OSError as exc:
        raise _io_error(exc, path) from exc
    try:
        write(Path(tmp))
        # ``write`` may have replaced the file at ``tmp`` (some libraries write a new file):
        # sync what is there now.
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _sync_dir(path.parent)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, IsaIOError):
            raise _io_error(exc, path) from exc
        raise
    finally:
        os.close(fd)  # releases the lock, after the rename
    return path


def write_bytes(path: str | os.PathLike, data: bytes, **kw: Any) -> Path:
    """:func:`write_with` of a byte string."""
    return write_with(path, lambda tmp: tmp.write_bytes(data), **kw)


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8", **kw: Any) -> Path:
    """:func:`write_with` of a text."""
    return write_with(path, lambda tmp: tmp.write_text(text, encoding=encoding), **kw)


def _sync_dir(directory: Path) -> None:
    """Make a rename durable (best effort: not every platform can open a folder)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _clean(directory: Path, ours: Callable[[str], bool]) -> int:
    if fcntl is None:
        return 0
    removed = 0
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return 0
    for e in entries:
        if not ours(e.name):
            continue
        try:
            fd = os.open(e.path, os.O_RDONLY)
        except OSError:
            continue
        try:
            # Held: a live writer's. Free: its writer is gone (a rename would have taken the name).
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if _same_file(e.path, fd):
                os.remove(e.path)
                removed += 1
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


def clean_stale(path: str | os.PathLike) -> int:
    """Remove the stale temporary files of ``path`` (left by a killed writer); returns how many.
    Never raises."""
    path = Path(path)
    prefix = _prefix(path)
    return _clean(path.parent, lambda n: n.startswith(prefix))


def clean_stale_in(directory: str | os.PathLike) -> int:
    """Remove every stale isa temporary file in ``directory``; returns how many. Never raises."""
    return _clean(Path(directory), lambda n: n.startswith(".") and TEMP_MARK in n)


__all__ = ["TEMP_MARK", "clean_stale", "clean_stale_in", "write_bytes", "write_text", "write_with"]

"""The ``isa`` command installed by pip: the Rust command line (``isa train``, ``predict``,
``detect``, ``inspect``; ``isa --help``) compiled into the extension, the same program as the
``isa`` binary that ``cargo build -p isa-cli`` makes. ``python -m isa`` stays the Python
pipeline's commands (``demo``, ``experiment``, ``train`` from meshes, ...)."""

from __future__ import annotations

import signal
import sys


def main(argv: list[str] | None = None) -> int:
    """Runs ``isa`` with ``argv`` (default: the process's arguments); returns the exit code."""
    from isa import _core

    # Ctrl-C ends the process as it ends the binary (outputs are written atomically), instead of
    # waiting for the Rust code to return to Python's handler.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    return _core._cli_main(["isa", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

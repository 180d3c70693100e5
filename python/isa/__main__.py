"""``python -m isa <command> [options]``: the package's commands (``python -m isa <command> --help``
for each one's options).

Each command is a module with ``main(argv)``; adding one is one line in :data:`COMMANDS`. Only the
chosen command's module is imported.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: command -> (module with ``main(argv)``, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("isa.forest.build", "train a category model from a folder of meshes (or ModelNet10, or procedural)"),
    "models": ("isa.forest.procedural_models", "build (once) the procedural model of each category: isa without any dataset"),
    "demo": ("isa.demo", "the whole pipeline on procedural furniture, in minutes (report + results.json)"),
    "experiment": ("isa.experiment", "the paper's synthetic experiment (Table 2, left)"),
    "detect-real": ("isa.detection.cli", "3D detection on real SUN RGB-D depth frames (Table 2, right)"),
    "scenes": ("isa.scenes.__main__", "the scene benchmark: make rooms, run category models on them, score, report"),
    "dataset": ("isa.render.dataset", "render a BOP training or test set of ModelNet10 or procedural objects"),
}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m isa", description="isa's commands; python -m isa COMMAND --help gives a command's options.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_, help_) in COMMANDS.items():
        sub.add_parser(name, help=help_, add_help=False)
    return p


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in COMMANDS:
        module, _ = COMMANDS[argv[0]]
        # The command parses its own options (and --help), under prog "python -m isa <command>".
        importlib.import_module(module).main(argv[1:])
        return
    parser().parse_args(argv)  # no or unknown command: argparse prints the usage and exits 2


if __name__ == "__main__":
    main()

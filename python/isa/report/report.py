"""A small Markdown report builder: headings, text, tables and pictures, plus the JSON results.

Reports are written atomically (:mod:`isa.atomic`) so a crashed run never leaves a
half-written report behind.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Sequence

from isa import atomic

__all__ = ["Report"]

#: Version of the ``results.json`` layout (docs/results.md); bumped when its schema changes.
RESULTS_SCHEMA = "isa-results/2"


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.1f}"
    return "" if x is None else str(x)


class Report:
    """Collects Markdown blocks; ``figure_path(name)`` gives where to save a picture."""

    def __init__(self, out_dir: str | os.PathLike, title: str) -> None:
        self.out_dir = Path(out_dir)
        self.fig_dir = self.out_dir / "figures"
        self.fig_dir.mkdir(parents=True, exist_ok=True)
        self.blocks: list[str] = [f"# {title}\n"]
        self.results: dict[str, Any] = {}

    def heading(self, text: str, level: int = 2) -> None:
        self.blocks.append(f"{'#' * level} {text}\n")

    def text(self, text: str) -> None:
        self.blocks.append(text.strip() + "\n")

    def code(self, text: str, lang: str = "") -> None:
        self.blocks.append(f"```{lang}\n{text.rstrip()}\n```\n")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(_fmt(c) for c in row) + " |" for row in rows]
        self.blocks.append("\n".join(lines) + "\n")

    def figure_path(self, name: str) -> Path:
        return self.fig_dir / name

    def image(self, path: str | os.PathLike, caption: str) -> None:
        rel = os.path.relpath(path, self.out_dir)
        self.blocks.append(f"![{caption}]({rel})\n\n*{caption}*\n")

    def write(self, name: str = "report.md", results_name: str = "results.json") -> Path:
        path = self.out_dir / name
        atomic.write_text(path, "\n".join(self.blocks))
        if self.results:
            atomic.write_text(self.out_dir / results_name, json.dumps(self.results, indent=2, sort_keys=True))
        return path

"""Shared by the benchmark scripts: replace one marked section of docs/benchmarks.md."""

from __future__ import annotations

from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def write_section(name: str, body: str, script: str) -> None:
    """Replace (or append) the section ``name``, keeping every other section as it is."""
    begin, end = f"<!-- {name}:begin", f"<!-- {name}:end -->"
    section = f"{begin} (written by benchmarks/{script}) -->\n{body}{end}\n"
    text = DOC.read_text() if DOC.exists() else "# Benchmarks\n\n"
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + section + rest.split(end, 1)[1].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + section
    DOC.write_text(text)

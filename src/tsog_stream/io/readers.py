"""Input detection and loading: any supported file becomes a :class:`~tsog_stream.model.Scene`.

Formats are recognised by content (magic bytes, PLY header, zip with meta.json), not only by
extension; ``format=`` overrides detection.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from ..codec.bundle import is_zip
from ..errors import InputError, UnsupportedError
from ..model import Scene
from .chunks import is_unbundled, read_chunk
from .compressed_ply import is_compressed_ply
from .files import read_bytes
from .ply import parse_ply, sniff_ply
from .ply_header import parse_header

FORMATS = ("ply", "compressed-ply", "sog")
"""Input formats this version reads (``--format`` values)."""


@dataclass(frozen=True)
class LoadedScene:
    """A scene with the format it was read as and any warnings the reader had."""

    scene: Scene
    format: str
    notes: list[str] = field(default_factory=list)


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format name of the file or folder at ``path``, from its content."""
    p = Path(path)
    if is_unbundled(p):
        return "sog"
    if p.is_dir():
        raise UnsupportedError("a folder without meta.json is not a known input", where=str(p))
    with open(p, "rb") as f:
        head = f.read(64 * 1024)
    if is_zip(head):
        return "sog"
    if sniff_ply(head):
        return "compressed-ply" if is_compressed_ply(parse_header(head, name=str(p))) else "ply"
    raise UnsupportedError("not a PLY, SOG or TSOG file (unknown magic bytes)", where=str(p))


def load_scene(path: str | os.PathLike[str], *, format: str | None = None) -> LoadedScene:
    """Read any supported input as a Scene (static inputs have no timeline)."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", where=str(p))
    kind = format or detect_format(p)
    if kind == "sog":
        return LoadedScene(read_chunk(p), kind)
    if kind not in FORMATS:
        raise InputError(f"unknown format {kind!r}; known: {', '.join(FORMATS)}", where="--format")
    contents = parse_ply(read_bytes(p), name=str(p))  # plain or compressed, told by its header
    return LoadedScene(Scene(contents.gaussians), kind, list(contents.notes))

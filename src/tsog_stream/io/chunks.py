"""SOG/TSOG chunks on disk: bundled ``.sog`` zips and unbundled folders with meta.json."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from ..codec.bundle import bundle_bytes, read_bundle
from ..codec.chunk import decode_chunk, read_meta
from ..constants import META_JSON
from ..errors import SourceError
from ..model import Scene
from ..schemas import listed_files
from .files import atomic_write_bytes, atomic_write_folder, read_bytes, refuse_existing
from .objects import Location, ObjectPath, as_location


def is_unbundled(path: Location) -> bool:
    """True for a folder holding meta.json, or a path to such a meta.json."""
    return (path.is_dir() and (path / META_JSON).is_file()) or (
        path.name == META_JSON and path.is_file()
    )


def read_folder(path: Location) -> dict[str, bytes]:
    """meta.json and every image it lists from an unbundled chunk folder."""
    folder = path if path.is_dir() else path.parent
    where = str(folder)
    files = {META_JSON: read_bytes(folder / META_JSON)}
    meta = read_meta(files, where=where)
    for field, name in listed_files(meta):
        file = folder / name
        if not file.is_file():
            raise SourceError(f"file {name!r} listed in {field} is missing", where=where)
        files[name] = read_bytes(file)
    return files


def read_chunk_files(path: str | os.PathLike[str] | ObjectPath) -> dict[str, bytes]:
    """The files of a chunk stored as a .sog zip or an unbundled folder."""
    p = as_location(path)
    if is_unbundled(p):
        return read_folder(p)
    if p.is_dir():
        raise SourceError("folder has no meta.json", where=str(p))
    return read_bundle(read_bytes(p), where=str(p))


def read_chunk(path: str | os.PathLike[str] | ObjectPath) -> Scene:
    """Decode the chunk at ``path`` (bundled or unbundled)."""
    return decode_chunk(read_chunk_files(path), where=str(path))


def write_chunk_files(
    path: str | os.PathLike[str], files: Mapping[str, bytes], *, overwrite: bool = True
) -> int:
    """Publish a chunk atomically: ``*.sog`` as a zip, else a folder; returns the bytes written."""
    p = Path(path)
    if p.suffix.lower() == ".sog":
        refuse_existing(p, overwrite=overwrite)
        data = bundle_bytes(files)
        atomic_write_bytes(p, data)
        return len(data)
    if p.name == META_JSON:
        p = p.parent
    atomic_write_folder(p, files, overwrite=overwrite)
    return sum(len(b) for b in files.values())

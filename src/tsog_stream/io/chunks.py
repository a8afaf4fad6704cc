"""SOG/TSOG chunks on disk: bundled ``.sog`` zips and unbundled folders with meta.json."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from ..codec.bundle import MAX_META_JSON_BYTES, bundle_bytes, member_budgets, read_bundle
from ..codec.chunk import decode_chunk, read_meta
from ..constants import META_JSON
from ..errors import SogError, SourceError
from ..model import Scene
from ..schemas import listed_files
from .files import atomic_write_bytes, atomic_write_folder, check_output, read_bytes, read_head
from .objects import Location, ObjectPath, as_location, size_of


def is_unbundled(path: Location) -> bool:
    """True for a folder holding meta.json, or a path to such a meta.json."""
    return (path.is_dir() and (path / META_JSON).is_file()) or (
        path.name == META_JSON and path.is_file()
    )


def read_folder(path: Location) -> dict[str, bytes]:
    """meta.json and every image it lists from an unbundled chunk folder, each refused
    unread when larger than a bundle's reader would inflate it (codec.bundle)."""
    folder = path if path.is_dir() else path.parent
    where = str(folder)
    meta_cap = MAX_META_JSON_BYTES
    files = {META_JSON: _read_capped(folder / META_JSON, meta_cap, "a meta.json may hold")}
    meta = read_meta(files, where=where)
    budgets = member_budgets(meta)
    for field, name in listed_files(meta):
        file = folder / name
        if not file.is_file():
            raise SourceError(f"file {name!r} listed in {field} is missing", where=where)
        what = "a WebP of the image size meta.json implies may hold"
        files[name] = _read_capped(file, budgets[name], what)
    return files


def _read_capped(file: Location, cap: int, what: str) -> bytes:
    """The bytes of ``file``, refused (a SogError) when over ``cap`` bytes: by its size before
    reading, and by reading at most ``cap + 1`` bytes (it may grow meanwhile)."""
    try:
        size = size_of(file)
    except OSError as exc:
        raise SourceError(f"cannot read: {exc.strerror}", where=str(file)) from exc
    data = b"" if size > cap else read_head(file, size + 1)  # one byte more: did it grow?
    if size > cap or len(data) > cap:
        found = f"{size} bytes" if size > cap else "grew while read"
        raise SogError(f"{found}, more than the {cap} {what}", where=str(file))
    return data


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


def chunk_folder(path: str | os.PathLike[str]) -> bool:
    """Whether :func:`write_chunk_files` writes a chunk at ``path`` as a folder (any name but
    ``*.sog``)."""
    return Path(path).suffix.lower() != ".sog"


def write_chunk_files(
    path: str | os.PathLike[str], files: Mapping[str, bytes], *, overwrite: bool = True
) -> int:
    """Publish a chunk atomically: ``*.sog`` as a zip, else a folder (:func:`chunk_folder`);
    returns the bytes written."""
    p = Path(path)
    if not chunk_folder(p):
        check_output(p, overwrite=overwrite)
        data = bundle_bytes(files)
        atomic_write_bytes(p, data)
        return len(data)
    if p.name == META_JSON:
        p = p.parent
    atomic_write_folder(p, files, overwrite=overwrite)
    return sum(len(b) for b in files.values())

"""Bundled chunks: a ``.sog`` zip of stored entries, written deterministically.

Entries are stored (WebP is already compressed), with a fixed timestamp so the same files
give byte-identical archives, no extra fields and no archive comment. ``meta.json`` goes last,
as splat-transform writes it.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from collections.abc import Mapping

from ..constants import META_JSON
from ..errors import SogError
from ..schemas import listed_files, parse_any_meta

FIXED_DATE = (1980, 1, 1, 0, 0, 0)
MAX_ENTRIES = 4096
ZIP_MAGIC = b"PK\x03\x04"
MAX_DEFLATE_RATIO = 1032
"""Deflate cannot expand data more than about 1032:1; a larger claim is a lie or a bomb."""
ZIP_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    struct.error,
    OSError,
    ValueError,
    EOFError,
    RuntimeError,
    NotImplementedError,
)
"""What :mod:`zipfile` raises on damaged archives (zlib.error from corrupt deflate streams)."""


def is_zip(data: bytes) -> bool:
    """True when ``data`` starts like a zip archive (a bundled .sog)."""
    return data[:4] == ZIP_MAGIC


def bundle_bytes(files: Mapping[str, bytes]) -> bytes:
    """A .sog archive of ``files`` (name -> bytes), meta.json last, byte-for-byte reproducible.

    WebP images are stored (already compressed); ``meta.json`` is deflated, which the engine
    and splat-transform read too: its codebooks are most of a small chunk's fixed cost.
    """
    names = [n for n in files if n != META_JSON] + ([META_JSON] if META_JSON in files else [])
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED, allowZip64=False) as archive:
        for name in names:
            info = zipfile.ZipInfo(name, date_time=FIXED_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED if name == META_JSON else zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            archive.writestr(info, files[name])
    return out.getvalue()


def read_bundle(data: bytes, *, where: str = "<bundle>") -> dict[str, bytes]:
    """``meta.json`` and the entries it names, of a .sog archive (stored or deflated).

    Only those are inflated: an entry ``meta.json`` never names is not read at all, and every
    entry read is checked against the central directory first (see :func:`_read_entry`), so a
    small archive cannot make a reader inflate gigabytes. Any damage raises SogError.
    """
    return _scan(data, where, read_named=True)[0]


def unnamed_entries(data: bytes, *, where: str = "<bundle>") -> list[str]:
    """Entries of a .sog archive that its ``meta.json`` does not name (readers skip them)."""
    return _scan(data, where, read_named=False)[1]


def _scan(data: bytes, where: str, *, read_named: bool) -> tuple[dict[str, bytes], list[str]]:
    """(``meta.json`` and, if ``read_named``, the entries it names; the other entries' names)."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except ZIP_ERRORS as exc:
        raise SogError(f"not a readable zip archive: {exc}", where=where) from exc
    with archive:
        infos = archive.infolist()
        if len(infos) > MAX_ENTRIES:
            raise SogError(
                f"{len(infos)} entries, more than the {MAX_ENTRIES} allowed", where=where
            )
        by_name = {info.filename: info for info in infos}
        if META_JSON not in by_name:
            raise SogError("archive has no meta.json at its root", where=where)
        files = {META_JSON: _read_entry(archive, by_name[META_JSON], len(data), where)}
        named = named_files(files[META_JSON], where=f"{where}/{META_JSON}")
        for name in named if read_named else []:
            if name in by_name:
                files[name] = _read_entry(archive, by_name[name], len(data), where)
    return files, sorted(set(by_name) - {META_JSON, *named})


def named_files(meta_json: bytes, *, where: str) -> list[str]:
    """The image files a ``meta.json`` (a chunk's or an SH-band chunk's) names (it is
    validated on the way)."""
    return [name for _, name in listed_files(parse_any_meta(meta_json, where=where))]


def _read_entry(archive: zipfile.ZipFile, info: zipfile.ZipInfo, total: int, where: str) -> bytes:
    """One entry's bytes, refusing methods other than stored/deflate and absurd sizes."""
    name = f"{where}/{info.filename}"
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise SogError(f"compression method {info.compress_type} is not supported", where=name)
    if info.compress_size > total or info.file_size > MAX_DEFLATE_RATIO * info.compress_size + 1024:
        raise SogError(
            f"entry claims {info.file_size} bytes ({info.compress_size} compressed) in a "
            f"{total}-byte archive",
            where=name,
        )
    if info.flag_bits & 0x1:
        raise SogError("encrypted entries are not supported", where=name)
    try:
        return archive.read(info)
    except ZIP_ERRORS as exc:
        raise SogError(f"damaged entry: {exc}", where=name) from exc

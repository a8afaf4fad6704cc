"""Bundled chunks: a ``.sog`` zip of stored entries, written deterministically (fixed
timestamps, no extra fields or comment, ``meta.json`` last as splat-transform writes it).

Reading inflates ``meta.json`` and only the entries it names, each under a cap applied while
inflating (the sizes a zip declares can lie): a 10 MB archive inflates to at most ~160 MB.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from collections.abc import Mapping

from ..constants import (
    IMAGE_SLACK_TEXELS,
    META_JSON,
    SH_CENTROIDS_PER_ROW,
    SH_COEFFS_BY_BANDS,
    pixel_budget,
)
from ..errors import FormatError, SogError
from ..schemas import ChunkMeta, ShBandsMeta, listed_files, parse_any_meta
from ..schemas.validate import CENTROIDS_FIELD, MAX_CENTROID_ROWS
from .webp_header import max_webp_bytes

FIXED_DATE = (1980, 1, 1, 0, 0, 0)
MAX_ENTRIES = 4096
ZIP_MAGIC = b"PK\x03\x04"
MAX_DEFLATE_RATIO = 1032
"""Deflate cannot expand data more than about 1032:1; a larger claim is a lie or a bomb."""
MAX_META_JSON_BYTES = 4 << 20
"""Most bytes a ``meta.json`` may hold: real ones take tens of KiB, and 4 MiB of the
smallest JSON values parses to under 100 MB."""
MAX_WEBP_MEMBER_RATIO = 16
"""Most bytes a deflated WebP member may inflate to per compressed byte (beyond
:data:`FREE_INFLATE_BYTES`): deflate shrinks real WebP by a few percent."""
FREE_INFLATE_BYTES = 64 << 10
INFLATE_STEP = 256 << 10
"""Bytes inflated at a time: a member lying about its size costs at most this beyond it."""
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
"""What :mod:`zipfile` raises on damaged archives."""


def is_zip(data: bytes) -> bool:
    """True when ``data`` starts like a zip archive (a bundled .sog)."""
    return data[:4] == ZIP_MAGIC


def bundle_bytes(files: Mapping[str, bytes]) -> bytes:
    """A reproducible .sog archive of ``files`` (name -> bytes), meta.json last: images
    stored (already compressed), ``meta.json`` deflated (its codebooks are most of a small
    chunk's fixed cost; the engine and splat-transform read it)."""
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
    """``meta.json`` and the entries it names of a .sog archive, each inflated under its
    cap (other entries are never read); any damage raises SogError."""
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
        meta_cap = (MAX_META_JSON_BYTES, "a meta.json may hold")
        files = {META_JSON: _read_entry(archive, by_name[META_JSON], meta_cap, len(data), where)}
        meta = parse_any_meta(files[META_JSON], where=f"{where}/{META_JSON}")
        named = [name for _, name in listed_files(meta)]
        if read_named:
            budgets = member_budgets(meta)
            for name in named:
                if name in by_name:
                    cap = _webp_cap(by_name[name], budgets[name])
                    files[name] = _read_entry(archive, by_name[name], cap, len(data), where)
    return files, sorted(set(by_name) - {META_JSON, *named})


def member_budgets(meta: ChunkMeta | ShBandsMeta) -> dict[str, int]:
    """The most bytes each image ``meta`` names may hold: :func:`~.webp_header.max_webp_bytes`
    of the largest image a reader accepts for it (per Gaussian: ``2 * count + slack`` texels
    within the pixel budget; the SH centroids: the largest palette's)."""
    per_gaussian = min(2 * int(meta.count) + IMAGE_SLACK_TEXELS, pixel_budget())
    budgets: dict[str, int] = {}
    for field, name in listed_files(meta):
        texels = per_gaussian
        if field == CENTROIDS_FIELD and meta.shN is not None:
            width = SH_CENTROIDS_PER_ROW * SH_COEFFS_BY_BANDS[int(meta.shN.bands)]
            texels = width * MAX_CENTROID_ROWS
        budgets[name] = max(budgets.get(name, 0), max_webp_bytes(texels))
    return budgets


def _webp_cap(info: zipfile.ZipInfo, budget: int) -> tuple[int, str]:
    """(cap, what it is) of an image member: its budget and, deflated, its ratio cap."""
    ratio = FREE_INFLATE_BYTES + MAX_WEBP_MEMBER_RATIO * info.compress_size
    if info.compress_type == zipfile.ZIP_DEFLATED and ratio < budget:
        return ratio, f"a WebP of {info.compress_size} deflated bytes may inflate to"
    return budget, "a WebP of the image size meta.json implies may hold"


def check_member(
    info: zipfile.ZipInfo,
    total: int,
    where: str,
    *,
    error: type[FormatError] = SogError,
    unsupported: type[FormatError] = SogError,
) -> None:
    """Refuse, before anything is inflated, a zip member stored other than plainly or by
    deflate, or encrypted (``unsupported``), or claiming more than its compressed bytes, within
    an archive of ``total`` bytes, can inflate to (``error``: MAX_DEFLATE_RATIO)."""
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise unsupported(f"compression method {info.compress_type} is not supported", where=where)
    if info.compress_size > total or info.file_size > MAX_DEFLATE_RATIO * info.compress_size + 1024:
        raise error(
            f"claims {info.file_size} bytes ({info.compress_size} compressed) in a "
            f"{total}-byte archive",
            where=where,
        )
    if info.flag_bits & 0x1:
        raise unsupported("encrypted entries are not supported", where=where)


def _read_entry(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, cap: tuple[int, str], total: int, where: str
) -> bytes:
    """One stored or deflated entry's bytes, refused if it claims or inflates to more than
    ``cap`` (at most cap + 1 bytes are inflated; zipfile checks the CRC-32 at the end)."""
    name = f"{where}/{info.filename}"
    check_member(info, total, name)
    most, what = cap
    if info.file_size > most:
        found = f"entry claims {info.file_size} bytes, more than the {most}"
        raise SogError(f"{found} {what} (a decompression bomb?)", where=name)
    pieces: list[bytes] = []
    left = most + 1
    try:
        with archive.open(info) as member:
            while left > 0 and (piece := member.read(min(INFLATE_STEP, left))):
                pieces.append(piece)
                left -= len(piece)
    except ZIP_ERRORS as exc:
        raise SogError(f"damaged entry: {exc}", where=name) from exc
    if left <= 0:
        found = f"entry inflates past {most} bytes, the most"
        raise SogError(f"{found} {what} (a decompression bomb?)", where=name)
    return b"".join(pieces)

"""Bundled chunks: a ``.sog`` zip of stored entries, written deterministically.

Entries are stored (WebP is already compressed), with a fixed timestamp so the same files
give byte-identical archives, no extra fields and no archive comment. ``meta.json`` goes last,
as splat-transform writes it.

Reading inflates nothing unbounded: ``meta.json`` at most :data:`MAX_META_JSON_BYTES`, each
image it names at most what its image can hold (:func:`member_budgets`) and, deflated, at most
:data:`MAX_WEBP_MEMBER_RATIO` times its compressed size (so a 10 MB archive inflates to at most
about 160 MB whatever count its meta declares); the others never. Every cap is applied while
inflating (at most cap + 1 bytes come out of the stream), since the sizes a zip declares can
lie.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import IO

from ..constants import (
    IMAGE_SLACK_TEXELS,
    META_JSON,
    SH_CENTROIDS_PER_ROW,
    SH_COEFFS_BY_BANDS,
    pixel_budget,
)
from ..errors import SogError
from ..schemas import ChunkMeta, ShBandsMeta, listed_files, parse_any_meta
from ..schemas.validate import CENTROIDS_FIELD, MAX_CENTROID_ROWS
from .webp_header import max_webp_bytes

FIXED_DATE = (1980, 1, 1, 0, 0, 0)
MAX_ENTRIES = 4096
ZIP_MAGIC = b"PK\x03\x04"
MAX_DEFLATE_RATIO = 1032
"""Deflate cannot expand data more than about 1032:1; a larger claim is a lie or a bomb."""
MAX_META_JSON_BYTES = 4 << 20
"""Most bytes a ``meta.json`` may hold (inflated, or as a file in a folder): its codebooks and
ranges take tens of KiB, and 4 MiB of the smallest JSON values parses to under 100 MB."""
MAX_WEBP_MEMBER_RATIO = 16
"""Most bytes a WebP member may inflate to per compressed byte, beyond :data:`FREE_INFLATE_BYTES`:
WebP is entropy-coded, so deflate shrinks a real one by a few percent (writers store it)."""
FREE_INFLATE_BYTES = 64 << 10
"""Bytes any member may inflate to whatever its compressed size."""
INFLATE_STEP = 256 << 10
"""Bytes inflated at a time: zipfile inflates as much as asked before it cuts a member at its
declared size, so a lying member costs at most this beyond what it declared."""
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

    Only those are inflated, each under its budget (see the module docstring): an entry
    ``meta.json`` never names is not read at all, so a small archive cannot make a reader
    inflate gigabytes. Any damage raises SogError.
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
        meta_info = by_name[META_JSON]
        meta_cap = _Cap(MAX_META_JSON_BYTES, "a meta.json may hold")
        files = {META_JSON: _read_entry(archive, meta_info, meta_cap, len(data), where)}
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
    """The most bytes each image ``meta`` names may hold: :func:`~.webp.max_webp_bytes` of the
    largest image a reader accepts for it (a per-Gaussian image: ``2 * count + slack`` texels
    within the read budget; the SH centroids: the largest palette's)."""
    per_gaussian = min(2 * int(meta.count) + IMAGE_SLACK_TEXELS, pixel_budget())
    budgets: dict[str, int] = {}
    for field, name in listed_files(meta):
        texels = per_gaussian
        if field == CENTROIDS_FIELD and meta.shN is not None:
            width = SH_CENTROIDS_PER_ROW * SH_COEFFS_BY_BANDS[int(meta.shN.bands)]
            texels = width * MAX_CENTROID_ROWS
        budgets[name] = max(budgets.get(name, 0), max_webp_bytes(texels))
    return budgets


def _inflate(member: IO[bytes], most: int) -> bytes:
    """At most ``most`` bytes of an open member, INFLATE_STEP at a time."""
    pieces: list[bytes] = []
    total = 0
    while total < most and (piece := member.read(min(INFLATE_STEP, most - total))):
        pieces.append(piece)
        total += len(piece)
    return b"".join(pieces)


@dataclass(frozen=True, slots=True)
class _Cap:
    """The most bytes an entry may inflate to, and what that bound is (for the message)."""

    size: int
    what: str


def _webp_cap(info: zipfile.ZipInfo, budget: int) -> _Cap:
    """What an image member may inflate to: its budget, and for a deflated one at most
    :data:`MAX_WEBP_MEMBER_RATIO` times its compressed bytes beyond the free allowance."""
    ratio = FREE_INFLATE_BYTES + MAX_WEBP_MEMBER_RATIO * info.compress_size
    if info.compress_type == zipfile.ZIP_DEFLATED and ratio < budget:
        return _Cap(ratio, f"a WebP of {info.compress_size} deflated bytes may inflate to")
    return _Cap(budget, "a WebP of the image size meta.json implies may hold")


def _read_entry(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, cap: _Cap, total: int, where: str
) -> bytes:
    """One entry's bytes, refusing methods other than stored/deflate and any entry that claims
    or inflates to more than ``cap`` (at most ``cap.size + 1`` bytes are ever inflated: the
    sizes a zip declares can lie)."""
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
    if info.file_size > cap.size:
        found = f"entry claims {info.file_size} bytes, more than the {cap.size}"
        raise SogError(f"{found} {cap.what} (a decompression bomb?)", where=name)
    try:
        with archive.open(info) as member:
            data = _inflate(member, cap.size + 1)  # zipfile checks the CRC-32 at the end
    except ZIP_ERRORS as exc:
        raise SogError(f"damaged entry: {exc}", where=name) from exc
    if len(data) > cap.size:
        found = f"entry inflates past {cap.size} bytes, the most"
        raise SogError(f"{found} {cap.what} (a decompression bomb?)", where=name)
    return data

"""Parse and dump ``meta.json``, check image sizes, export the JSON Schemas (sans-I/O).

Every failure is a :class:`~tsog_stream.errors.MetaError` whose ``field`` is the culprit's
path (``temporal.quats.mins[1][2]``), or ``<document>`` when the text is no JSON object.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from ..constants import (
    IMAGE_SLACK_TEXELS,
    SH_CENTROIDS_PER_ROW,
    SH_COEFFS_BY_BANDS,
    SH_PALETTE_MAX,
)
from ..errors import MetaError
from .sog_meta import DOCUMENT, SCHEMA_DIALECT, describe, schema_text, validate_into
from .tsog_meta import ChunkMeta, ShBandsMeta

AnyMeta = ChunkMeta | ShBandsMeta

KEY_ORDER = (
    "version",
    "asset",
    "count",
    "model",
    "means",
    "scales",
    "quats",
    "sh0",
    "shN",
    "timeline",
    "temporal",
    "extras",
)
"""Top-level key order written by :func:`dump_meta` (splat-transform's order, then ours)."""

CENTROIDS_FIELD = "shN.files[0]"
MAX_CENTROID_ROWS = SH_PALETTE_MAX // SH_CENTROIDS_PER_ROW
"""Rows of the largest shN centroid image (a 65536-entry palette)."""

SCHEMA_ID = "https://tsog-stream.invalid/schema/meta.schema.json"
SH_BANDS_SCHEMA_ID = "https://tsog-stream.invalid/schema/sh-bands.schema.json"


def _load_json(data: bytes | bytearray | memoryview | str, where: str) -> Any:
    """The JSON value of UTF-8 ``data`` (a bad byte reported with its offset; a leading BOM
    dropped, as browsers do; NaN/Infinity parse here for the schema to refuse by path)."""
    try:
        text = data if isinstance(data, str) else bytes(data).decode("utf-8")
        return json.loads(text.removeprefix("\ufeff"))
    except UnicodeDecodeError as exc:
        found = f"UTF-8 text, found byte 0x{exc.object[exc.start]:02x} at offset {exc.start}"
    except json.JSONDecodeError as exc:
        found = f"valid JSON, found {exc.msg} at line {exc.lineno} column {exc.colno}"
    except (ValueError, RecursionError) as exc:  # int digit limit, absurd nesting
        found = f"valid JSON, found {exc}"
    raise MetaError(f"expected {found}", field=DOCUMENT, where=where)


def _document(data: bytes | str | Mapping[str, Any], where: str) -> dict[str, Any]:
    """The JSON object of a ``meta.json`` (bytes, text or a mapping), with a version key."""
    document = data if isinstance(data, Mapping) else _load_json(data, where)
    if not isinstance(document, Mapping):
        found = describe(document)
        raise MetaError(f"expected a JSON object, found {found}", field=DOCUMENT, where=where)
    if "version" not in document:
        raise MetaError(
            "expected 2, found no version key (the SOG v1 layout is not supported)",
            field="version",
            where=where,
        )
    return dict(document)


def _is_sh_bands(document: Mapping[str, Any]) -> bool:
    """True for the meta of an SH-band chunk: bands without positions."""
    return "means" not in document and "shN" in document


def parse_meta(data: bytes | str | Mapping[str, Any], *, where: str = "meta.json") -> ChunkMeta:
    """Validate a ``meta.json`` (bytes, text or an already-parsed mapping) into a ChunkMeta.

    Raises MetaError naming the first failing field; ``where`` names the file in messages.
    """
    document = _document(data, where)
    if _is_sh_bands(document):
        raise MetaError(
            "expected a SOG chunk, found the meta of an SH-band chunk (it has no positions: "
            "read it with the chunk whose bands it holds)",
            field="means",
            where=where,
        )
    return validate_into(ChunkMeta, document, where=where)


def parse_sh_meta(
    data: bytes | str | Mapping[str, Any], *, where: str = "meta.json"
) -> ShBandsMeta:
    """Validate the ``meta.json`` of an SH-band chunk (MetaError naming the failing field)."""
    document = _document(data, where)
    if "means" in document:
        raise MetaError(
            "expected an SH-band chunk (bands only), found a SOG chunk's meta",
            field="means",
            where=where,
        )
    return validate_into(ShBandsMeta, document, where=where)


def parse_any_meta(data: bytes | str | Mapping[str, Any], *, where: str = "meta.json") -> AnyMeta:
    """A chunk's or an SH-band chunk's ``meta.json``, whichever it is (for readers of both,
    such as the bundle reader)."""
    document = _document(data, where)
    if _is_sh_bands(document):
        return validate_into(ShBandsMeta, document, where=where)
    return validate_into(ChunkMeta, document, where=where)


def dump_sh_meta(meta: ShBandsMeta) -> bytes:
    """Compact UTF-8 JSON of an SH-band chunk's meta (absent ``asset`` omitted)."""
    return _compact(meta.model_dump(mode="json", exclude_none=True))


def meta_document(meta: ChunkMeta) -> dict[str, Any]:
    """``meta`` as a JSON-ready dict: keys in :data:`KEY_ORDER`, absent optional keys omitted."""
    data = meta.model_dump(mode="json")
    out: dict[str, Any] = {}
    for key in KEY_ORDER:
        value = data.get(key)
        if value is not None or (key == "extras" and "extras" in meta.model_fields_set):
            out[key] = value
    if "timeline" in out:
        out["timeline"] = {k: v for k, v in out["timeline"].items() if v is not None}
    for key in meta.model_extra or {}:
        out[key] = data[key]
    return out


def dump_meta(meta: ChunkMeta) -> bytes:
    """Compact UTF-8 JSON of ``meta`` (floats as Python repr: an exact round trip)."""
    return _compact(meta_document(meta))


def _compact(document: Any) -> bytes:
    """UTF-8 JSON without whitespace."""
    return json.dumps(document, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode()


def listed_files(meta: AnyMeta) -> list[tuple[str, str]]:
    """(field path, file name) of every image ``meta`` references, in canonical order."""
    return meta.listed_files()


def _centroid_problem(meta: AnyMeta, size: tuple[int, int]) -> str | None:
    """Why the shN centroid image has the wrong size for ``shN.bands``/``shN.count``, or None."""
    shn = meta.shN
    if shn is None:
        return None
    width = SH_CENTROIDS_PER_ROW * SH_COEFFS_BY_BANDS[shn.bands]
    rows = math.ceil(shn.count / SH_CENTROIDS_PER_ROW)
    if size[0] != width:
        return f"expected width {width} (64 x coefficients of {shn.bands} bands), found {size[0]}"
    if size[1] < rows:
        return f"expected height >= {rows} (for {shn.count} palette entries), found {size[1]}"
    if size[1] > MAX_CENTROID_ROWS:
        return f"expected height <= {MAX_CENTROID_ROWS} (the largest palette), found {size[1]}"
    return None


def check_image_sizes(
    meta: AnyMeta, sizes: Mapping[str, tuple[int, int]], *, where: str = "meta.json"
) -> None:
    """Check image sizes (name -> (width, height)) against ``meta``; MetaError names the
    ``files`` entry (or ``count``) at fault.

    Per-Gaussian images share the first one's W x H (means, or an SH-band chunk's labels) with
    ``count <= W*H <= 2 * count + 4096`` (any writer's layout reads; memory stays proportional
    to the count); the shN centroids are ``64*coeffs`` wide, ``ceil(count / 64)`` to 1024 rows.
    """
    files = listed_files(meta)
    for field, name in files:
        if name not in sizes:
            raise MetaError(f"expected an image {name!r}, found none", field=field, where=where)
    first_field, first = next((f, n) for f, n in files if f != CENTROIDS_FIELD)
    width, height = sizes[first]
    if meta.count > width * height:
        raise MetaError(
            f"expected at most {width * height} Gaussians ({first!r} is {width}x{height}), "
            f"found {meta.count}",
            field="count",
            where=where,
        )
    most = 2 * meta.count + IMAGE_SLACK_TEXELS
    if width * height > most:
        raise MetaError(
            f"{first!r}: expected at most {most} texels for {meta.count} Gaussians, found "
            f"{width}x{height}",
            field=first_field,
            where=where,
        )
    for field, name in files:
        size = tuple(sizes[name])
        if field == CENTROIDS_FIELD:
            problem = _centroid_problem(meta, (size[0], size[1]))
        elif size != (width, height):
            found = f"{size[0]}x{size[1]}"
            problem = f"expected {width}x{height} like {first_field} ({first!r}), found {found}"
        else:
            problem = None
        if problem is not None:
            raise MetaError(f"{name!r}: {problem}", field=field, where=where)


def meta_json_schema_text() -> str:
    """JSON Schema (2020-12) of a TSOG chunk's meta.json as docs/schema/ ships it."""
    description = (
        "SOG v2 meta.json plus the optional TSOG keys 'timeline' and 'temporal'. Rules a "
        "schema cannot state (mins <= maxs, channel counts, fps only for types 0 and 1, "
        "distinct file names) are enforced by tsog_stream.schemas.parse_meta."
    )
    keys = {"$schema": SCHEMA_DIALECT, "$id": SCHEMA_ID, "title": "TSOG chunk meta.json"}
    return schema_text(ChunkMeta, **keys, description=description)


def sh_bands_json_schema_text() -> str:
    """JSON Schema (2020-12) of an SH-band chunk's meta.json (docs/spec.md §8.7)."""
    keys = {"$schema": SCHEMA_DIALECT, "$id": SH_BANDS_SCHEMA_ID}
    return schema_text(ShBandsMeta, **keys, title="TSOG SH-band chunk meta.json")

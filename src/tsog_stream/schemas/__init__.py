"""Schemas of the JSON a TSOG file holds (chunk ``meta.json``, the index), pydantic at the edge.

Parse with :func:`parse_meta`, write with :func:`dump_meta`; both raise
:class:`~tsog_stream.errors.MetaError` naming the failing field. ``docs/schema/`` ships
:func:`meta_json_schema_text` (scripts/export_schemas.py).
"""

from __future__ import annotations

from .sog_meta import MeansMeta, QuatsMeta, ScalesMeta, Sh0Meta, ShNMeta, SogMeta
from .tsog_meta import ChunkMeta, ShBandsMeta, TemporalAttributeMeta, TimelineMeta
from .validate import (
    check_image_sizes,
    dump_meta,
    dump_sh_meta,
    listed_files,
    meta_document,
    meta_json_schema_text,
    parse_any_meta,
    parse_meta,
    parse_sh_meta,
    sh_bands_json_schema_text,
)

__all__ = [
    "ChunkMeta",
    "MeansMeta",
    "QuatsMeta",
    "ScalesMeta",
    "Sh0Meta",
    "ShBandsMeta",
    "ShNMeta",
    "SogMeta",
    "TemporalAttributeMeta",
    "TimelineMeta",
    "check_image_sizes",
    "dump_meta",
    "dump_sh_meta",
    "listed_files",
    "meta_document",
    "meta_json_schema_text",
    "parse_any_meta",
    "parse_meta",
    "parse_sh_meta",
    "sh_bands_json_schema_text",
]

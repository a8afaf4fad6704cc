"""meta.json schemas: real SOG files, TSOG round trips, every rejection naming its field."""

from __future__ import annotations

import copy
import json
import math
import zipfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tsog_stream import schemas
from tsog_stream.errors import MetaError
from tsog_stream.model import TimelineType
from tsog_stream.schemas import (
    ChunkMeta,
    TimelineMeta,
    check_image_sizes,
    dump_meta,
    listed_files,
    meta_json_schema_text,
    parse_meta,
)
from tsog_stream.schemas.manifest import dump_manifest, manifest_json_schema_text, parse_manifest

ROOT = Path(__file__).resolve().parent.parent
PLAYBOT = Path("3dgs") / "pc_playbot_lod6_sog" / "meta.json"
WAVE = Path("4d") / "pc_flipbook_wave" / "wave_0001.sog"

Doc = dict[str, Any]


def sog_doc(count: int = 100, *, sh: bool = True) -> Doc:
    """A small valid SOG v2 meta document (synthetic codebooks)."""
    doc: Doc = {
        "version": 2,
        "asset": {"generator": "test"},
        "count": count,
        "means": {
            "mins": [-1.5, -0.25, -2.0],
            "maxs": [1.5, 0.75, 2.0],
            "files": ["means_l.webp", "means_u.webp"],
        },
        "scales": {"codebook": [i / 16 - 10 for i in range(256)], "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": [i / 64 - 2 for i in range(256)], "files": ["sh0.webp"]},
    }
    if sh:
        doc["shN"] = {
            "count": 128,
            "bands": 2,
            "codebook": [i / 128 - 1 for i in range(256)],
            "files": ["shN_centroids.webp", "shN_labels.webp"],
        }
    return doc


def tsog_doc() -> Doc:
    """A full TSOG meta: timeline type 2 with scene_length, means order 1, quats order 2."""
    doc = sog_doc()
    doc["timeline"] = {
        "type": 2,
        "scene_length": 10.0,
        "mins": [0.0, 0.05],
        "maxs": [10.0, 2.5],
        "files": ["timeline_l.webp", "timeline_u.webp"],
    }
    doc["temporal"] = {
        "means": {
            "mins": [[-0.5, -0.25, -0.125]],
            "maxs": [[0.5, 0.25, 0.125]],
            "files": ["temporal_means_1_l.webp", "temporal_means_1_u.webp"],
        },
        "quats": {
            "mins": [[-0.1, -0.2, -0.3, -0.4], [-0.01, -0.02, -0.03, -0.04]],
            "maxs": [[0.1, 0.2, 0.3, 0.4], [0.01, 0.02, 0.03, 0.04]],
            "files": [
                "temporal_quats_1_l.webp",
                "temporal_quats_1_u.webp",
                "temporal_quats_2_l.webp",
                "temporal_quats_2_u.webp",
            ],
        },
    }
    return doc


# --- real files and round trips --------------------------------------------------------------


def test_real_sog_meta_round_trips_byte_for_byte(samples: Path) -> None:
    raw = (samples / PLAYBOT).read_bytes()
    meta = parse_meta(raw, where=str(PLAYBOT))
    assert meta.shN is not None and meta.shN.bands == 2
    assert json.loads(dump_meta(meta)) == json.loads(raw)
    assert dump_meta(meta) == raw.strip()  # same key order and float repr as splat-transform


def test_real_sog_bundle_meta_round_trips(samples: Path) -> None:
    with zipfile.ZipFile(samples / WAVE) as bundle:
        raw = bundle.read("meta.json")
        names = set(bundle.namelist())
    meta = parse_meta(raw, where=f"{WAVE}/meta.json")
    assert meta.shN is None and meta.timeline is None
    assert json.loads(dump_meta(meta)) == json.loads(raw)
    assert {name for _, name in listed_files(meta)} <= names


def test_tsog_meta_round_trips() -> None:
    doc = tsog_doc()
    meta = parse_meta(doc)
    assert meta.timeline is not None and meta.timeline.type is TimelineType.CENTER_SCALE
    assert meta.temporal is not None and meta.temporal["quats"].orders == 2
    data = dump_meta(meta)
    assert b" " not in data and b"\n" not in data
    again = parse_meta(data)
    assert again == meta
    assert dump_meta(again) == data
    assert json.loads(data) == doc


def test_dump_key_order_and_preserved_keys() -> None:
    doc = tsog_doc()
    doc = {"zzz": [1, None], "extras": None, **{k: doc[k] for k in reversed(list(doc))}}
    doc["temporal"] = dict(reversed(list(doc["temporal"].items())))
    out = json.loads(dump_meta(parse_meta(doc)))
    assert list(out) == [
        *("version", "asset", "count", "means", "scales", "quats", "sh0", "shN"),
        *("timeline", "temporal", "extras", "zzz"),
    ]
    assert list(out["temporal"]) == ["means", "quats"]
    assert out["extras"] is None and out["zzz"] == [1, None]
    assert "fps" not in out["timeline"] and "model" not in out


def test_floats_round_trip_exactly() -> None:
    doc = sog_doc()
    doc["means"]["mins"] = [-4.692155711711776, 5e-324, -0.0]
    doc["means"]["maxs"] = [87.99999999999999, 0.1 + 0.2, 0.0]  # the largest bounds kept
    out = json.loads(dump_meta(parse_meta(json.dumps(doc))))
    assert out["means"]["mins"] == doc["means"]["mins"]
    assert out["means"]["maxs"][1] == 0.1 + 0.2
    assert math.copysign(1.0, out["means"]["mins"][2]) == -1.0


# --- rejections ------------------------------------------------------------------------------


def _set(path: str, value: Any) -> Callable[[Doc], None]:
    """A mutation setting ``a.b.c`` (list indexes as digits) of a document to ``value``."""

    def mutate(doc: Doc) -> None:
        *parents, last = path.split(".")
        node: Any = doc
        for key in parents:
            node = node[int(key)] if key.isdigit() else node[key]
        node[int(last) if last.isdigit() else last] = value

    return mutate


def _drop(key: str) -> Callable[[Doc], None]:
    """A mutation removing top-level ``key``."""
    return lambda doc: doc.pop(key)


def _chain(*mutations: Callable[[Doc], None]) -> Callable[[Doc], None]:
    """All ``mutations`` in turn."""

    def mutate(doc: Doc) -> None:
        for one in mutations:
            one(doc)

    return mutate


BAD_DOCS: list[tuple[str, Callable[[Doc], None], str]] = [
    ("count as string", _set("count", "12"), "count"),
    ("count as bool", _set("count", True), "count"),
    ("negative count", _set("count", -1), "count"),
    ("count as float", _set("count", 12.0), "count"),
    ("missing means", _drop("means"), "means"),
    ("missing version", _drop("version"), "version"),
    ("version 3", _set("version", 3), "version"),
    ("codebook of 255", _set("scales.codebook", [0.0] * 255), "scales.codebook"),
    ("codebook of 257", _set("sh0.codebook", [0.0] * 257), "sh0.codebook"),
    ("codebook string", _set("sh0.codebook.7", "1"), "sh0.codebook[7]"),
    ("null codebook entry", _set("scales.codebook.0", None), "scales.codebook[0]"),
    ("means mins > maxs", _set("means.mins.2", 3.0), "means.mins[2]"),
    ("shN bands 4", _set("shN.bands", 4), "shN.bands"),
    ("shN count 0", _set("shN.count", 0), "shN.count"),
    ("shN count too big", _set("shN.count", 65537), "shN.count"),
    ("unknown key in means", _set("means.min", [0, 0, 0]), "means.min"),
    ("timeline type 3", _set("timeline.type", 3), "timeline.type"),
    ("timeline type bool", _set("timeline.type", True), "timeline.type"),
    ("timeline type float", _set("timeline.type", 2.0), "timeline.type"),
    ("fps with type 2", _set("timeline.fps", 30), "timeline.fps"),
    ("fps zero", _set("timeline.fps", 0), "timeline.fps"),
    ("negative scene_length", _set("timeline.scene_length", -1.0), "timeline.scene_length"),
    ("typo in timeline", _set("timeline.fsp", 30), "timeline.fsp"),
    ("timeline mins > maxs", _set("timeline.mins.0", 11.0), "timeline.mins[0]"),
    ("timeline three files", _set("timeline.files", ["a", "b", "c"]), "timeline.files"),
    ("timeline three mins", _set("timeline.mins", [0.0, 0.0, 0.0]), "timeline.mins"),
    (
        "quats two channels",  # 4 (w, x, y, z) or the paper's 3 (x, y, z) only
        _chain(
            _set("temporal.quats.mins", [[0, 0], [0, 0]]),
            _set("temporal.quats.maxs", [[1, 1], [1, 1]]),
        ),
        "temporal.quats.mins[0]",
    ),
    ("unknown attribute", _set("temporal.colour", {}), "temporal.colour"),
    (
        "wrong number of files",
        _set("temporal.means.files", ["a", "b", "c"]),
        "temporal.means.files",
    ),
    ("maxs rows != mins rows", _set("temporal.quats.maxs", [[1, 1, 1, 1]]), "temporal.quats.maxs"),
    ("nested mins > maxs", _set("temporal.quats.mins.1.2", 0.5), "temporal.quats.mins[1][2]"),
    ("too many orders", _set("temporal.means.mins", [[0, 0, 0]] * 9), "temporal.means.mins"),
    ("empty temporal", _set("temporal", {}), "temporal"),
    ("temporal without timeline", _drop("timeline"), "temporal"),
    ("escape", _set("means.files.0", "../evil.webp"), "means.files[0]"),
    ("absolute", _set("quats.files.0", "/etc/passwd"), "quats.files[0]"),
    ("subfolder", _set("shN.files.1", "a/b.webp"), "shN.files[1]"),
    ("backslash", _set("timeline.files.1", "..\\x"), "timeline.files[1]"),
    ("NUL", _set("temporal.quats.files.3", "x\x00.webp"), "temporal.quats.files[3]"),
    ("drive letter", _set("sh0.files.0", "C:sh0.webp"), "sh0.files[0]"),
    ("dot-dot", _set("scales.files.0", ".."), "scales.files[0]"),
    ("empty name", _set("scales.files.0", ""), "scales.files[0]"),
    ("256-byte name", _set("scales.files.0", "é" * 128), "scales.files[0]"),
    ("duplicate name", _set("quats.files.0", "sh0.webp"), "sh0.files[0]"),
    ("NaN in extras", _set("extras", {"a": [1, math.nan]}), "extras.a[1]"),
    ("Infinity in unknown key", _set("other", {"x": math.inf}), "other.x"),
    ("lone surrogate", _set("model", "\ud800"), "model"),
]


@pytest.mark.parametrize(
    ("mutate", "field"), [case[1:] for case in BAD_DOCS], ids=[case[0] for case in BAD_DOCS]
)
def test_bad_meta_names_the_field(mutate: Callable[[Doc], None], field: str) -> None:
    doc = tsog_doc()
    mutate(doc)
    with pytest.raises(MetaError) as info:
        parse_meta(doc, where="chunk/meta.json")
    assert info.value.field == field
    assert info.value.where == "chunk/meta.json"
    assert "expected" in info.value.message


def test_messages_keep_braces_and_say_what_was_found() -> None:
    doc = sog_doc()
    doc["means"]["files"][0] = "{message}/{tsog_suffix}"
    with pytest.raises(MetaError) as info:
        parse_meta(doc)
    assert "found string '{message}/{tsog_suffix}'" in info.value.message
    doc = sog_doc()
    doc["count"] = "12"
    with pytest.raises(MetaError) as info:
        parse_meta(doc)
    assert info.value.message.endswith(": expected a valid integer, found string '12'")


def test_type0_with_nonzero_g_channel() -> None:
    doc = tsog_doc()
    doc["timeline"].update(type=0, fps=30, mins=[0.0, 0.0], maxs=[299.0, 0.5])
    with pytest.raises(MetaError) as info:
        parse_meta(doc)
    assert info.value.field == "timeline.maxs[1]"
    doc["timeline"]["maxs"][1] = 0.0
    assert parse_meta(doc).timeline == TimelineMeta(
        type=TimelineType.FRAME,
        fps=30.0,
        scene_length=10.0,
        mins=(0.0, 0.0),
        maxs=(299.0, 0.0),
        files=("timeline_l.webp", "timeline_u.webp"),
    )


@pytest.mark.parametrize(
    ("text", "field"),
    [
        (json.dumps(sog_doc()).replace("-1.5", "NaN", 1), "means.mins[0]"),
        (json.dumps(tsog_doc()).replace("2.5]", "Infinity]", 1), "timeline.maxs[1]"),
        (json.dumps(sog_doc()).replace("-10.0", "-Infinity", 1), "scales.codebook[0]"),
        (json.dumps(sog_doc()).replace('"count": 100', '"count": 1e400', 1), "count"),
    ],
    ids=["NaN", "Infinity", "-Infinity", "huge float"],
)
def test_non_finite_literals_are_rejected(text: str, field: str) -> None:
    with pytest.raises(MetaError) as info:
        parse_meta(text)
    assert info.value.field == field


@pytest.mark.parametrize(
    "data",
    [b'{"version": 2,', b'{"version":2,"count":"\xff"}', b"[1, 2]", b"", b"\xef\xbb\xbf null"],
    ids=["truncated", "not UTF-8", "array", "empty", "BOM null"],
)
def test_bad_documents(data: bytes) -> None:
    with pytest.raises(MetaError) as info:
        parse_meta(data)
    assert info.value.field == "<document>"


def test_bom_is_tolerated() -> None:
    raw = b"\xef\xbb\xbf" + json.dumps(sog_doc()).encode()
    assert parse_meta(raw).count == 100


# --- temporal entries ------------------------------------------------------------------------


def test_temporal_entries_keep_their_rows_and_files() -> None:
    doc = tsog_doc()
    temporal = parse_meta(doc).temporal
    assert temporal is not None
    quats = temporal["quats"]
    assert (quats.orders, quats.channels) == (2, 4)
    assert quats.mins == tuple(tuple(row) for row in doc["temporal"]["quats"]["mins"])
    assert quats.files[2:] == ("temporal_quats_2_l.webp", "temporal_quats_2_u.webp")


def test_a_temporal_entry_of_another_channel_count_is_refused_by_path() -> None:
    doc = tsog_doc()
    doc["temporal"]["opacity"] = {
        "mins": [[0.0, 0.0]],
        "maxs": [[1.0, 1.0]],
        "files": ["temporal_opacity_1_l.webp", "temporal_opacity_1_u.webp"],
    }
    with pytest.raises(MetaError) as info:
        parse_meta(doc)
    assert info.value.field == "temporal.opacity.mins[0]"


# --- files and image sizes -------------------------------------------------------------------


def test_listed_files_order() -> None:
    assert listed_files(parse_meta(tsog_doc())) == [
        ("means.files[0]", "means_l.webp"),
        ("means.files[1]", "means_u.webp"),
        ("quats.files[0]", "quats.webp"),
        ("scales.files[0]", "scales.webp"),
        ("sh0.files[0]", "sh0.webp"),
        ("shN.files[0]", "shN_centroids.webp"),
        ("shN.files[1]", "shN_labels.webp"),
        ("timeline.files[0]", "timeline_l.webp"),
        ("timeline.files[1]", "timeline_u.webp"),
        ("temporal.means.files[0]", "temporal_means_1_l.webp"),
        ("temporal.means.files[1]", "temporal_means_1_u.webp"),
        ("temporal.quats.files[0]", "temporal_quats_1_l.webp"),
        ("temporal.quats.files[1]", "temporal_quats_1_u.webp"),
        ("temporal.quats.files[2]", "temporal_quats_2_l.webp"),
        ("temporal.quats.files[3]", "temporal_quats_2_u.webp"),
    ]


def _sizes(meta: ChunkMeta, width: int = 12, height: int = 12) -> dict[str, tuple[int, int]]:
    sizes = {name: (width, height) for _, name in listed_files(meta)}
    sizes["shN_centroids.webp"] = (64 * 8, 2)  # 2 bands -> 8 coefficients; 128 entries -> 2 rows
    return sizes


def test_check_image_sizes_accepts_consistent_sizes() -> None:
    meta = parse_meta(tsog_doc())
    check_image_sizes(meta, _sizes(meta))
    check_image_sizes(meta, _sizes(meta, 10, 10))  # exactly count texels; multiples of 4 not needed


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"temporal_quats_2_u.webp": (12, 16)}, "temporal.quats.files[3]"),
        ({"sh0.webp": (16, 12)}, "sh0.files[0]"),
        ({"means_l.webp": (9, 11), "means_u.webp": (9, 11)}, "count"),
        ({"shN_centroids.webp": (64 * 3, 2)}, "shN.files[0]"),
        ({"shN_centroids.webp": (64 * 8, 1)}, "shN.files[0]"),
        ({"timeline_u.webp": None}, "timeline.files[1]"),
        ({"means_l.webp": None}, "means.files[0]"),
    ],
    ids=[
        "temporal size",
        "sh0 size",
        "count too large",
        "centroid width",
        "centroid rows",
        "missing",
        "missing means",
    ],
)
def test_check_image_sizes_rejects(change: dict[str, tuple[int, int] | None], field: str) -> None:
    meta = parse_meta(tsog_doc())
    sizes = _sizes(meta)
    for name, size in change.items():
        if size is None:
            del sizes[name]
        else:
            sizes[name] = size
    with pytest.raises(MetaError) as info:
        check_image_sizes(meta, sizes, where="x/meta.json")
    assert info.value.field == field
    assert info.value.where == "x/meta.json"


# --- schema export and public surface --------------------------------------------------------


def test_committed_json_schema_is_fresh() -> None:
    committed = (ROOT / "docs" / "schema" / "meta.schema.json").read_text(encoding="utf-8")
    assert committed == meta_json_schema_text(), "run scripts/export_schemas.py"


def test_json_schema_describes_every_property() -> None:
    schema = json.loads(meta_json_schema_text())
    models = [schema, *schema["$defs"].values()]
    for model in models:
        for name, prop in model.get("properties", {}).items():
            assert prop.get("description"), f"{model.get('title')}.{name} has no description"


def test_public_names() -> None:
    public = {
        name
        for name in dir(schemas)
        if not name.startswith("_")
        and name != "annotations"
        and not isinstance(getattr(schemas, name), ModuleType)
    }
    assert set(schemas.__all__) == public


# --- property test ---------------------------------------------------------------------------

FLOATS = st.floats(allow_nan=False, allow_infinity=False)
NAME_CHARS = st.characters(blacklist_categories=("Cs", "Cc"), blacklist_characters="/\\:")
SUFFIX = st.text(NAME_CHARS, max_size=12)
JSON_LEAVES = st.none() | st.booleans() | st.integers() | FLOATS | st.text(NAME_CHARS, max_size=8)
JSON_VALUES = st.recursive(
    JSON_LEAVES,
    lambda inner: (
        st.lists(inner, max_size=3)
        | st.dictionaries(st.text(NAME_CHARS, max_size=5), inner, max_size=3)
    ),
    max_leaves=8,
)


@st.composite
def ranges(
    draw: st.DrawFn, width: int, bound: float = 3.4028234663852886e38
) -> tuple[list[float], list[float]]:
    """mins <= maxs, ``width`` channels, within ±``bound`` (float32's, or the log-position
    bound of ``means``)."""
    values = st.floats(-bound, bound)
    pairs = [sorted(draw(st.tuples(values, values))) for _ in range(width)]
    return [p[0] for p in pairs], [p[1] for p in pairs]


@st.composite
def metas(draw: st.DrawFn) -> Doc:
    """Random valid TSOG meta documents (file names distinct by construction)."""
    suffix = draw(SUFFIX)

    def name(role: str) -> str:
        return f"{role}.{suffix}.webp"

    doc = sog_doc(draw(st.integers(0, 10**7)), sh=draw(st.booleans()))
    doc["means"]["mins"], doc["means"]["maxs"] = draw(ranges(3, bound=88.0))
    doc["means"]["files"] = [name("ml"), name("mu")]
    doc["scales"]["codebook"] = draw(st.lists(FLOATS, min_size=256, max_size=256))
    if "shN" in doc:
        doc["shN"].update(count=draw(st.integers(1, 65536)), bands=draw(st.integers(1, 3)))
    if draw(st.booleans()):
        doc["model"] = draw(st.text(NAME_CHARS, max_size=10))
    if draw(st.booleans()):
        doc["extras"] = draw(JSON_VALUES)
    if draw(st.booleans()):
        doc["x-other"] = draw(JSON_VALUES)
    if draw(st.booleans()):
        kind = draw(st.integers(0, 2))
        mins, maxs = draw(ranges(2))
        if kind == 0:
            mins[1] = maxs[1] = 0.0
        doc["timeline"] = {
            "type": kind,
            "mins": mins,
            "maxs": maxs,
            "files": [name("tl"), name("tu")],
        }
        if kind < 2 and draw(st.booleans()):
            doc["timeline"]["fps"] = draw(st.floats(0.001, 1000.0))
        if draw(st.booleans()):
            doc["timeline"]["scene_length"] = draw(st.floats(0.001, 1e6))
        attrs = draw(
            st.lists(st.sampled_from(["means", "scales", "quats", "sh0", "opacity"]), unique=True)
        )
        temporal: Doc = {}
        for attr in attrs:
            width = {"means": 3, "scales": 3, "quats": 4, "sh0": 3, "opacity": 1}[attr]
            rows = [draw(ranges(width)) for _ in range(draw(st.integers(1, 3)))]
            temporal[attr] = {
                "mins": [r[0] for r in rows],
                "maxs": [r[1] for r in rows],
                "files": [name(f"t{attr}{k}{h}") for k in range(len(rows)) for h in "lu"],
            }
        if temporal:
            doc["temporal"] = temporal
    return doc


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(metas())
def test_random_valid_metas_round_trip(doc: Doc) -> None:
    meta = parse_meta(copy.deepcopy(doc))
    data = dump_meta(meta)
    again = parse_meta(data)
    assert again == meta
    assert dump_meta(again) == data
    assert json.loads(data) == doc


def test_committed_manifest_schema_is_fresh() -> None:
    committed = (ROOT / "docs" / "schema" / "manifest.schema.json").read_text(encoding="utf-8")
    assert committed == manifest_json_schema_text(), "run scripts/export_schemas.py"


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("means.mins", [-1e308, 0.0, 0.0], "means.mins[0]"),
        ("means.maxs", [1000.0, 1.0, 1.0], "means.maxs[0]"),
        ("timeline.maxs", [1e308, 1.0], "timeline.mins[0]"),
        ("temporal.means.mins", [[-1e308, 0.0, 0.0]], "temporal.means.mins[0][0]"),
    ],
)
def test_ranges_that_would_decode_to_inf_or_nan_are_refused(
    path: str, value: list[Any], field: str
) -> None:
    doc = tsog_doc()
    _set(path, value)(doc)
    if path == "timeline.maxs":
        _set("timeline.mins", [-1e308, 0.0])(doc)
    with pytest.raises(MetaError) as info:
        parse_meta(json.dumps(doc).encode())
    assert info.value.field == field, str(info.value)


# --- the index's scene: static streams, assumed lengths (issue 55) -----------------------------


def manifest_doc(**scene: Any) -> Doc:
    """A valid index of no chunks whose scene fields are overridden by ``scene``."""
    box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
    fields: Doc = {"gaussians": 0, "stored": 0, "start_s": 0.0, "end_s": 2.0, "fps": None}
    fields |= {"timeline_type": 2, "temporal": {}, "sh_bands": 0, "bbox": box}
    return {
        "generator": "test",
        "policy": "hybrid",
        "window_s": 1.0,
        "max_pixels": 256,
        "scene": {**fields, **scene},
        "nodes": [],
        "chunks": [],
        "payload_bytes": 0,
    }


def test_an_index_without_duration_assumed_reads_as_a_length_that_was_read() -> None:
    """Indexes written before the field read as before; the writer leaves it out when false
    (the same bytes as before) and writes it when true."""
    old = parse_manifest(json.dumps(manifest_doc()).encode())
    assert old.scene.duration_assumed is False
    assert "duration_assumed" not in json.loads(dump_manifest(old))["scene"]
    assumed = parse_manifest(json.dumps(manifest_doc(duration_assumed=True)).encode())
    assert assumed.scene.duration_assumed is True
    assert json.loads(dump_manifest(assumed))["scene"]["duration_assumed"] is True
    assert parse_manifest(dump_manifest(assumed)) == assumed


@pytest.mark.parametrize("value", ["true", 1, 0, None, "yes"])
def test_duration_assumed_is_a_json_boolean(value: Any) -> None:
    with pytest.raises(MetaError) as info:
        parse_manifest(json.dumps(manifest_doc(duration_assumed=value)).encode())
    assert info.value.field == "scene.duration_assumed", str(info.value)


def test_a_static_index_is_one_moment_without_a_timeline() -> None:
    static = parse_manifest(
        json.dumps(manifest_doc(timeline_type=None, start_s=0.0, end_s=0.0)).encode()
    )
    assert static.scene.timeline_type is None and static.scene.start_s == static.scene.end_s
    schema = json.loads(manifest_json_schema_text())["$defs"]["SceneInfo"]["properties"]
    assert schema["duration_assumed"]["type"] == "boolean"
    assert schema["duration_assumed"]["default"] is False

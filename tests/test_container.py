"""The .tsogs container: damage is always a TsogError, one request opens it, pack/unpack, CLI.

Damaged containers are built from one small valid container by flipping, cutting or patching
bytes (the header re-packed, the index re-encoded with ``encode_index``), so each case breaks
exactly one rule of docs/spec.md §8.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import TypeVar

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import means_log_step
from test_interop import assert_same_gaussians, run_tool
from tsog_stream import (
    FormatError,
    InputError,
    IntegrityError,
    MetaError,
    Scene,
    SourceError,
    TimelineType,
    TsogError,
    UnsupportedError,
)
from tsog_stream.cli.main import main
from tsog_stream.client import StreamClient, open_stream
from tsog_stream.client.verify import Check
from tsog_stream.codec.bundle import read_bundle
from tsog_stream.codec.positions import log_transform
from tsog_stream.container import writer
from tsog_stream.container.header import HEADER_SIZE, PREFIX_SIZE, Header, container_length
from tsog_stream.container.index import MAX_INDEX_BYTES, encode_index
from tsog_stream.container.sources import FileSource, MemorySource, read_index
from tsog_stream.container.stream_index import MANIFEST, StreamIndex
from tsog_stream.io.chunks import read_chunk
from tsog_stream.io.ply import read_ply
from tsog_stream.io.sequence import read_ply_sequence
from tsog_stream.schemas.manifest import Manifest, parse_manifest
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene

HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
FIREWORKS = "4d/tztechno_fireworks_frames"


def tiny_scene(background: int = 120, seed: int = 3) -> Scene:
    """A type-1 scene of a few hundred Gaussians (no SH: quick to encode)."""
    spec = SceneSpec(
        timeline_type=TimelineType.START_DURATION,
        background=background,
        objects=3,
        per_object=40,
        duration=2.0,
        fps=5.0,
        sh_bands=0,
        dynamic=("means",),
        seed=seed,
    )
    return generate_scene(spec)


SMALL_OPTIONS = SegmentOptions(window_s=0.5, policy="duplicate", max_pixels=12 * 12)


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A valid container with a handful of chunks and its index inside the 16 KiB prefix, the
    payloads after it (the layout of a container over ``COMPACT_MAX``)."""
    path = tmp_path_factory.mktemp("container") / "small.tsogs"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(writer, "COMPACT_MAX", 0)
        segment_scene(tiny_scene(), path, SMALL_OPTIONS)
    return path


@pytest.fixture(scope="module")
def compact(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same scene as ``small`` written as it is by default: compact, payloads right after
    the index."""
    path = tmp_path_factory.mktemp("container") / "compact.tsogs"
    segment_scene(tiny_scene(), path, SMALL_OPTIONS)
    return path


@pytest.fixture(scope="module")
def small_bytes(small: Path) -> bytes:
    return small.read_bytes()


def open_bytes(data: bytes) -> StreamIndex:
    """Open a container held in memory."""
    return asyncio.run(read_index(MemorySource(data, "damaged.tsogs")))


def open_and_read_all(data: bytes) -> None:
    """Open, then fetch, verify and decode every chunk."""

    async def run() -> None:
        source = MemorySource(data, "damaged.tsogs")
        index = await read_index(source)
        client = StreamClient(source, index)
        for chunk in index.manifest.chunks:
            await client.chunk_scene(chunk.id)

    asyncio.run(run())


def pack(folder: Path, out: Path) -> int:
    """``tsog pack``: the unpacked folder as one container file."""
    with open_stream(folder) as stream:
        return stream.pack(out)


def header_of(data: bytes) -> Header:
    return Header.unpack(data[:HEADER_SIZE])


def with_header(data: bytes, **changes: int | bytes) -> bytes:
    """``data`` with header fields replaced (packed as is: no checks)."""
    header = dataclasses.replace(header_of(data), **changes)  # type: ignore[arg-type]
    return header.pack() + data[HEADER_SIZE:]


def with_manifest(data: bytes, manifest: Manifest) -> bytes:
    """``data`` with its index replaced by ``manifest`` (re-encoded, header patched)."""
    index, digest, raw_length = encode_index(manifest)
    assert HEADER_SIZE + len(index) <= PREFIX_SIZE
    prefix = bytearray(data[:PREFIX_SIZE])
    prefix[HEADER_SIZE:] = bytes(PREFIX_SIZE - HEADER_SIZE)
    prefix[HEADER_SIZE : HEADER_SIZE + len(index)] = index
    out = bytes(prefix) + data[PREFIX_SIZE:]
    return with_header(
        out,
        index_offset=HEADER_SIZE,
        index_length=len(index),
        index_raw_length=raw_length,
        index_sha256=digest,
    )


R = TypeVar("R")


def unvalidated_copy(record: R, changes: Mapping[str, object]) -> R:
    """A copy of an index record with fields changed and not validated (to write bad ones)."""
    changed = copy.copy(record)
    for name, value in changes.items():
        object.__setattr__(changed, name, value)
    return changed


def edit_chunks(data: bytes, changes: Mapping[int, Mapping[str, object]]) -> bytes:
    """``data`` with chunk fields changed (``{chunk id: {field: value}}``), unvalidated."""
    manifest = open_bytes(data).manifest
    chunks = [unvalidated_copy(c, changes.get(c.id, {})) for c in manifest.chunks]
    return with_manifest(data, manifest.model_copy(update={"chunks": chunks}))


def short_file_with_chunk_in_prefix(data: bytes, *, claimed: int = 1024) -> bytes:
    """A file shorter than 16 KiB whose one chunk sits at byte 1024, after the index, and
    which its index says is at ``claimed``."""
    manifest = open_bytes(data).manifest
    chunk = min(manifest.chunks, key=lambda c: c.length)
    payload = data[chunk.offset : chunk.offset + chunk.length]
    at = 1024
    entry = dataclasses.replace(chunk, id=0, file="chunks/000000.sog", offset=claimed)
    home = (chunk.level, chunk.node)
    nodes = [
        dataclasses.replace(n, chunks=[0] if (n.level, n.index) == home else [])
        for n in manifest.nodes
    ]
    manifest = manifest.model_copy(
        update={"chunks": [entry], "nodes": nodes, "payload_bytes": chunk.length}
    )
    index, digest, raw_length = encode_index(manifest)
    assert HEADER_SIZE + len(index) <= at and at + len(payload) < PREFIX_SIZE
    body = bytearray(at + len(payload))
    body[HEADER_SIZE : HEADER_SIZE + len(index)] = index
    body[at:] = payload
    header = dataclasses.replace(
        header_of(data),
        index_length=len(index),
        index_raw_length=raw_length,
        file_length=len(body),
        index_sha256=digest,
    )
    body[:HEADER_SIZE] = header.pack()
    return bytes(body)


def flip(data: bytes, at: int, mask: int = 0x55) -> bytes:
    """``data`` with the byte at ``at`` XOR ``mask``."""
    out = bytearray(data)
    out[at] ^= mask
    return bytes(out)


# --- damage ------------------------------------------------------------------------------


def test_a_small_scene_is_written_compact(small: Path, small_bytes: bytes, compact: Path) -> None:
    """Under ``COMPACT_MAX`` of payloads nothing pads the file: the payloads follow the index
    at once, the same chunk bytes as in the 16 KiB-prefix layout, and the file opens, reads
    and verifies as that one does."""
    data = compact.read_bytes()
    index, reserved = open_bytes(data), open_bytes(small_bytes)
    header = index.header
    start = header.index_offset + header.index_length
    assert header.index_offset == HEADER_SIZE and header.version_minor >= 1
    first = min(c.offset for c in index.manifest.chunks)
    assert first - start in range(16), "at most a few zero bytes between index and payloads"
    assert len(data) == len(small_bytes) - PREFIX_SIZE + first
    estimate = container_length(index.manifest.payload_bytes, header.index_length)
    assert 0 <= len(data) - estimate < 16, "the segmenter's cost model counts the same bytes"
    for ours, theirs in zip(index.manifest.chunks, reserved.manifest.chunks, strict=True):
        assert ours.sha256 == theirs.sha256 and ours.offset - theirs.offset == first - PREFIX_SIZE
    open_and_read_all(data)
    with open_stream(compact) as reader:
        assert reader.verify().exit_code == 0


def test_payloads_outgrowing_compact_max_go_after_the_prefix(
    small_bytes: bytes, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Payloads held while the file may be compact are written after the 16 KiB prefix once
    they pass ``COMPACT_MAX``: the same file as one never held."""
    first_two = sum(c.length for c in open_bytes(small_bytes).manifest.chunks[:2])
    monkeypatch.setattr(writer, "COMPACT_MAX", first_two)
    path = tmp_path / "outgrown.tsogs"
    segment_scene(tiny_scene(), path, SMALL_OPTIONS)
    assert path.read_bytes() == small_bytes


def test_a_short_file_with_its_chunk_after_the_index_opens(small_bytes: bytes) -> None:
    open_and_read_all(short_file_with_chunk_in_prefix(small_bytes))


def test_the_small_container_is_valid(small: Path, small_bytes: bytes) -> None:
    index = open_bytes(small_bytes)
    assert len(index.manifest.chunks) >= 3
    assert index.header.index_offset == HEADER_SIZE
    assert index.manifest.chunks[0].offset == PREFIX_SIZE
    open_and_read_all(small_bytes)
    with open_stream(small) as reader:
        report = reader.verify()
    assert report.problems == [] and report.exit_code == 0


def _cases(data: bytes) -> dict[str, tuple[bytes, type[TsogError]]]:
    """Every damaged variant of ``data`` and the error class it must raise."""
    header = header_of(data)
    manifest = open_bytes(data).manifest
    first, second = manifest.chunks[0], manifest.chunks[1]
    mid_index = header.index_offset + header.index_length // 2

    last = manifest.chunks[-1]
    overlap = {1: {"offset": first.offset + first.length // 2}}
    past_end = {last.id: {"length": last.length + 10}}
    negative = {1: {"offset": -second.length}}
    into_prefix = {0: {"offset": HEADER_SIZE}}

    return {
        "empty file": (b"", FormatError),
        "shorter than the header": (data[: HEADER_SIZE - 1], FormatError),
        "header only": (data[:HEADER_SIZE], IntegrityError),
        "truncated payload": (data[:-100], IntegrityError),
        "truncated prefix": (data[: PREFIX_SIZE // 2], IntegrityError),
        "appended byte": (data + b"\x00", IntegrityError),
        "wrong magic": (b"TSOGX" + data[5:], FormatError),
        "text-mode newline": (data[:6] + b"\n" + data[8:], FormatError),
        "future major version": (with_header(data, version_major=2), UnsupportedError),
        "unknown required flag": (with_header(data, required_flags=1 << 7), UnsupportedError),
        "unknown index codec": (with_header(data, index_codec=2), UnsupportedError),
        "index past the end": (with_header(data, index_offset=len(data)), FormatError),
        "index inside the header": (with_header(data, index_offset=10), FormatError),
        "index too long": (with_header(data, index_length=len(data)), FormatError),
        "index raw length over the limit": (
            with_header(data, index_raw_length=MAX_INDEX_BYTES + 1),
            FormatError,
        ),
        "index raw length off by one": (
            with_header(data, index_raw_length=header.index_raw_length + 1),
            IntegrityError,
        ),
        "index hash": (with_header(data, index_sha256=bytes(32)), IntegrityError),
        "flipped index byte": (flip(data, mid_index), IntegrityError),
        "overlapping chunks": (edit_chunks(data, overlap), IntegrityError),
        "chunk past the payload": (edit_chunks(data, past_end), IntegrityError),
        "chunk inside the prefix": (edit_chunks(data, into_prefix), IntegrityError),
        "negative chunk offset": (edit_chunks(data, negative), MetaError),
        "short file, chunk over its index": (
            short_file_with_chunk_in_prefix(data, claimed=HEADER_SIZE + 16),
            IntegrityError,
        ),
    }


CASES = [
    "empty file",
    "shorter than the header",
    "header only",
    "truncated payload",
    "truncated prefix",
    "appended byte",
    "wrong magic",
    "text-mode newline",
    "future major version",
    "unknown required flag",
    "unknown index codec",
    "index past the end",
    "index inside the header",
    "index too long",
    "index raw length over the limit",
    "index raw length off by one",
    "index hash",
    "flipped index byte",
    "overlapping chunks",
    "chunk past the payload",
    "chunk inside the prefix",
    "negative chunk offset",
    "short file, chunk over its index",
]


@pytest.mark.parametrize("case", CASES)
def test_damaged_containers_raise_the_right_error(case: str, small_bytes: bytes) -> None:
    data, error = _cases(small_bytes)[case]
    with pytest.raises(error) as info:
        open_bytes(data)
    assert "damaged.tsogs" in str(info.value), "the message names the file"


def test_every_damage_is_a_tsog_error_and_nothing_else(small_bytes: bytes) -> None:
    cases = _cases(small_bytes)
    assert sorted(cases) == sorted(CASES)
    for name, (data, _) in cases.items():
        try:
            open_and_read_all(data)
        except Exception as exc:
            assert isinstance(exc, TsogError), f"{name}: {type(exc).__name__}: {exc}"
        else:
            pytest.fail(f"{name}: opened and read without an error")


def test_files_on_disk_fail_the_same_way(small_bytes: bytes, tmp_path: Path) -> None:
    path = tmp_path / "damaged.tsogs"
    for data, error in _cases(small_bytes).values():
        path.write_bytes(data)
        with pytest.raises(error):
            open_stream(path).close()
    with pytest.raises(SourceError, match="cannot read"):
        open_stream(tmp_path / "missing.tsogs")


def test_a_flipped_chunk_byte_fails_that_chunk_only(small_bytes: bytes, tmp_path: Path) -> None:
    index = open_bytes(small_bytes)
    victim = index.manifest.chunks[1]
    path = tmp_path / "flipped.tsogs"
    path.write_bytes(flip(small_bytes, victim.offset + victim.length // 2))
    with open_stream(path) as reader:
        with pytest.raises(IntegrityError, match=f"chunk {victim.id}"):
            reader.chunk_bytes(victim.id)
        with pytest.raises(IntegrityError):
            reader.chunk_scene(victim.id)
        for chunk in index.manifest.chunks:
            if chunk.id != victim.id:
                assert len(reader.chunk_scene(chunk.id)) == chunk.count
        report = reader.verify()
    assert report.exit_code == int(Check.HASH) == 3
    assert [(kind, cid) for kind, cid, _ in report.problems] == [(Check.HASH, victim.id)]


def test_verify_names_each_kind_of_problem(small_bytes: bytes, tmp_path: Path) -> None:
    """Exit status 4 for undecodable bytes whose hash matches, 5 over budget, 6 when a chunk
    contradicts its index entry (count, or an interval where none of it is visible)."""
    manifest = open_bytes(small_bytes).manifest
    chunk = manifest.chunks[1]
    garbage = bytes(chunk.length)
    replaced = bytearray(small_bytes)
    replaced[chunk.offset : chunk.offset + chunk.length] = garbage
    undecodable = edit_chunks(bytes(replaced), {1: {"sha256": hashlib.sha256(garbage).hexdigest()}})
    cases = [
        (undecodable, Check.DECODE, {1}),
        (
            with_manifest(small_bytes, manifest.model_copy(update={"max_pixels": 64})),
            Check.BUDGET,
            None,
        ),
        (edit_chunks(small_bytes, {1: {"count": chunk.count + 1}}), Check.INDEX, {1}),
        (edit_chunks(small_bytes, {1: {"start_s": 50.0, "end_s": 60.0}}), Check.INDEX, {1}),
    ]
    path = tmp_path / "v.tsogs"
    for data, kind, culprits in cases:
        path.write_bytes(data)
        with open_stream(path) as reader:
            report = reader.verify()
        assert report.exit_code == kind, report.problems
        if culprits is not None:
            assert {cid for _, cid, _ in report.problems} == culprits


def test_tolerated_header_changes_still_open(small_bytes: bytes) -> None:
    """Minor versions, optional flags and reserved bytes are for future writers."""
    for data in (
        with_header(small_bytes, version_minor=7),
        with_header(small_bytes, optional_flags=0xFFFF_FFFF),
        small_bytes[:100] + b"\xff" + small_bytes[101:],  # reserved
    ):
        assert open_bytes(data).manifest == open_bytes(small_bytes).manifest


def test_every_flipped_index_byte_is_caught(small_bytes: bytes) -> None:
    header = header_of(small_bytes)
    original = open_bytes(small_bytes).manifest
    for at in range(header.index_offset, header.index_offset + header.index_length):
        try:
            manifest = open_bytes(flip(small_bytes, at)).manifest
        except (IntegrityError, FormatError):
            continue
        # only a change zstd ignores (e.g. frame header bits) may pass, and then unchanged
        assert manifest == original, f"byte {at}: a changed index was accepted"


def test_absurd_but_valid_index_values_do_not_break_chunk_choice(small_bytes: bytes) -> None:
    """Huge levels and extreme window lengths pass the schema; choosing chunks must cope."""
    manifest = open_bytes(small_bytes).manifest
    far = dataclasses.replace(manifest.nodes[0], level=10**9, index=0)
    index = open_bytes(with_manifest(small_bytes, manifest.model_copy(update={"nodes": [far]})))
    for t in (0.0, 0.2, 0.7, 2.0):
        chosen = index.chunks_for(t)
        assert {c.id for c in chosen} <= set(far.chunks)
        assert all(c.start_s - 1e-6 <= t <= c.end_s + 1e-6 for c in chosen)
    for window_s in (5e-324, 1e300):
        changed = manifest.model_copy(update={"window_s": window_s})
        index = open_bytes(with_manifest(small_bytes, changed))
        for t in (0.0, 0.7, 2.0):
            assert set(index.chunks_for(t)) <= set(manifest.chunks)


def test_times_must_be_finite(small: Path) -> None:
    with open_stream(small) as reader:
        for t in (float("nan"), float("inf"), -float("inf")):
            with pytest.raises(InputError, match="finite"):
                reader.frame_at(t)
        assert reader.index.chunks_for_interval(2.5, 3.0) == []
        assert len(reader.frame_at(-0.5)) == 0


@st.composite
def damage(draw: st.DrawFn, size: int) -> tuple[list[tuple[int, int]], int]:
    """Byte flips (biased to the header and index) and a length to cut to."""
    position = st.one_of(
        st.integers(0, HEADER_SIZE - 1),
        st.integers(0, PREFIX_SIZE - 1),
        st.integers(0, size - 1),
    )
    flips = draw(st.lists(st.tuples(position, st.integers(1, 255)), max_size=4))
    cut = draw(st.one_of(st.just(size), st.integers(0, size)))
    return flips, cut


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_random_damage_is_a_tsog_error_or_harmless(small_bytes: bytes, data: st.DataObject) -> None:
    flips, cut = data.draw(damage(len(small_bytes)))
    damaged = bytearray(small_bytes)
    for at, mask in flips:
        damaged[at] ^= mask
    with contextlib.suppress(TsogError):
        open_and_read_all(bytes(damaged[:cut]))


# --- the first request ---------------------------------------------------------------------


def test_a_small_container_opens_with_one_request(small_bytes: bytes) -> None:
    source = MemorySource(small_bytes)
    index = asyncio.run(read_index(source))
    assert source.stats.requests == 1 and source.stats.bytes == PREFIX_SIZE
    assert index.header.index_offset + index.header.index_length <= PREFIX_SIZE


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Scene]:
    """A container with so many chunks that its index does not fit the prefix."""
    scene = tiny_scene(background=2700, seed=4)
    path = tmp_path_factory.mktemp("big") / "big.tsogs"
    segment_scene(scene, path, SegmentOptions(window_s=2.0, max_pixels=16))
    return path, scene


def test_a_big_index_goes_to_the_end_and_opening_takes_two_requests(
    big: tuple[Path, Scene],
) -> None:
    path, scene = big
    data = path.read_bytes()
    source = MemorySource(data)
    index = asyncio.run(read_index(source))
    header = index.header
    assert len(index.manifest.chunks) > 150
    assert HEADER_SIZE + header.index_length > PREFIX_SIZE
    assert header.index_offset == PREFIX_SIZE + index.manifest.payload_bytes
    assert header.index_offset + header.index_length == header.file_length == len(data)
    assert source.stats.requests == 2
    assert source.stats.bytes == PREFIX_SIZE + header.index_length
    assert data[HEADER_SIZE:PREFIX_SIZE] == bytes(PREFIX_SIZE - HEADER_SIZE)
    file_source = FileSource(path)
    asyncio.run(read_index(file_source))
    assert file_source.stats.requests == 2
    with open_stream(path) as reader:
        assert len(reader.frame_at(0.9)) == len(scene.at(0.9))


def test_the_writer_moves_the_index_when_the_prefix_is_full(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Any index longer than the room after the header goes to the end (checked with a
    smaller room, so a small container exercises the same branch)."""
    monkeypatch.setattr(writer, "HEADER_SIZE", PREFIX_SIZE - 64)
    path = tmp_path / "moved.tsogs"
    segment_scene(tiny_scene(), path, SegmentOptions(window_s=1.0))
    data = path.read_bytes()
    header = header_of(data)
    assert header.index_offset > PREFIX_SIZE
    source = MemorySource(data)
    asyncio.run(read_index(source))
    assert source.stats.requests == 2


# --- pack / unpack -------------------------------------------------------------------------


def test_unpack_then_pack_is_byte_identical(compact: Path, tmp_path: Path) -> None:
    small = compact
    folder = tmp_path / "unpacked"
    with open_stream(small) as reader:
        assert reader.unpack(folder) == len(reader.index.manifest.chunks)
        manifest = reader.index.manifest
    assert sorted(p.name for p in (folder / "chunks").iterdir()) == [
        Path(c.file).name for c in manifest.chunks
    ]
    raw = (folder / MANIFEST).read_bytes()
    assert hashlib.sha256(raw).digest() == header_of(small.read_bytes()).index_sha256
    assert parse_manifest(raw) == manifest
    out = tmp_path / "packed.tsogs"
    assert pack(folder, out) == small.stat().st_size
    assert out.read_bytes() == small.read_bytes()
    with (
        open_stream(small) as reader,
        pytest.raises(SourceError, match="already exists"),
    ):
        reader.unpack(folder)


def test_packing_the_16_kib_prefix_layout_gives_the_compact_file(
    small: Path, compact: Path, tmp_path: Path
) -> None:
    """Files written before compact containers pack (unpacked and packed again) to the file
    the writer makes today."""
    with open_stream(small) as reader:
        reader.unpack(tmp_path / "unpacked")
    pack(tmp_path / "unpacked", tmp_path / "packed.tsogs")
    assert (tmp_path / "packed.tsogs").read_bytes() == compact.read_bytes()


@pytest.fixture
def unpacked(small: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "unpacked"
    with open_stream(small) as reader:
        reader.unpack(folder)
    return folder


def test_pack_refuses_an_edited_manifest(unpacked: Path, tmp_path: Path) -> None:
    doc = json.loads((unpacked / MANIFEST).read_bytes())
    chunks = doc["chunks"]
    i, j = next(
        (a, b)
        for a in range(len(chunks))
        for b in range(a + 1, len(chunks))
        if chunks[a]["length"] != chunks[b]["length"]
    )
    chunks[i]["offset"], chunks[j]["offset"] = chunks[j]["offset"], chunks[i]["offset"]
    (unpacked / MANIFEST).write_text(json.dumps(doc))
    out = tmp_path / "x.tsogs"
    with pytest.raises(IntegrityError, match="manifest was edited"):
        pack(unpacked, out)
    assert not out.exists() and not list(tmp_path.glob(".*.tmp"))


def test_pack_refuses_a_tampered_chunk(unpacked: Path, tmp_path: Path) -> None:
    chunk = unpacked / "chunks" / "000001.sog"
    chunk.write_bytes(flip(chunk.read_bytes(), 100))
    with pytest.raises(IntegrityError, match="SHA-256"):
        pack(unpacked, tmp_path / "x.tsogs")
    chunk.unlink()
    with pytest.raises(SourceError):
        pack(unpacked, tmp_path / "x.tsogs")
    (unpacked / MANIFEST).unlink()
    with pytest.raises(SourceError, match=r"manifest\.json"):
        pack(unpacked, tmp_path / "x.tsogs")
    assert not (tmp_path / "x.tsogs").exists()


# --- command line --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def hanabi(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "hanabi.tsogs"
    args = ["segment", str(samples / HANABI), "--window", "0.25s", "--policy", "hybrid"]
    args += ["-o", str(out)]
    assert main([*args, "--workers", "1", "-q"]) == 0
    return out


def test_cli_segment_and_info(hanabi: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["info", str(hanabi), "--json", "-q"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "tsogs" and info["bytes"] == hanabi.stat().st_size
    assert info["window_s"] == 0.25 and info["policy"] == "hybrid"
    assert info["index"]["offset"] == HEADER_SIZE
    assert info["chunks"] >= 4 and info["scene"]["timeline_type"] == 2
    costs = info["seek_costs"]
    assert len(costs) == 8 and costs[0]["t"] == 0.0 and costs[-1]["t"] == info["scene"]["end_s"]
    for row in costs:
        assert 1 <= row["requests"] <= row["chunks"]
        assert 0 < row["bytes"] < info["bytes"] and row["visible"] > 0
    assert main(["info", str(hanabi), "-q"]) == 0
    assert "seek costs:" in capsys.readouterr().out


def test_cli_verify_then_corrupt(
    hanabi: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["verify", str(hanabi), "-q"]) == 0
    assert "OK" in capsys.readouterr().out
    with open_stream(hanabi) as reader:
        chunk = reader.index.manifest.chunks[2]
    bad = tmp_path / "bad.tsogs"
    bad.write_bytes(flip(hanabi.read_bytes(), chunk.offset + 1000))
    assert main(["verify", str(bad), "-q"]) == 3
    out = capsys.readouterr().out
    assert f"chunk {chunk.id}: hash" in out and "1 problem(s)" in out


def test_cli_frame_reads_only_what_t_needs(
    hanabi: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "f.ply"
    capsys.readouterr()
    assert main(["frame", str(hanabi), "--t", "0.6", "-o", str(out), "-v", "-q"]) == 0
    streams = capsys.readouterr()
    read = int(streams.err.split("read ")[1].split(" bytes")[0])
    assert 0 < read < hanabi.stat().st_size // 2
    frame = read_ply(out).gaussians
    with open_stream(hanabi) as reader:
        expected = reader.frame_at(0.6)
        needed = reader.index.chunks_for(0.6)
    assert f"{len(expected)} Gaussians visible" in streams.out
    assert read == PREFIX_SIZE + sum(c.length for c in needed)
    np.testing.assert_allclose(frame.means, expected.means, rtol=1e-6)


def test_cli_frame_of_a_stream_writes_a_static_sog(hanabi: Path, tmp_path: Path) -> None:
    out = tmp_path / "f.sog"
    assert main(["frame", str(hanabi), "--t", "0.6", "-o", str(out), "-q"]) == 0
    with open_stream(hanabi) as reader:
        expected = reader.frame_at(0.6)
    files = read_bundle(out.read_bytes())
    meta = json.loads(files["meta.json"])
    assert "timeline" not in meta and meta["count"] == len(expected)
    got = read_chunk(out)
    assert got.timeline is None
    # Texel order differs (Morton order of the frame): compare position sets, sorted.
    step = means_log_step(meta["means"]["mins"], meta["means"]["maxs"]).max()
    a, b = (np.sort(log_transform(g.means), axis=0) for g in (got.gaussians, expected))
    assert np.abs(a - b).max() <= step


def test_cli_extract_gives_the_byte_range_as_a_sog(
    hanabi: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "c.sog"
    assert main(["extract", str(hanabi), "1", "-o", str(out), "-q"]) == 0
    with open_stream(hanabi) as reader:
        chunk = reader.index.manifest.chunks[1]
        decoded = reader.chunk_scene(1)
    data = out.read_bytes()
    assert data == hanabi.read_bytes()[chunk.offset : chunk.offset + chunk.length]
    assert "meta.json" in read_bundle(data)
    scene = read_chunk(out)
    assert len(scene) == chunk.count and scene.timeline is not None
    np.testing.assert_array_equal(scene.gaussians.means, decoded.gaussians.means)
    assert main(["extract", str(hanabi), "99", "-o", str(tmp_path / "n.sog"), "-q"]) == 1
    assert "no chunk 99" in capsys.readouterr().err


def test_cli_unpack_pack_round_trip(
    hanabi: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "u"
    assert main(["unpack", str(hanabi), "-o", str(folder), "-q"]) == 0
    assert main(["pack", str(folder), "-o", str(tmp_path / "p.tsogs"), "-q"]) == 0
    assert (tmp_path / "p.tsogs").read_bytes() == hanabi.read_bytes()
    assert main(["pack", str(folder), "-o", str(tmp_path / "p.tsogs"), "-q"]) == 1
    assert "already exists" in capsys.readouterr().err


def test_cli_segments_a_frame_folder(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fw.tsogs"
    folder = samples / FIREWORKS
    args = ["segment", str(folder), "--fps", "6", "--window", "2f", "-o", str(out)]
    assert main([*args, "--workers", "1", "-q"]) == 0
    assert "3 windows" in capsys.readouterr().out
    source = read_ply_sequence(folder, fps=6.0).scene
    with open_stream(out) as reader:
        assert reader.index.manifest.window_s == pytest.approx(2 / 6)
        for k in range(6):
            t = k / 6
            frame = reader.frame_at(t)
            expected = source.at(t)
            assert len(frame) == len(expected), f"frame {k}"
            assert len(reader.index.chunks_for(t)) == 1
            np.testing.assert_allclose(
                np.sort(frame.means, axis=0), np.sort(expected.means, axis=0), atol=2e-3
            )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["verify", "{tmp}/missing.tsogs"], "missing.tsogs"),
        (["frame", "{tmp}/missing.tsogs", "--t", "0", "-o", "{tmp}/f.ply"], "missing.tsogs"),
        (["segment", "{hanabi_src}", "--window", "3f", "-o", "{tmp}/x.tsogs"], "frame rate"),
        (["segment", "{hanabi_src}", "--window", "soon", "-o", "{tmp}/x.tsogs"], "--window"),
        (["extract", "{bad}", "0", "-o", "{tmp}/c.sog"], "not a .tsogs container"),
    ],
)
def test_cli_errors_are_one_friendly_line(
    args: list[str],
    message: str,
    samples: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bad = tmp_path / "bad.tsogs"
    bad.write_bytes(b"\x00" * 200)
    fields = {"tmp": tmp_path, "hanabi_src": samples / HANABI, "bad": bad}
    capsys.readouterr()
    assert main([a.format(**fields) for a in args] + ["-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if not line.startswith(("tsog: note:", "tsog: warning:"))]
    assert len(errors) == 1 and errors[0].startswith("tsog: error:"), err
    assert message in errors[0] and err[-1] == errors[0]
    assert not (tmp_path / "x.tsogs").exists()


# --- interop -------------------------------------------------------------------------------


@pytest.mark.interop
def test_reference_tool_reads_an_extracted_chunk_as_a_plain_sog(
    hanabi: Path, splat_transform: Path, tmp_path: Path
) -> None:
    with open_stream(hanabi) as reader:
        chunk = reader.index.manifest.chunks[0]
        ours = reader.chunk_scene(chunk.id)
    sog = tmp_path / "chunk.sog"
    with hanabi.open("rb") as f:
        f.seek(chunk.offset)
        sog.write_bytes(f.read(chunk.length))
    run_tool(splat_transform, sog, tmp_path / "base.ply")
    theirs = read_ply(tmp_path / "base.ply").gaussians
    assert len(theirs) == chunk.count
    assert_same_gaussians(ours.gaussians, theirs)

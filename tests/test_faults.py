"""Faults on disk and on the server side of a live client (issue 6, "Faults").

- A single flipped byte anywhere in a container is caught by ``tsog verify``, by the reader and
  by the HTTP client, except in the bytes that carry no data (docs/spec.md §8.6), where it is
  proven harmless.
- A container replaced on the server while a client plays is noticed through the ETag: the
  client stops with a SourceError and never mixes chunks of two versions; reopening gives the
  new version. Process-level faults (server killed, segmenter interrupted) are in
  tests/test_faults_process.py.
"""

from __future__ import annotations

import asyncio
import io
import os
import shutil
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from helpers import ThreadedServer
from tsog_stream import TimelineType
from tsog_stream.cli.main import main
from tsog_stream.client import StreamClient, open_stream
from tsog_stream.client.http_options import HttpOptions
from tsog_stream.client.verify import RESERVED_START
from tsog_stream.container import writer
from tsog_stream.container.header import HEADER_SIZE, PREFIX_SIZE
from tsog_stream.container.sources import MemorySource, read_index
from tsog_stream.errors import FormatError, IntegrityError, SourceError, TsogError
from tsog_stream.model import Gaussians
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.server.catalog import Catalog
from tsog_stream.synthetic import small_scene

FAST = HttpOptions(retries=1, backoff_s=0.01)
HARMLESS = ("minor_version", "optional_flags", "reserved", "padding")
"""Regions whose bytes no reader acts on (docs/spec.md §8.6)."""
TIMES = (0.25, 0.75, 1.25, 1.75)


def _segment(path: Path, seed: int, *, compact: bool = False) -> Path:
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0, dynamic=("means",), seed=seed)
    with pytest.MonkeyPatch.context() as patch:
        if not compact:
            patch.setattr(writer, "COMPACT_MAX", 0)
        segment_scene(scene, path, SegmentOptions(window_s=1.0, policy="duplicate"))
    return path


@pytest.fixture(scope="module")
def versions(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two different containers of the same shape (versions A and B of one scene), with
    their payloads after the 16 KiB prefix: every region of spec §8.6, padding included."""
    folder = tmp_path_factory.mktemp("faults")
    return _segment(folder / "a.tsogs", 0), _segment(folder / "b.tsogs", 1)


@pytest.fixture(scope="module")
def compact(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Version A as the writer makes it by default: compact, payloads right after the index."""
    return _segment(tmp_path_factory.mktemp("faults") / "compact.tsogs", 0, compact=True)


def same(a: Gaussians, b: Gaussians) -> bool:
    names = ("means", "scales", "quats", "opacities", "sh0", "shN")
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names)


def local_frames(path: Path, times: tuple[float, ...] = TIMES) -> list[Gaussians]:
    with open_stream(path) as reader:
        return [reader.frame_at(t) for t in times]


# ---------------------------------------------------------------- flipped bytes


def _spread(start: int, end: int, count: int) -> list[int]:
    """``count`` offsets evenly spread over [start, end), both ends included."""
    return sorted({int(x) for x in np.linspace(start, end - 1, min(count, end - start))})


def _chunk_offsets(data: bytes, offset: int) -> dict[str, list[int]]:
    """Offsets in one chunk's zip: local headers, member data, meta.json, central directory."""
    z = zipfile.ZipFile(io.BytesIO(data))
    zip_headers, images, meta = [], [], []
    for info in z.infolist():
        base = offset + info.header_offset
        data_start = base + 30 + len(info.filename.encode()) + len(info.extra)
        zip_headers += [base, base + 14, base + 26]
        data_end = data_start + info.compress_size
        if info.filename == "meta.json":
            meta += _spread(data_start, data_end, 6)
        else:
            images += _spread(data_start, data_end, 2)
    end = offset + len(data)
    directory = [*_spread(offset + z.start_dir, end - 22, 6), end - 22, end - 12, end - 1]
    return {"zip_headers": zip_headers, "images": images, "meta": meta, "directory": directory}


def flip_offsets(path: Path) -> dict[str, list[int]]:
    """~160 offsets chosen deterministically to cover every region of the container."""
    data = path.read_bytes()
    with open_stream(path) as reader:
        index = reader.index
    h = index.header
    index_end = h.index_offset + h.index_length
    first = min(c.offset for c in index.manifest.chunks)
    assert h.index_offset == HEADER_SIZE and index_end < PREFIX_SIZE
    regions = {
        "header": [0, 5, 7, 8, 9, 12, 15, 20, 24, 31, 32, 39, 40, 47, 48, 55, 56, 70, 87],
        "minor_version": [10, 11],
        "optional_flags": [16, 19],
        "reserved": [RESERVED_START, 100, HEADER_SIZE - 1],
        "index": _spread(h.index_offset, index_end, 30),
        "padding": sorted(
            {index_end, index_end + 1, (index_end + first) // 2, first - 1}
            & set(range(index_end, first))
        ),
    }
    for c in index.manifest.chunks:
        for name, offsets in _chunk_offsets(data[c.offset : c.offset + c.length], c.offset).items():
            regions[f"chunk{c.id}_{name}"] = offsets
    return regions


def flipped(data: bytes, offset: int) -> bytes:
    """``data`` with the byte at ``offset`` changed (all bits or the lowest, alternately)."""
    out = bytearray(data)
    out[offset] ^= 0xFF if offset % 2 else 0x01
    return bytes(out)


async def _reader_detects(data: bytes) -> bool:
    """Whether opening or reading any chunk raises IntegrityError / FormatError."""
    source = MemorySource(data)
    try:
        index = await read_index(source)
        client = StreamClient(source, index)
        for c in index.manifest.chunks:
            await client.chunk_bytes(c.id)
    except (IntegrityError, FormatError):
        return True
    return False


def test_flip_offsets_cover_every_region(versions: tuple[Path, Path]) -> None:
    regions = flip_offsets(versions[0])
    total = sum(len(v) for v in regions.values())
    assert 120 <= total <= 220
    for name, offsets in regions.items():
        assert offsets, name
    assert {"chunk0_meta", "chunk1_images", "chunk1_zip_headers", "chunk0_directory"} <= set(
        regions
    )


def test_a_compact_container_detects_any_flipped_byte(compact: Path) -> None:
    """The same damage in a compact container (chunks right after the index) is caught the
    same way; a flip in the few zero bytes between index and payloads is harmless."""
    data = compact.read_bytes()
    regions = flip_offsets(compact)
    assert min(regions["chunk0_zip_headers"]) < PREFIX_SIZE
    missed = _undetected(data, regions)
    assert len(missed) <= 3 and {name for name, _ in missed} <= {"index"}
    expected = local_frames(compact)
    for off in regions["padding"]:
        target = compact.with_name("padding.tsogs")
        target.write_bytes(flipped(data, off))
        assert all(same(a, b) for a, b in zip(local_frames(target), expected, strict=True))


def _undetected(data: bytes, regions: dict[str, list[int]]) -> list[tuple[str, int]]:
    """(region, offset) of the flips the reader does not detect."""
    return [
        (name, off)
        for name, offsets in regions.items()
        if name not in HARMLESS
        for off in offsets
        if not asyncio.run(_reader_detects(flipped(data, off)))
    ]


def test_the_reader_detects_any_flipped_byte(versions: tuple[Path, Path], tmp_path: Path) -> None:
    data = versions[0].read_bytes()
    missed = _undetected(data, flip_offsets(versions[0]))
    # A zstd frame has a few "don't care" bits (entropy-coder padding): a flip there still
    # decompresses to the very JSON the header's SHA-256 covers, so the reader sees the same
    # index and shows the same frames (docs/spec.md §8.6).
    assert len(missed) <= 3 and {name for name, _ in missed} <= {"index"}
    with open_stream(versions[0]) as reader:
        manifest = reader.index.manifest
    expected = local_frames(versions[0])
    for _, off in missed:
        target = tmp_path / "same.tsogs"
        target.write_bytes(flipped(data, off))
        with open_stream(target) as reader:
            assert reader.index.manifest == manifest
        assert all(same(a, b) for a, b in zip(local_frames(target), expected, strict=True))


def test_verify_detects_any_flipped_byte(
    versions: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = versions[0].read_bytes()
    regions = flip_offsets(versions[0])
    same_index = set(_undetected(data, regions))
    codes: dict[str, set[int]] = {}
    for name, offsets in regions.items():
        for off in offsets:
            if (name, off) in same_index:
                continue
            target = tmp_path / "flip.tsogs"
            target.write_bytes(flipped(data, off))
            codes.setdefault(name, set()).add(main(["verify", str(target), "-q"]))
    capsys.readouterr()
    for name, found in codes.items():
        if name in ("minor_version", "optional_flags"):
            assert found == {0}, name  # any value is valid (spec §8.1): nothing to detect
        elif name in ("reserved", "padding"):
            assert found == {6}, name  # reported as damage although harmless to readers
        else:
            assert 0 not in found, name
    assert codes["chunk0_images"] == {3} and codes["chunk1_meta"] == {3}  # hash


def test_flips_in_bytes_without_data_are_harmless(
    versions: tuple[Path, Path], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    data = versions[0].read_bytes()
    expected = local_frames(versions[0])
    regions = flip_offsets(versions[0])
    with open_stream(versions[0]) as reader:
        identity = reader.index.identity
    for name in HARMLESS:
        for off in regions[name]:
            target = tmp_path / "harmless.tsogs"
            target.write_bytes(flipped(data, off))
            with open_stream(target) as reader:
                assert reader.index.identity == identity
                frames = [reader.frame_at(t) for t in TIMES]
            assert all(same(a, b) for a, b in zip(frames, expected, strict=True)), (name, off)
    main(["verify", str(target), "-q"])
    assert "container: index: non-zero padding byte" in capsys.readouterr().out


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[Path, str]]:
    """A server on a fresh root: yields (root, base URL of /files/)."""
    root = tmp_path / "root"
    root.mkdir()
    server = ThreadedServer(make_app(root))
    try:
        yield root, f"http://127.0.0.1:{server.port}/files/"
    finally:
        server.stop()


def _chunk_times(path: Path) -> dict[int, float]:
    """A time at which each chunk is needed."""
    with open_stream(path) as reader:
        return {c.id: (c.start_s + c.end_s) / 2 for c in reader.index.manifest.chunks}


def test_the_client_detects_any_flipped_byte(
    versions: tuple[Path, Path], served: tuple[Path, str]
) -> None:
    root, base = served
    data = versions[0].read_bytes()
    times = _chunk_times(versions[0])
    cases = []
    for name, offsets in flip_offsets(versions[0]).items():
        if name in HARMLESS:
            continue
        for off in offsets[::2]:  # every other offset keeps the test short
            (root / f"f{off}.tsogs").write_bytes(flipped(data, off))
            chunk = int(name[5]) if name.startswith("chunk") else None
            cases.append((name, off, chunk))

    async def outcome(off: int, chunk: int | None) -> str:
        try:
            async with await StreamClient.open(base + f"f{off}.tsogs", http=FAST) as client:
                for t in [times[chunk]] if chunk is not None else list(times.values()):
                    await client.frame_at(t)
        except (IntegrityError, FormatError) as exc:
            return type(exc).__name__
        return "missed"

    async def run() -> list[tuple[str, int, str]]:
        return [(name, off, await outcome(off, chunk)) for name, off, chunk in cases]

    results = asyncio.run(run())
    assert len(results) > 60
    assert not [r for r in results if r[2] == "missed"]
    assert {r[2] for r in results if r[0].startswith("chunk")} == {"IntegrityError"}


# ---------------------------------------------------------------- replaced while playing


def _replace(src: Path, dest: Path) -> None:
    """Atomically put a copy of ``src`` at ``dest`` (temp file + rename, as deploys do)."""
    tmp = dest.with_name(f".{dest.name}.new")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dest)


def test_a_replaced_container_stops_the_client_then_reopens_cleanly(
    versions: tuple[Path, Path], served: tuple[Path, str]
) -> None:
    a, b = versions
    root, base = served
    shutil.copyfile(a, root / "scene.tsogs")
    url = base + "scene.tsogs"
    frames_a, frames_b = local_frames(a), local_frames(b)

    async def run() -> tuple[list[Gaussians], str, list[Gaussians]]:
        got = []
        async with await StreamClient.open(url, http=FAST, coalesce_gap=None) as client:
            got.append(await client.frame_at(TIMES[0]))
            _replace(b, root / "scene.tsogs")
            got.append(await client.frame_at(TIMES[1]))  # chunk 0: cached, still version A
            with pytest.raises(SourceError) as err:
                await client.frame_at(TIMES[2])  # chunk 1 is fetched: If-Match -> 412
        async with await StreamClient.open(url, http=FAST) as client:
            reopened = [await client.frame_at(t) for t in TIMES]
        return got, str(err.value), reopened

    got, message, reopened = asyncio.run(run())
    assert all(same(x, y) for x, y in zip(got, frames_a[:2], strict=True))
    assert "the file changed on the server" in message and "scene.tsogs" in message
    assert all(same(x, y) for x, y in zip(reopened, frames_b, strict=True))
    assert not any(same(x, y) for x, y in zip(reopened, frames_a, strict=True))


def test_a_replaced_container_during_playback_never_mixes_versions(
    versions: tuple[Path, Path], served: tuple[Path, str]
) -> None:
    a, b = versions
    root, base = served
    shutil.copyfile(a, root / "scene.tsogs")
    frames_a = local_frames(a, tuple(k / 10 for k in range(20)))

    async def run() -> tuple[list[Gaussians], BaseException | None]:
        played: list[Gaussians] = []
        async with await StreamClient.open(
            base + "scene.tsogs", http=FAST, coalesce_gap=None, cache_bytes=0
        ) as client:
            try:
                async for frame in client.play(0.0, fps=10, duration=1.9, horizon_s=0.2):
                    played.append(frame.gaussians)
                    if frame.index == 3:
                        _replace(b, root / "scene.tsogs")
            except TsogError as exc:
                return played, exc
        return played, None

    played, error = asyncio.run(run())
    assert isinstance(error, SourceError) and "changed on the server" in str(error)
    assert 4 <= len(played) < 20
    assert all(same(x, y) for x, y in zip(played, frames_a, strict=False))


def test_a_replaced_unpacked_layout_is_caught_by_chunk_hashes(
    versions: tuple[Path, Path], served: tuple[Path, str], tmp_path: Path
) -> None:
    a, b = versions
    root, base = served
    for name, src in (("u", a), ("next", b)):
        with open_stream(src) as reader:
            reader.unpack(root / name)
    frame_a = local_frames(a, (TIMES[0],))[0]

    async def run() -> tuple[Gaussians, BaseException]:
        async with await StreamClient.open(base + "u/", http=FAST) as client:
            first = await client.frame_at(TIMES[0])
            os.replace(root / "u", tmp_path / "old")
            os.replace(root / "next", root / "u")
            with pytest.raises((IntegrityError, SourceError)) as err:
                await client.frame_at(TIMES[2])  # a new chunk: wrong length or wrong hash
        return first, err.value

    first, error = asyncio.run(run())
    assert same(first, frame_a)
    assert "000001.sog" in str(error) or "chunk 1 does not match its SHA-256" in str(error)


def test_a_same_size_copy_with_a_preserved_mtime_gets_a_new_etag(tmp_path: Path) -> None:
    """rsync -t / cp -p keep mtime: the server must still see the new content (inode, ctime)."""
    catalog = Catalog(tmp_path)
    target = tmp_path / "data.bin"
    target.write_bytes(b"a" * 4096)
    stamp = target.stat().st_mtime_ns
    first = asyncio.run(catalog.file("data.bin")).etag
    replacement = tmp_path / "incoming.bin"
    replacement.write_bytes(b"b" * 4096)
    os.utime(replacement, ns=(stamp, stamp))
    os.replace(replacement, target)
    assert target.stat().st_mtime_ns == stamp and target.stat().st_size == 4096
    second = asyncio.run(catalog.file("data.bin")).etag
    assert second != first

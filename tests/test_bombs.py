"""Decompression bombs, as a class: small files that would make a reader inflate or allocate
gigabytes are refused (or their hostile part skipped) before the memory is taken, with a
tracemalloc peak to prove it; the read budget is documented and configurable."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import struct
import tracemalloc
import zipfile
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path

import pytest
from PIL import Image
from pydantic import TypeAdapter

from tsog_stream import SogError, TimelineType, decode_chunk, encode_chunk
from tsog_stream.cli.main import main
from tsog_stream.client.verify import Check, check_chunk
from tsog_stream.codec import webp
from tsog_stream.codec.bundle import bundle_bytes, read_bundle, unnamed_entries
from tsog_stream.constants import (
    DEFAULT_MAX_PIXELS,
    MAX_CAMERA_FILE_BYTES,
    MAX_CAMERAS,
    MAX_PIXELS_ENV,
    pixel_budget,
)
from tsog_stream.errors import FormatError, TsogError
from tsog_stream.io import cameras
from tsog_stream.io.cameras import MAX_CAMERAS_JSON_BYTES, read_cameras
from tsog_stream.io.chunks import read_chunk, read_chunk_files
from tsog_stream.schemas.manifest import ChunkEntry
from tsog_stream.synthetic import small_scene

MiB = 1 << 20
BOMB = 512 * MiB
"""Bytes the hostile member inflates to: far over what the checks below allow a reader."""


@pytest.fixture(scope="module")
def files() -> dict[str, bytes]:
    """An honest chunk's files."""
    return encode_chunk(small_scene(TimelineType.CENTER_SCALE, sh_bands=0))


def with_extra_member(files: dict[str, bytes]) -> bytes:
    """The bundled chunk plus a deflated member of BOMB zero bytes that meta.json never names
    (a few hundred KiB in the archive)."""
    out = io.BytesIO(bundle_bytes(files))
    with (
        zipfile.ZipFile(out, "a", zipfile.ZIP_DEFLATED) as archive,
        archive.open("padding.bin", "w", force_zip64=True) as member,
    ):
        block = bytes(MiB)
        for _ in range(BOMB // MiB):
            member.write(block)
    return out.getvalue()


def peak_of(work: Callable[[], object]) -> tuple[object, int]:
    """What ``work()`` returns (or raises) and the peak of Python allocations meanwhile."""
    tracemalloc.start()
    try:
        try:
            result: object = work()
        except TsogError as exc:
            result = exc
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def bomb(files: dict[str, bytes]) -> bytes:
    data = with_extra_member(files)
    assert len(data) < 4 * MiB
    return data


def test_an_entry_meta_json_never_names_is_never_inflated(
    files: dict[str, bytes], bomb: bytes
) -> None:
    read, peak = peak_of(lambda: read_bundle(bomb, where="bomb.sog"))
    assert isinstance(read, dict) and set(read) == set(files)
    assert peak < 32 * MiB  # the 512 MiB member was not read
    assert len(decode_chunk(read, where="bomb.sog")) == len(decode_chunk(files))
    assert unnamed_entries(bomb) == ["padding.bin"]


def test_verify_reports_an_unnamed_entry(files: dict[str, bytes], bomb: bytes) -> None:
    """A chunk whose hash is consistent still shows its unnamed entry to ``tsog verify``."""
    entry = TypeAdapter(ChunkEntry).validate_python(
        {
            "id": 0,
            "level": 0,
            "node": 0,
            "file": "chunks/000000.sog",
            "offset": 16384,
            "length": len(bomb),
            "sha256": hashlib.sha256(bomb).hexdigest(),
            "count": len(decode_chunk(files)),
            "start_s": 0.0,
            "end_s": 10.0,
            "bbox": {"min": [-9, -9, -9], "max": [9, 9, 9]},
        }
    )
    found, peak = peak_of(lambda: check_chunk(entry, bomb, DEFAULT_MAX_PIXELS, "bomb"))
    assert isinstance(found, list) and peak < 32 * MiB
    assert [kind for kind, _ in found] == [Check.DECODE]
    assert "padding.bin" in found[0][1] and "not named by meta.json" in found[0][1]


@pytest.fixture
def budget(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[int], None]]:
    """Sets the read budget through its environment variable."""

    def set_budget(pixels: int) -> None:
        monkeypatch.setenv(MAX_PIXELS_ENV, str(pixels))

    yield set_budget


def test_the_read_budget_defaults_to_the_segmenters_and_is_configurable(
    budget: Callable[[int], None], files: dict[str, bytes]
) -> None:
    assert pixel_budget() == DEFAULT_MAX_PIXELS == 4096 * 4096
    meta = json.loads(files["meta.json"])
    budget(meta["count"] - 1)  # fewer pixels than Gaussians: refused before decoding
    with pytest.raises(SogError, match=f"over the read budget of {meta['count'] - 1}"):
        decode_chunk(files)
    budget(meta["count"] + 1)  # the count fits, the padded images do not
    with pytest.raises(SogError, match=r"image of \d+x\d+ = \d+ pixels, over the read budget"):
        decode_chunk(files)
    budget(10 * meta["count"])
    assert len(decode_chunk(files)) == meta["count"]


def test_a_huge_declared_count_is_refused_before_any_allocation(files: dict[str, bytes]) -> None:
    """The issue's bomb: a tiny chunk declaring 36 M Gaussians (one pixel each)."""
    meta = json.loads(files["meta.json"])
    meta["count"] = 36_000_000
    forged = {**files, "meta.json": json.dumps(meta).encode()}
    error, peak = peak_of(lambda: decode_chunk(forged, where="forged.sog"))
    assert isinstance(error, SogError) and peak < 8 * MiB
    assert "36000000 Gaussians, over the read budget" in str(error)


def test_cli_info_on_a_bomb_is_one_line_and_bounded(
    bomb: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bomb.sog"
    path.write_bytes(bomb)
    result, peak = peak_of(lambda: main(["info", str(path), "-q"]))
    assert result == 0 and peak < 64 * MiB
    assert "Traceback" not in capsys.readouterr().err


# --- every member of a bundle inflates within what its meta.json allows -------------------

MEMBER_BOMB = 32 * MiB
"""Zero bytes a forged member inflates to: far over any budget below, cheap to deflate."""
REFUSAL_PEAK = 4 * MiB
"""Python allocations a refusal may cost: a member inflated whole would show MEMBER_BOMB."""


def deflated_bundle(files: dict[str, bytes], name: str, padding: int) -> bytes:
    """``files`` as a zip whose member ``name`` is deflated with ``padding`` zero bytes
    after its own."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for member, data in files.items():
            info = zipfile.ZipInfo(member, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED if member == name else zipfile.ZIP_STORED
            archive.writestr(info, data + bytes(padding) if member == name else data)
    return out.getvalue()


def declaring(archive: bytes, name: str, size: int) -> bytes:
    """``archive`` whose central directory says member ``name`` inflates to ``size`` bytes
    (what zipfile reads; a lie when it is not)."""
    forged = bytearray(archive)
    at = 0
    while True:
        at = forged.index(b"PK\x01\x02", at)
        length = int.from_bytes(forged[at + 28 : at + 30], "little")
        if forged[at + 46 : at + 46 + length] == name.encode():
            forged[at + 24 : at + 28] = size.to_bytes(4, "little")
            return bytes(forged)
        at += 4


def many_gaussians_meta(files: dict[str, bytes], count: int) -> dict[str, bytes]:
    """``files`` with a meta.json declaring ``count`` Gaussians (a larger image budget)."""
    meta = json.loads(files["meta.json"])
    meta["count"] = count
    return {**files, "meta.json": json.dumps(meta).encode()}


MEMBER_SHAPES: dict[str, tuple[str, str, str]] = {
    "image, sizes told": ("means_l.webp", "told", "more than the .* a WebP of the image size"),
    "image, size lies small": ("means_l.webp", "small", "damaged entry: Bad CRC-32"),
    "image, size lies within budget": ("sh0.webp", "budget", "damaged entry: Bad CRC-32"),
    "meta.json, sizes told": ("meta.json", "told", "more than the 4194304 a meta.json may hold"),
    "meta.json, size lies small": ("meta.json", "small", "damaged entry: Bad CRC-32"),
    "image, within a 60000-Gaussian budget, deflated 1000:1": (
        "quats.webp",
        "ratio",
        r"more than the \d+ a WebP of \d+ deflated bytes may inflate to",
    ),
}
"""A member of a bundle inflating past what it may hold, with its sizes told or forged:
(member, shape, the refusal it gets)."""


@pytest.mark.parametrize("shape", list(MEMBER_SHAPES))
def test_a_member_inflating_past_its_budget_is_refused_without_inflating_it(
    files: dict[str, bytes], shape: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The issue's bomb (a named image inflating 1000x) as a class: whatever sizes the zip
    declares, no member is inflated past its cap (from meta.json's count, or its deflated
    size for an image, or the meta.json bound), and the refusal names the member, in the
    library and in one line of every command that reads a chunk."""
    name, how, refusal = MEMBER_SHAPES[shape]
    honest = many_gaussians_meta(files, 60000) if how == "ratio" else files
    padding = 1 * MiB if how == "ratio" else MEMBER_BOMB
    data = deflated_bundle(honest, name, padding)
    lie = {"small": len(files[name]), "budget": 64 << 10}.get(how)  # else the true size
    if lie is not None:
        data = declaring(data, name, lie)
    error, peak = peak_of(lambda: read_bundle(data, where="bomb.sog"))
    assert isinstance(error, SogError) and peak < REFUSAL_PEAK, (error, peak)
    assert error.where == f"bomb.sog/{name}" and re.search(refusal, error.message)
    path = tmp_path / "bomb.sog"
    path.write_bytes(data)
    for command in (["info"], ["decode", str(tmp_path / "o.ply")], ["frame", "--t", "0"]):
        argv = [command[0], str(path), *command[1:]]
        if command[0] == "frame":
            argv += ["-o", str(tmp_path / "f.ply")]
        code, peak = peak_of(partial(main, [*argv, "-q"]))
        err = capsys.readouterr().err
        assert code == 1 and peak < REFUSAL_PEAK, (command, peak)
        assert err.startswith(f"tsog: error: {path}/{name}: ") and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bomb.sog"]


@pytest.mark.parametrize("name", ["meta.json", "means_l.webp", "sh0.webp"])
def test_an_unbundled_file_over_its_budget_is_refused_unread(
    files: dict[str, bytes], name: str, tmp_path: Path
) -> None:
    """A chunk folder's meta.json or image larger than a bundle's member may inflate to (a
    sparse 512 MiB file here) is refused by its size, before a byte of it is read."""
    for member, data in files.items():
        (tmp_path / member).write_bytes(data)
    os.truncate(tmp_path / name, BOMB)
    error, peak = peak_of(lambda: read_chunk(tmp_path))
    assert isinstance(error, SogError) and peak < 1 * MiB, (error, peak)
    assert error.where == str(tmp_path / name)
    may_hold = r"a (meta.json|WebP of the image size meta.json implies) may hold"
    assert re.fullmatch(rf"{BOMB} bytes, more than the \d+ {may_hold}", error.message)


def test_an_honest_chunk_is_within_every_budget(files: dict[str, bytes], tmp_path: Path) -> None:
    """Negative control: the same chunk, bundled stored or deflated, or unbundled, reads."""
    expected = decode_chunk(files)
    for member, data in files.items():
        (tmp_path / member).write_bytes(data)
    for read in (
        read_bundle(bundle_bytes(files)),
        read_bundle(deflated_bundle(files, "means_l.webp", 0)),
        read_chunk_files(tmp_path),
    ):
        assert len(decode_chunk(read)) == len(expected)


# --- every WebP header is checked before libwebp or Pillow sees it ------------------------

WEBP_SHAPES: dict[str, tuple[str, str]] = {
    "VP8X canvas 60000 px": ("sog-image-60000px.sog", "exceeds the WebP limit of 16383 px"),
    "VP8X canvas, no image": ("sog-webp-vp8x-no-image.sog", "VP8X file without a VP8 or VP8L"),
    "VP8X canvas over a smaller image": (
        "sog-webp-vp8x-canvas-4096-image-4.sog",
        "VP8X canvas of 4096x4096 holds a 4x4 image",
    ),
    "VP8X animated": ("sog-webp-vp8x-animated.sog", "animated WebP"),
    "VP8L huge": ("sog-images-16383px-for-16.sog", "expected at most 4128 texels"),
    "VP8 huge": ("sog-webp-vp8-16383px.sog", "expected at most 4128 texels"),
    "canvas not the one meta implies": ("sog-webp-sizes-differ.sog", "expected 4x4 like"),
    "RIFF truncated": ("sog-webp-truncated.sog", "RIFF size says 38 bytes, past its end"),
    "RIFF size lies long": ("sog-webp-riff-size-1gib.sog", "RIFF size says 1073741832 bytes"),
    "RIFF size lies short": ("sog-webp-riff-size-short.sog", "16 bytes before its end"),
    "chunk past the end": ("sog-webp-chunk-past-end.sog", "ends past the file"),
}
"""Hostile WebP headers (corpus files of tests/data/invalid/) and what refuses them."""
INVALID = Path(__file__).parent / "data" / "invalid"


@pytest.mark.parametrize("shape", list(WEBP_SHAPES))
@pytest.mark.parametrize("command", ["info", "decode", "frame"])
def test_every_command_refuses_a_hostile_webp_header_in_one_line(
    shape: str, command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tsog info`` (it showed Pillow's DecompressionBombError traceback), decode and frame
    check each image's header against the size meta.json implies before decoding it."""
    corpus, refusal = WEBP_SHAPES[shape]
    out = str(tmp_path / "o.ply")
    argv = {"info": [], "decode": [out], "frame": ["--t", "0", "-o", out]}
    code, peak = peak_of(lambda: main([command, str(INVALID / corpus), *argv[command], "-q"]))
    err = capsys.readouterr().err
    assert code == 1 and peak < REFUSAL_PEAK and "Traceback" not in err
    assert err.startswith(f"tsog: error: {INVALID / corpus}/") and err.count("\n") == 1, err
    assert refusal in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "raised",
    [
        OSError("broken"),
        ValueError("broken"),
        RuntimeError("broken"),
        EOFError("broken"),
        struct.error("broken"),
        Image.DecompressionBombError("broken"),
    ],
    ids=lambda e: type(e).__name__,
)
def test_any_error_of_the_image_decoder_becomes_a_sog_error(
    files: dict[str, bytes], raised: Exception, monkeypatch: pytest.MonkeyPatch
) -> None:
    def failing(data: bytes, size: tuple[int, int]) -> None:
        raise raised

    monkeypatch.setattr(webp, "_libwebp_rgba", failing)
    with pytest.raises(SogError, match=r"chunk.sog/\w+\.webp: corrupt WebP image: broken"):
        decode_chunk(files, where="chunk.sog")


# --- camera files: refused by size before parsing, counted while parsed -------------------


def test_a_cameras_json_over_its_size_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "cameras.json"
    path.write_bytes(b"[")
    os.truncate(path, 60_000_000)
    error, peak = peak_of(lambda: read_cameras(path))
    assert isinstance(error, FormatError) and peak < 1 * MiB
    assert error.message == (
        f"60000000 bytes, more than the {MAX_CAMERAS_JSON_BYTES} a camera file may hold"
    )
    assert MAX_CAMERAS_JSON_BYTES == MAX_CAMERAS * 4096


@pytest.mark.parametrize("entry", [b"{}", b"[]", b"0", b'""', b'{"width":1}'])
def test_a_cameras_json_of_too_many_entries_is_refused_as_it_is_parsed(
    entry: bytes, tmp_path: Path
) -> None:
    """The issue's 60 MB of empty objects (1.55 GiB parsed whole), cut to the size bound:
    refused at the entry past MAX_CAMERAS, what precedes it parsed and nothing after it."""
    count = MAX_CAMERAS_JSON_BYTES // (len(entry) + 2)
    path = tmp_path / "cameras.json"
    path.write_bytes(b"[" + b", ".join([entry] * count) + b"]")
    error, peak = peak_of(lambda: read_cameras(path))
    assert isinstance(error, FormatError), error
    assert error.message == f"more than the {MAX_CAMERAS} cameras a scene may carry"
    assert peak < 2 * path.stat().st_size + 8 * MiB, peak // MiB  # the bytes and their text


def test_a_colmap_text_model_over_its_size_is_refused_unread(tmp_path: Path) -> None:
    for name in ("cameras.txt", "images.txt"):
        (tmp_path / name).write_bytes(b"# empty\n")
    os.truncate(tmp_path / "cameras.txt", MAX_CAMERA_FILE_BYTES + 1)
    error, peak = peak_of(lambda: read_cameras(tmp_path))
    assert isinstance(error, FormatError) and peak < 1 * MiB
    assert "a camera file may hold" in error.message


@pytest.mark.parametrize(
    "text",
    [
        "[1]",
        ' [ {"a": [1, 2]} ,\n "x" ,[ ]] \n',
        "[]",
        '{"a": 1}',
        '"one"',
        "[1,]",
        "[1 2]",
        "[,1]",
        "[",
        "[[]",
        "[1] x",
        "",
        "[NaN, 1e400]",
    ],
)
def test_the_cameras_json_list_parsed_by_entries_reads_what_json_reads(text: str) -> None:
    """The entry-at-a-time parse accepts and refuses what ``json.loads`` does."""
    try:
        expected: object = json.loads(text)
    except ValueError:
        expected = ValueError
    try:
        found: object = cameras._json_list(text, 10, "x")
    except ValueError:
        found = ValueError
    assert repr(found) == repr(expected)

"""Decompression bombs, as a class: small files that would make a reader inflate or allocate
gigabytes are refused (or their hostile part skipped) before the memory is taken, with a
tracemalloc peak to prove it; the read budget is documented and configurable."""

from __future__ import annotations

import hashlib
import io
import json
import tracemalloc
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pydantic import TypeAdapter

from tsog_stream import SogError, TimelineType, decode_chunk, encode_chunk
from tsog_stream.cli.main import main
from tsog_stream.client.verify import Check, check_chunk
from tsog_stream.codec.bundle import bundle_bytes, read_bundle, unnamed_entries
from tsog_stream.constants import DEFAULT_MAX_PIXELS, MAX_PIXELS_ENV, pixel_budget
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
        except SogError as exc:
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

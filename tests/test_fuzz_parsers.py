"""Property-based fuzzing of every parser: any bytes decode or raise a TsogError, nothing else.

Inputs are mutations of small valid files (bit flips, byte overwrites, insertions, deletions,
truncation: random bytes alone would all die at the magic) and, for the HTTP header parsers,
structured random text. The same targets run under atheris in ``scripts/fuzz``. Hostile but
tiny inputs (a 100-byte PLY body declaring 10^9 vertices, a 60000x60000 WebP in a zip, a zstd frame
declaring 4 GiB) must be refused with a small tracemalloc peak (numpy allocations are traced);
cameras declaring 200x65536 pixels or a focal length of 1e-30 are drawn within the same peak.
"""

from __future__ import annotations

import itertools
import json
import struct
import subprocess
import sys
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from test_invalid_corpus import load, targets
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.errors import FormatError, MetaError, PlyError, SogError, TsogError
from tsog_stream.io.ply import parse_ply
from tsog_stream.server.ranges import Ignore, Serve, Unsatisfiable, parse_range

corpus = load("scripts/make_invalid_corpus.py", "make_invalid_corpus")

FUZZ = settings(
    derandomize=True,
    max_examples=400,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
SLOW_FUZZ = settings(FUZZ, max_examples=150)
"""For targets that decode images (a few ms per input)."""
SMALL_PEAK = 32 * 1024 * 1024


@st.composite
def mutated(draw: st.DrawFn, seeds: list[bytes]) -> bytes:
    """One seed with one to four edits: flip a bit, overwrite, insert, delete or truncate."""
    data = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(("flip", "set", "insert", "delete", "truncate")))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "flip" and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and data:
            data[at] = draw(st.sampled_from((0x00, 0xFF, 0x7F, 0x80, 0x2D, 0x39, 0x22)))
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del data[at : at + draw(st.integers(1, 16))]
        elif op == "truncate":
            del data[at:]
    return bytes(data)


def seeds_of(target: str) -> list[bytes]:
    """Valid seeds plus the corpus files this target reads."""
    found = list(targets.valid_seeds(target).values())
    for path in sorted(corpus.OUT.glob("*")):
        if targets.EXTENSIONS.get(path.suffix) == target:
            found.append(path.read_bytes())
    return found


def check(target: str, data: bytes) -> None:
    """Decoded, or a TsogError with a message; anything else fails the test."""
    assert targets.outcome(targets.TARGETS[target], data) in ("decoded", "rejected")


def fuzz_test(target: str, config: settings) -> Callable[[], None]:
    """A hypothesis test feeding mutations of ``target``'s seeds to it."""

    @config
    @given(data=mutated(seeds_of(target)))
    def run(data: bytes) -> None:
        check(target, data)

    run.__name__ = f"test_mutations_of_{target}_inputs_decode_or_raise_tsog_error"
    return run


test_ply = fuzz_test("ply", FUZZ)
test_splatv = fuzz_test("splatv", FUZZ)
test_meta = fuzz_test("meta", FUZZ)
test_manifest = fuzz_test("manifest", FUZZ)
test_index = fuzz_test("index", FUZZ)
test_index_json = fuzz_test("index_json", SLOW_FUZZ)
test_container = fuzz_test("container", SLOW_FUZZ)
test_sog = fuzz_test("sog", SLOW_FUZZ)
test_chunk_member = fuzz_test("chunk", SLOW_FUZZ)
test_cameras_json = fuzz_test("cameras_json", FUZZ)
test_colmap_bin = fuzz_test("colmap_bin", FUZZ)
test_colmap_text = fuzz_test("colmap_text", FUZZ)
test_cameras_render = fuzz_test("cameras_render", FUZZ)


@FUZZ
@given(data=st.binary(max_size=200))
def test_random_bytes_never_crash_any_target(data: bytes) -> None:
    names = ("ply", "splatv", "meta", "manifest", "index", "sog", "container", "colmap_bin")
    for name in (*names, "cameras_render"):
        check(name, data)


RANGE_TEXT = st.text(alphabet=st.sampled_from("bytes=0123456789-, \t;xX\u0663\u00e9"), max_size=60)


@FUZZ
@given(value=RANGE_TEXT | st.text(max_size=40), length=st.integers(0, 2**64))
def test_range_parser_returns_a_truthful_verdict(value: str, length: int) -> None:
    verdict = parse_range(value, length)
    assert isinstance(verdict, Serve | Ignore | Unsatisfiable)
    if isinstance(verdict, Serve):
        spans = [(r.start, r.end) for r in verdict.ranges]
        assert spans and all(0 <= s < e <= length for s, e in spans)
        assert all(a[1] < b[0] for a, b in itertools.pairwise(spans))


@FUZZ
@given(
    first=st.integers(0, 10**20),
    last=st.integers(0, 10**20),
    length=st.integers(0, 10**19),
)
def test_a_served_range_is_the_requested_one_clipped(first: int, last: int, length: int) -> None:
    verdict = parse_range(f"bytes={first}-{last}", length)
    if last < first:
        assert isinstance(verdict, Ignore)
    elif first >= length:
        assert isinstance(verdict, Unsatisfiable)
    else:
        assert isinstance(verdict, Serve)
        assert [(r.start, r.end) for r in verdict.ranges] == [(first, min(last + 1, length))]


HEADER_TEXT = st.text(alphabet=st.sampled_from('"W/*, \t:0123456789abcdefGMTSunNov-\n\x00\u00ff'))


@FUZZ
@given(data=HEADER_TEXT | st.text(max_size=80))
def test_conditional_headers_never_raise(data: str) -> None:
    check("conditional", data.encode("latin-1", "replace"))


HTTP_DATE = st.builds(
    "{}, {:02d} {} {} {:02d}:{:02d}:{:02d} {}".format,
    st.sampled_from(("Sun", "Mon", "Xyz")),
    st.integers(-1, 99),
    st.sampled_from(("Jan", "Nov", "Dec", "Foo")),
    st.integers(-(10**30), 10**30) | st.integers(0, 10_000),
    st.integers(-1, 99),
    st.integers(0, 99),
    st.integers(0, 99),
    st.sampled_from(("GMT", "UTC", "+0100", "-2359", "+9999", "-0000", "Z", "")),
)


@FUZZ
@given(date=HTTP_DATE)
def test_out_of_range_http_dates_never_raise(date: str) -> None:
    check("conditional", f"{date}\n\n\n{date}\n{date}".encode("latin-1"))


@FUZZ
@given(data=st.binary(max_size=100))
def test_conditional_bytes_never_raise(data: bytes) -> None:
    check("conditional", data)


# --- hostile but tiny inputs: refused with a small allocation peak ------------------------


def peak_of(call: Callable[[], object]) -> tuple[BaseException | None, int]:
    """The exception ``call`` raised (None if it returned) and the tracemalloc peak."""
    raised: BaseException | None = None
    tracemalloc.start()
    try:
        call()
    except Exception as exc:
        raised = exc
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return raised, peak


def hostile_cases() -> dict[str, tuple[str, bytes, type[TsogError] | None]]:
    """Tiny inputs whose headers declare gigabytes: (target, bytes, expected error or None
    when the input is read as far as it goes)."""
    ply_small = corpus.ply(10**9, bytes(100))  # a 3DGS header (~330 bytes) and 100 bytes
    ascii_ply = corpus.ply(10**12, b"1 2 3 4 5 6 7 8 9 10 11 12 13 14\n", fmt="ascii")
    files = corpus.sog_files()
    big = {**files, "means_l.webp": corpus.webp_header(b"VP8X", 60000, 60000)}
    canvas = {n: corpus.webp_header(b"VP8X", 4096, 4096) for n in files if n != "meta.json"}
    canvas_meta = corpus.meta_bytes(corpus.meta(4096 * 4096))
    wide = {n: corpus.webp_header(b"VP8X", 16384, 1024) for n in files if n != "meta.json"}
    within = {n: corpus.webp_header(b"VP8L", 16383, 16383) for n in files if n != "meta.json"}
    many = {**within, "meta.json": corpus.meta_bytes(corpus.meta(16383 * 16000))}
    splat = json.dumps([{"type": "splat", "size": 64 * 10**9}]).encode()
    splatv = struct.pack("<II", 0x674B, len(splat)) + splat + bytes(64)
    raw = corpus.manifest()
    zst = corpus.container_cases()["index-frame-declares-4gib.zst"][2]
    cameras = {
        f"{reader} camera {shape}, drawn": ("cameras_render", seed, None)
        for shape in targets.HOSTILE_CAMERA_SHAPES
        for reader, seed in (
            ("cameras.json", targets.valid_seeds("cameras_render")[f"json-{shape}.camrender"]),
            (".splatv header", targets.valid_seeds("cameras_render")[f"splatv-{shape}.camrender"]),
        )
    }
    return cameras | {
        "small PLY declaring 10^9 vertices": ("ply", ply_small, PlyError),
        "ASCII PLY declaring 10^12 vertices": ("ply", ascii_ply, PlyError),
        "zip holding a 60000x60000 WebP": ("sog", bundle_bytes(big), SogError),
        "VP8X canvases of 2^24 pixels and a count to match": (
            "sog",
            bundle_bytes({**canvas, "meta.json": canvas_meta}),
            SogError,
        ),
        "VP8X canvases 16384 wide": (
            "sog",
            bundle_bytes({**wide, "meta.json": files["meta.json"]}),
            SogError,
        ),
        "16383^2 images for 16 Gaussians": (
            "sog",
            bundle_bytes({**within, **{"meta.json": files["meta.json"]}}),
            MetaError,
        ),
        "16383^2 images and a count to match": ("sog", bundle_bytes(many), SogError),
        "a 60000x60000 WebP header alone": (
            "chunk",
            b"\x00" + corpus.webp_header(b"VP8X", 60000, 60000),
            SogError,
        ),
        "splatv declaring 10^9 records (reads the 1 present)": ("splatv", splatv, None),
        "zstd index frame declaring 4 GiB": ("index", zst, FormatError),
        "container whose index claims 4 GiB": (
            "container",
            corpus.container(raw, index_raw_length=4 * 1024**3),
            FormatError,
        ),
    }


HOSTILE = hostile_cases()


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_tiny_hostile_inputs_are_refused_without_big_allocations(
    case: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused from the headers alone: Pillow (whose libwebp allocates the whole canvas in C,
    unseen by tracemalloc) is never even asked to open an image."""

    def no_pillow(*args: object, **kwargs: object) -> None:
        raise AssertionError("Pillow was asked to open an image")

    monkeypatch.setattr(Image, "open", no_pillow)
    target, data, error = HOSTILE[case]
    assert len(data) < 20_000
    exc, peak = peak_of(lambda: targets.TARGETS[target](data))
    assert peak < SMALL_PEAK, f"{case}: peak {peak} bytes"
    if error is None:
        assert exc is None
    else:
        assert isinstance(exc, error), repr(exc)
        assert str(exc)


def test_the_atheris_harness_replays_the_corpus(tmp_path: Path) -> None:
    """The coverage-guided harness (scripts/fuzz) runs: every bad chunk file, run once, is
    rejected and nothing is recorded as a crash."""
    pytest.importorskip("atheris")
    files = sorted(str(p) for p in corpus.OUT.glob("*.sog"))
    stats, crashes = tmp_path / "stats.json", tmp_path / "crashes"
    harness = str(Path(targets.__file__ or "").with_name("harness.py"))
    command = [sys.executable, harness, "sog", "--stats", str(stats), "--crashes", str(crashes)]
    done = subprocess.run(
        [*command, "--", *files], check=False, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    counts = json.loads(stats.read_text())["counts"]
    assert counts == {"inputs": len(files), "rejected": len(files)}
    assert not crashes.exists()


def test_ascii_ply_values_beyond_float32_are_kept_as_inf() -> None:
    """Found by atheris: 1e300 in a float column raised numpy's overflow warning."""
    data = corpus.ply(1, b"0 1 2 3 4 5 6 1e300 8 9 10 11 12 13\n", fmt="ascii")
    contents = parse_ply(data)
    assert np.isinf(contents.gaussians.scales[0, 0])
    assert contents.gaussians.means.tolist() == [[0.0, 1.0, 2.0]]
    assert any("non-finite" in note for note in contents.notes)

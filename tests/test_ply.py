"""Plain 3DGS PLY: real files, generated variants (ASCII, big-endian, any order/type), errors."""

from __future__ import annotations

import io
import json
import math
import os
import re
import tracemalloc
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from conftest import SAMPLES, optional_data_dir
from tsog_stream import columns
from tsog_stream.constants import BLOCK_BYTES
from tsog_stream.errors import (
    InputError,
    PlyError,
    SourceError,
    TsogError,
    UnsupportedError,
)
from tsog_stream.io import ply
from tsog_stream.io.ply import (
    PlyContents,
    parse_ply,
    ply_bytes,
    read_ply,
    sniff_ply,
    write_ply,
)
from tsog_stream.io.ply_header import parse_header
from tsog_stream.model import Gaussians
from tsog_stream.synthetic import static_gaussians

NP_CODES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4"}
NP_CODES |= {"uint": "u4", "float": "f4", "double": "f8", "float32": "f4", "uint8": "u1"}
ATTRS = ("means", "scales", "quats", "opacities", "sh0", "shN")
Columns = Mapping[str, tuple[str, npt.NDArray[np.generic]]]


# --- helpers -------------------------------------------------------------------------------


def make_gaussians(n: int, bands: int, seed: int = 0) -> Gaussians:
    """Seeded Gaussians whose every column holds distinct values (catches mix-ups)."""
    rng = np.random.default_rng(seed)
    k = {0: 0, 1: 3, 2: 8, 3: 15}[bands]

    def f(*shape: int) -> npt.NDArray[np.float32]:
        return rng.standard_normal(shape).astype(np.float32)

    return Gaussians(f(n, 3), f(n, 3) - 4, f(n, 4), f(n), f(n, 3), f(n, k, 3) * 0.1)


def standard_columns(
    g: Gaussians, order: Sequence[str] | None = None
) -> dict[str, npt.NDArray[Any]]:
    """The standard PLY columns of ``g`` by name (f_rest channel-major), optionally reordered."""
    k = g.shN.shape[1]
    cols = {n: g.means[:, i] for i, n in enumerate("xyz")}
    cols |= {f"f_dc_{i}": g.sh0[:, i] for i in range(3)}
    cols |= {f"f_rest_{c * k + j}": g.shN[:, j, c] for c in range(3) for j in range(k)}
    cols |= {"opacity": g.opacities}
    cols |= {f"scale_{i}": g.scales[:, i] for i in range(3)}
    cols |= {f"rot_{i}": g.quats[:, i] for i in range(4)}
    return {n: cols[n] for n in order} if order else cols


def build_ply(
    fmt: str,
    elements: Sequence[tuple[str, Columns]],
    *,
    tail_header: Sequence[str] = (),
    tail: bytes = b"",
) -> bytes:
    """A PLY of ``elements`` (name -> {property: (PLY type, values)}) in any of the 3 formats."""
    lines, body = ["ply", f"format {fmt} 1.0", "comment test file"], b""
    for name, props in elements:
        count = len(next(iter(props.values()))[1]) if props else 0
        lines.append(f"element {name} {count}")
        lines += [f"property {ptype} {pname}" for pname, (ptype, _) in props.items()]
        body += _body(fmt, props, count)
    lines += [*tail_header, "end_header"]
    return ("\n".join(lines) + "\n").encode() + body + tail


def _body(fmt: str, props: Columns, count: int) -> bytes:
    """Rows of one element: text lines for ASCII, packed records for binary."""
    if fmt == "ascii":
        text = [
            [repr(float(v)) if NP_CODES[t][0] == "f" else str(int(v)) for v in values]
            for t, values in props.values()
        ]
        return "".join(" ".join(row) + "\n" for row in zip(*text, strict=True)).encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    dtype = np.dtype([(n, order + NP_CODES[t]) for n, (t, _) in props.items()])
    records = np.zeros(count, dtype)
    for n, (_, values) in props.items():
        records[n] = values
    return records.tobytes()


def floats(cols: Mapping[str, npt.NDArray[Any]]) -> dict[str, tuple[str, npt.NDArray[Any]]]:
    """Every column as a PLY float."""
    return {n: ("float", v) for n, v in cols.items()}


def assert_same(a: Gaussians, b: Gaussians) -> None:
    """Bit-exact float32 equality of every attribute (NaN equal to NaN)."""
    for attr in ATTRS:
        x, y = getattr(a, attr), getattr(b, attr)
        assert x.dtype == np.float32 and x.shape == y.shape, attr
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), attr


def appendix_b(document: Path) -> dict[str, dict[str, object]]:
    """Appendix B of a provenance document (../shared/data/PROVENANCE.md, or its copy for the
    files the repository carries, tests/data/README.md): the checker's ranges for every PLY,
    by relative path."""
    text = document.read_text()
    section = text.split("## Appendix B", 1)[1].split("\n## ", 1)[0]
    return {m[1]: json.loads(m[2]) for m in re.finditer(r"^- `([^`]+)`: (\{.*\})$", section, re.M)}


def assert_range(values: npt.NDArray[Any], expected: object, what: str) -> None:
    """``values`` span the "[lo, hi]" range the appendix gives to 4 significant digits."""
    assert isinstance(expected, str)
    lo, hi = (float(v) for v in expected.strip("[]").split(","))
    got = (float(np.min(values)), float(np.max(values)))
    assert np.allclose(got, (lo, hi), rtol=2e-3, atol=1e-6), f"{what}: {got} vs {expected}"


# --- real files ----------------------------------------------------------------------------


SAMPLE_DOCS = {"samples": "../README.md", "optional_samples": "PROVENANCE.md"}
"""Each sample set's provenance document, relative to the set (tests/data/real and its
README one level up; ../shared/data and its PROVENANCE.md)."""
PLY_COUNTS = {"samples": 15, "optional_samples": 16}


@pytest.mark.parametrize("kind", list(SAMPLE_DOCS))
def test_appendix_b_lists_every_real_ply(kind: str, request: pytest.FixtureRequest) -> None:
    data: Path = request.getfixturevalue(kind)
    on_disk = {str(p.relative_to(data)) for p in data.rglob("*.ply")}
    listed = set(appendix_b(data / SAMPLE_DOCS[kind]))
    assert listed == on_disk and len(on_disk) == PLY_COUNTS[kind]


@pytest.mark.parametrize("kind", list(SAMPLE_DOCS))
def test_real_plys_match_provenance_ranges(kind: str, request: pytest.FixtureRequest) -> None:
    data: Path = request.getfixturevalue(kind)
    for rel, facts in appendix_b(data / SAMPLE_DOCS[kind]).items():
        contents = read_ply(data / rel)
        g = contents.gaussians
        assert len(g) == facts["count"], rel
        for i, axis in enumerate("xyz"):
            assert_range(g.means[:, i], facts[axis], f"{rel} {axis}")
        assert_range(g.scales, facts["log_scale"], f"{rel} log_scale")
        if "opacity_logit" in facts:  # plain PLY
            assert_range(g.opacities, facts["opacity_logit"], f"{rel} opacity")
            assert_range(np.linalg.norm(g.quats, axis=1), facts["quat_norm"], f"{rel} quats")
            assert g.sh_bands == facts["sh_degree"]
        else:  # compressed: alpha = sigmoid(opacity)
            alpha = 1 / (1 + np.exp(-g.opacities.astype(np.float64)))
            assert_range(alpha, facts["opacity_sigmoid(alpha)"], f"{rel} alpha")
            assert g.shN.shape[1] * 3 == facts["sh_element"]
        assert contents.header is not None
        assert list(contents.header.comments) == facts["comments"]
        has_trailing_note = any("trailing bytes" in n for n in contents.notes)
        assert has_trailing_note is (not facts["size_exact"]), rel


def test_trailing_bytes_are_a_note(samples: Path) -> None:
    contents = read_ply(samples / "3dgs" / "cvlab_pc_short.ply")
    assert len(contents.gaussians) == 100
    assert "ignored 14029 trailing bytes after the declared 100 'vertex' rows" in contents.notes


def test_extra_property_is_kept(samples: Path) -> None:
    contents = read_ply(samples / "3dgs" / "supersplat_pr291_fruit_drops_minimal.ply")
    assert list(contents.extra) == ["transform"]
    assert contents.extra["transform"].shape == (4721,)
    assert contents.extra["transform"].dtype == np.float32
    assert any("transform" in n for n in contents.notes)


# --- round trips ---------------------------------------------------------------------------


@pytest.mark.parametrize("bands", [0, 1, 2, 3])
def test_write_read_is_bit_exact(bands: int) -> None:
    g = make_gaussians(200, bands, seed=bands)
    data = ply_bytes(g)
    rest = [f"f_rest_{i}" for i in range(3 * g.shN.shape[1])]
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *rest, "opacity"]
    expected += ["scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    header = parse_header(data)
    assert header.format == "binary_little_endian"
    assert list(header.elements[0].names) == expected
    assert all(p.type == "f4" for p in header.elements[0].properties)
    contents = parse_ply(data)
    assert_same(contents.gaussians, g)
    assert contents.extra == {} and contents.notes == []


@pytest.mark.parametrize("fmt", ["ascii", "binary_big_endian", "binary_little_endian"])
def test_formats_round_trip_exactly(fmt: str) -> None:
    g = make_gaussians(50, 3, seed=7)
    order = sorted(standard_columns(g), reverse=True)  # any property order
    data = build_ply(fmt, [("vertex", floats(standard_columns(g, order)))])
    contents = parse_ply(memoryview(data))
    assert_same(contents.gaussians, g)
    assert contents.notes == []


def test_write_ply_file_with_extras(tmp_path: Path) -> None:
    g = make_gaussians(30, 1)
    t = np.linspace(0, 1, 30, dtype=np.float32)
    write_ply(tmp_path / "out.ply", g, {"t": t, "motion_0": t * 2})
    contents = read_ply(tmp_path / "out.ply")
    assert_same(contents.gaussians, g)
    assert list(contents.extra) == ["t", "motion_0"]
    assert np.array_equal(contents.extra["motion_0"], t * 2)
    assert os.listdir(tmp_path) == ["out.ply"]


def test_empty_scene_round_trips() -> None:
    g = Gaussians.empty(2)
    assert_same(parse_ply(ply_bytes(g)).gaussians, g)


def test_any_numeric_type_and_normals_ignored() -> None:
    g = make_gaussians(20, 0)
    cols: dict[str, tuple[str, npt.NDArray[Any]]] = floats(standard_columns(g))
    cols["x"] = ("double", g.means[:, 0].astype(np.float64))
    cols["opacity"] = ("uchar", np.arange(20))
    cols["rot_0"] = ("short", -np.arange(20))
    cols |= {n: ("float", np.ones(20)) for n in ("nx", "ny", "nz")}
    for fmt in ("ascii", "binary_big_endian"):
        contents = parse_ply(build_ply(fmt, [("vertex", cols)]))
        assert np.array_equal(contents.gaussians.means, g.means)
        assert np.array_equal(contents.gaussians.opacities, np.arange(20, dtype=np.float32))
        assert np.array_equal(contents.gaussians.quats[:, 0], -np.arange(20, dtype=np.float32))
        assert contents.extra == {}


@pytest.mark.parametrize("fmt", ["ascii", "binary_big_endian", "binary_little_endian"])
def test_other_elements_are_located_by_offset(fmt: str) -> None:
    g = make_gaussians(10, 1)
    chunk = {"min_x": ("float", np.arange(3.0)), "flag": ("uchar", np.arange(3))}
    face = b"3 0 1 2\n" if fmt == "ascii" else b"\x03" + np.arange(3, dtype="<i4").tobytes()
    data = build_ply(
        fmt,
        [("chunk", chunk), ("vertex", floats(standard_columns(g)))],
        tail_header=["element face 1", "property list uchar int vertex_indices"],
        tail=face,
    )
    contents = parse_ply(data)
    assert_same(contents.gaussians, g)
    assert any("'chunk'" in n for n in contents.notes)
    assert any("'face'" in n for n in contents.notes)


def test_nonfinite_values_are_kept_and_counted() -> None:
    g = make_gaussians(10, 0)
    g.means[2, 1] = np.nan
    g.opacities[[3, 4]] = [np.inf, -np.inf]
    contents = parse_ply(ply_bytes(g))
    assert_same(contents.gaussians, g)
    assert contents.notes == ["kept 3 non-finite values as read (y: 1, opacity: 2)"]


# --- errors --------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_truncated_body_is_an_error(fmt: str) -> None:
    data = build_ply(fmt, [("vertex", floats(standard_columns(make_gaussians(20, 1))))])
    with pytest.raises(PlyError, match=r"expected \d+ (bytes|values).*found \d+"):
        parse_ply(data[:-20])


def test_trailing_bytes_note_on_generated_file() -> None:
    contents = parse_ply(ply_bytes(make_gaussians(5, 0)) + b"\0" * 7)
    assert contents.notes == ["ignored 7 trailing bytes after the declared 5 'vertex' rows"]


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_huge_count_in_tiny_file_does_not_allocate(fmt: str) -> None:
    header = ply_bytes(make_gaussians(1, 3)).split(b"end_header\n")[0].decode()
    header = header.replace("binary_little_endian", fmt).replace("vertex 1", f"vertex {10**12}")
    data = (header + "end_header\n").encode() + b"0 " * 50
    tracemalloc.start()
    try:
        with pytest.raises(PlyError, match="1000000000000"):
            parse_ply(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000


GARBAGE = {
    "empty": b"",
    "not ply": b"PK\x03\x04 zip file",
    "no end_header": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
    "no format": b"ply\nelement vertex 0\nend_header\n",
    "bad format": b"ply\nformat binary_middle_endian 1.0\nend_header\n",
    "unknown keyword": b"ply\nformat ascii 1.0\nvertices 3\nend_header\n",
    "unknown type": b"ply\nformat ascii 1.0\nelement v 1\nproperty half x\nend_header\n",
    "orphan property": b"ply\nformat ascii 1.0\nproperty float x\nend_header\n",
    "negative count": b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n",
    "duplicate property": b"ply\nformat ascii 1.0\nelement v 0\nproperty float x\n"
    b"property float x\nend_header\n",
    "non-ascii": b"ply\nformat ascii 1.0\ncomment caf\xe9\nend_header\n",
    "endless header": b"ply\nformat ascii 1.0\n" + b"comment padding\n" * 5000,
    "bad ascii value": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
    b"end_header\nabc\n",
    "int out of range": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar x\n"
    b"end_header\n300\n",
}


@pytest.mark.parametrize("data", GARBAGE.values(), ids=GARBAGE.keys())
def test_garbage_is_a_ply_error(data: bytes) -> None:
    with pytest.raises(PlyError):
        parse_ply(data)


@pytest.mark.parametrize("missing", ["x", "scale_2", "rot_3", "opacity", "f_dc_1"])
def test_missing_property_is_named(missing: str) -> None:
    cols = standard_columns(make_gaussians(4, 0))
    del cols[missing]
    with pytest.raises(PlyError, match=rf"missing required vertex property {missing}\b"):
        parse_ply(build_ply("binary_little_endian", [("vertex", floats(cols))]))


def test_bad_f_rest_count_is_named() -> None:
    cols = standard_columns(make_gaussians(4, 1))
    del cols["f_rest_8"]
    with pytest.raises(PlyError, match="found 8"):
        parse_ply(build_ply("binary_little_endian", [("vertex", floats(cols))]))


def test_list_property_in_vertex_is_unsupported() -> None:
    g = make_gaussians(1, 0)
    data = build_ply("ascii", [("vertex", floats(standard_columns(g)))])
    head, body = data.split(b"end_header\n")
    data = head + b"property list uchar int idx\nend_header\n" + body.rstrip() + b" 2 5 6\n"
    with pytest.raises(UnsupportedError, match="list properties"):
        parse_ply(data)


def test_sniff() -> None:
    assert sniff_ply(b"ply\nformat") and sniff_ply(b"ply\r\nformat")
    assert not sniff_ply(b"plyx\n") and not sniff_ply(b"")


@pytest.mark.parametrize(
    "extra",
    [{"x": np.zeros(3)}, {"two words": np.zeros(3)}, {"t": np.zeros(4)}, {"t": np.zeros((3, 1))}],
)
def test_bad_extras_are_input_errors(extra: dict[str, npt.NDArray[Any]]) -> None:
    with pytest.raises(InputError):
        ply_bytes(make_gaussians(3, 0), extra)


def test_read_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError):
        read_ply(tmp_path / "nope.ply")


def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "scene.ply"
    target.write_bytes(b"old")

    def failing_replace(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(SourceError, match="No space left"):
        write_ply(target, make_gaussians(10, 1))
    assert os.listdir(tmp_path) == ["scene.ply"] and target.read_bytes() == b"old"
    target.unlink()
    with pytest.raises(SourceError):
        write_ply(target, make_gaussians(10, 1))
    assert os.listdir(tmp_path) == []


def test_write_failing_mid_write_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def failing_fsync(fd: int) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(SourceError, match="Input/output error"):
        write_ply(tmp_path / "a.ply", make_gaussians(3, 0))
    assert os.listdir(tmp_path) == []


def test_write_rejects_bad_input_before_touching_disk(tmp_path: Path) -> None:
    with pytest.raises(InputError):
        write_ply(tmp_path / "a.ply", make_gaussians(3, 0), {"t": np.zeros(2)})
    (tmp_path / "a-file").write_bytes(b"")
    with pytest.raises(SourceError):
        write_ply(tmp_path / "a-file" / "a.ply", make_gaussians(3, 0))
    assert os.listdir(tmp_path) == ["a-file"]
    write_ply(tmp_path / "made" / "a.ply", make_gaussians(3, 0))  # missing folders are made
    assert os.listdir(tmp_path / "made") == ["a.ply"]


def test_reading_holds_the_gaussians_and_a_few_blocks(tmp_path: Path) -> None:
    """A binary PLY file is read into its Gaussians' arrays a block of rows at a time: at most
    the arrays and a few blocks at any time (the file's bytes whole beside the arrays were a
    500k SH3 frame's read at 2.06x its arrays; before that, the columns were gathered into one
    matrix, from a copy of an unaligned body: the file and three times the arrays)."""
    path = tmp_path / "sh3.ply"
    write_ply(path, static_gaussians(60_000, sh_bands=3, seed=5))
    tracemalloc.start()
    try:
        g = read_ply(path).gaussians
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    arrays = sum(a.nbytes for a in (g.means, g.scales, g.quats, g.opacities, g.sh0, g.shN))
    assert peak <= arrays + 4 * BLOCK_BYTES


def _generated_plys() -> dict[str, bytes]:
    """PLY files of every kind a file may be read by blocks or not: both byte orders, other
    elements before and after the vertices, extras and doubles, trailing bytes, a body cut
    short, ASCII, list elements, non-finite values."""
    g = make_gaussians(40, 2)
    cols = floats(standard_columns(g))
    extra = {"t": ("double", np.linspace(0, 1, 40)), "id": ("uint", np.arange(40))}
    chunk = {"min_x": ("float", np.arange(3.0)), "flag": ("uchar", np.arange(3))}
    face = ["element face 1", "property list uchar int vertex_indices"]
    nan = dict(cols, x=("float", np.where(np.arange(40) % 7 == 0, np.nan, g.means[:, 0])))
    made = {
        f"{fmt} {what}": build_ply(fmt, elements)
        for fmt in ("binary_little_endian", "binary_big_endian", "ascii")
        for what, elements in {
            "plain": [("vertex", cols)],
            "extras": [("vertex", {**cols, **extra})],
            "elements around": [("chunk", chunk), ("vertex", cols), ("chunk2", chunk)],
            "non-finite": [("vertex", nan)],
        }.items()
    }
    plain = made["binary_little_endian plain"]
    made["trailing"] = plain + b"\0" * 9
    made["cut short"] = plain[:-20]
    made["list after"] = build_ply("binary_little_endian", [("vertex", cols)], tail_header=face)
    made["no vertex"] = build_ply("binary_little_endian", [("chunk", chunk)])
    made["no rotation"] = build_ply(
        "binary_little_endian", [("vertex", {n: c for n, c in cols.items() if n != "rot_3"})]
    )
    return made


def _contents_or_error(read: Callable[[Path], PlyContents], path: Path) -> Any:
    """What reading ``path`` gives: its Gaussians' arrays, extras, notes and header; or its
    error."""
    try:
        contents = read(path)
    except TsogError as exc:
        return (type(exc), str(exc))
    g = contents.gaussians
    arrays = [getattr(g, a) for a in ATTRS]
    extra = {n: (v.dtype, v.tobytes()) for n, v in contents.extra.items()}
    return [a.tobytes() for a in arrays], extra, contents.notes, contents.header


def test_reading_a_file_by_blocks_gives_what_parsing_its_bytes_gives(
    samples: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every PLY the repository holds (real, conformance, hostile) and generated ones of every
    kind, read from its file 5 rows at a time (or whole, where blocks do not apply), gives
    the Gaussians, extras, notes and header (or the error) that parsing its bytes gives."""
    files = sorted(samples.parent.rglob("*.ply"))
    for name, data in _generated_plys().items():
        files.append(tmp_path / f"{name}.ply")
        files[-1].write_bytes(data)
    assert len(files) > 40
    monkeypatch.setattr(columns, "BLOCK_BYTES", 5 * 60)  # a few rows a block
    for path in files:
        whole = _contents_or_error(lambda p: parse_ply(p.read_bytes(), name=str(p)), path)
        assert _contents_or_error(read_ply, path) == whole, path.name


def test_a_file_that_ends_while_read_is_a_ply_error() -> None:
    """A file cut short between its size being taken and its rows read: a PlyError."""
    with pytest.raises(PlyError, match="ended 2 bytes early"):
        ply._read_exactly(io.BytesIO(b"abc"), 5, "cut.ply")


# --- absurd values: a header naming the wrong byte order, as a class -----------------------

OTHER_ORDER = {
    b"binary_little_endian": b"binary_big_endian",
    b"binary_big_endian": b"binary_little_endian",
}


def real_plys() -> list[Path]:
    """Every real PLY the repository carries and, when present, the optional set's."""
    optional = optional_data_dir()
    found = sorted(SAMPLES.rglob("*.ply"))
    return found + (sorted(optional.rglob("*.ply")) if optional is not None else [])


def with_other_byte_order(data: bytes) -> bytes:
    """``data`` with its header's binary format line naming the other byte order."""
    for named, other in OTHER_ORDER.items():
        line = b"format " + named + b" "
        if line in data[:4096]:
            return data.replace(line, b"format " + other + b" ", 1)
    raise AssertionError("not a binary PLY")


@pytest.mark.parametrize("path", real_plys(), ids=lambda p: p.name)
def test_every_real_ply_reads_without_absurd_values(path: Path) -> None:
    """The bounds leave every real capture alone: read by blocks and parsed whole, nothing is
    clamped and the Gaussians are the same."""
    read = read_ply(path)
    parsed = parse_ply(path.read_bytes(), name=str(path))
    assert not any("absurd" in note for note in read.notes + parsed.notes)
    assert_same(read.gaussians, parsed.gaussians)


@pytest.mark.parametrize("path", real_plys(), ids=lambda p: p.name)
def test_every_real_ply_with_the_other_byte_order_is_refused_naming_a_property(
    path: Path, tmp_path: Path
) -> None:
    """The issue's file, as a class: each real capture (plain or compressed, either byte
    order) whose header names the other byte order is refused at the input, by the reader by
    blocks and the parse of bytes alike, naming a property and the format, with no numpy
    warning (the suite turns warnings into errors)."""
    swapped = with_other_byte_order(path.read_bytes())
    fmt = re.search(rb"format (\w+)", swapped)
    assert fmt is not None
    pattern = (
        rf"PLY property '\w+' holds absurd values: \d+ of \d+ beyond \+-\S+, the bound of a "
        rf"(position|log scale|rotation|opacity logit|colour): is the header's format "
        rf"\({fmt[1].decode()}\) right\?"
    )
    file = tmp_path / path.name
    file.write_bytes(swapped)
    with pytest.raises(PlyError, match=pattern):
        read_ply(file)
    with pytest.raises(PlyError, match=pattern):
        parse_ply(swapped, name=str(file))


KINDS = {
    "x": ("position", 1e9),
    "scale_1": ("log scale", 40.0),
    "rot_2": ("rotation", 1e4),
    "opacity": ("opacity logit", 100.0),
    "f_dc_0": ("colour", 1e3),
    "f_rest_7": ("colour", 1e3),
}
"""A property of each kind, with the kind and bound the reader applies."""


def column_of(g: Gaussians, name: str) -> npt.NDArray[np.float32]:
    """The values of PLY property ``name`` in ``g`` (f_rest channel-major, as files store it)."""
    if name in ("x", "y", "z"):
        return g.means[:, "xyz".index(name)]
    if name == "opacity":
        return g.opacities
    head, _, index = name.rpartition("_")
    if head == "f_rest":
        k = g.shN.shape[1]
        return g.shN[:, int(index) % k, int(index) // k]
    return {"scale": g.scales, "rot": g.quats, "f_dc": g.sh0}[head][:, int(index)]


def ply_with_values(fmt: str, name: str, values: Mapping[int, float]) -> bytes:
    """A 200-row SH1 PLY whose property ``name`` holds ``values`` (row -> value)."""
    cols = standard_columns(make_gaussians(200, 1, seed=3))
    column = np.array(cols[name], np.float64)
    column[list(values)] = list(values.values())
    return build_ply(fmt, [("vertex", floats({**cols, name: column}))])


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
@pytest.mark.parametrize("name", list(KINDS))
def test_a_few_absurd_values_are_clamped_and_noted(fmt: str, name: str, tmp_path: Path) -> None:
    """Two rows of 200 (1 %) beyond the bound of their kind, of either sign: kept, clamped to
    the bound and counted in a note, by blocks and whole alike; a NaN beside them is kept."""
    bound = KINDS[name][1]
    data = ply_with_values(fmt, name, {5: 3e30, 9: -3e30, 11: math.nan})
    (tmp_path / "a.ply").write_bytes(data)
    for contents in (parse_ply(data), read_ply(tmp_path / "a.ply")):
        assert contents.notes[0] == f"clamped 2 absurd values to their kind's bound ({name}: 2)"
        assert contents.notes[1] == f"kept 1 non-finite values as read ({name}: 1)"
        values = column_of(contents.gaussians, name)
        assert values[5] == np.float32(bound) and values[9] == -np.float32(bound)
        assert math.isnan(values[11])


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
@pytest.mark.parametrize("name", list(KINDS))
def test_more_absurd_values_refuse_the_file_naming_the_property(
    fmt: str, name: str, tmp_path: Path
) -> None:
    """Three rows of 200 (over 1 %): refused, the property and its kind named; a binary
    file's format is put in doubt, an ASCII file's is not."""
    kind, bound = KINDS[name]
    data = ply_with_values(fmt, name, {5: 3e30, 9: -3e30, 150: 1.5 * bound})
    (tmp_path / "a.ply").write_bytes(data)
    message = f"PLY property '{name}' holds absurd values: 3 of 200 beyond +-{bound:g}, "
    message += f"the bound of a {kind}"
    if fmt != "ascii":
        message += f": is the header's format ({fmt}) right?"
    with pytest.raises(PlyError) as parsed:
        parse_ply(data, name="a.ply")
    with pytest.raises(PlyError) as read:
        read_ply(tmp_path / "a.ply")
    assert parsed.value.message == read.value.message == message


def test_values_at_the_bound_are_kept_as_they_are() -> None:
    """The bound itself is plausible: nothing clamped, nothing noted."""
    for name, (_, bound) in KINDS.items():
        contents = parse_ply(ply_with_values("binary_little_endian", name, {1: bound, 2: -bound}))
        assert contents.notes == []
        assert list(column_of(contents.gaussians, name)[1:3]) == [bound, -bound]

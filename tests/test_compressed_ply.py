"""PlayCanvas compressed PLY: formulas on synthetic packs, real files, splat-transform interop."""

from __future__ import annotations

import math
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream.constants import ALPHA_EPS, SH_C0
from tsog_stream.errors import PlyError
from tsog_stream.io.compressed_ply import is_compressed_ply, parse_compressed_ply
from tsog_stream.io.ply import parse_ply, ply_bytes, read_ply
from tsog_stream.io.ply_header import parse_header
from tsog_stream.model import Gaussians

SPLAT_TRANSFORM = Path(__file__).resolve().parents[1] / "node_modules" / ".bin" / "splat-transform"
GUITAR = Path("3dgs") / "pc_guitar.compressed.ply"
ENGINE = Path("fixtures") / "pc_engine_test.compressed.ply"
ROT = 1 / math.sqrt(2)
U32 = npt.NDArray[np.uint32]


# --- a tiny compressed-PLY writer for the synthetic tests -----------------------------------


def build(elements: Mapping[str, Mapping[str, tuple[str, npt.ArrayLike]]]) -> bytes:
    """A binary little-endian PLY from {element: {property: (numpy code, values)}}."""
    lines, body = ["ply", "format binary_little_endian 1.0"], b""
    ply_type = {"<f4": "float", "<u4": "uint", "u1": "uchar"}
    for name, props in elements.items():
        count = len(np.asarray(next(iter(props.values()))[1]))
        lines.append(f"element {name} {count}")
        lines += [f"property {ply_type[code]} {p}" for p, (code, _) in props.items()]
        records = np.zeros(count, [(p, code) for p, (code, _) in props.items()])
        for p, (_, values) in props.items():
            records[p] = values
        body += records.tobytes()
    return ("\n".join([*lines, "end_header"]) + "\n").encode() + body


def pack_11_10_11(fields: npt.NDArray[np.int64]) -> U32:
    """Pack (N, 3) integer fields into 11/10/11-bit words, x in the top bits."""
    return ((fields[:, 0] << 21) | (fields[:, 1] << 11) | fields[:, 2]).astype(np.uint32)


def pack_rotation(quats: npt.NDArray[np.float64]) -> U32:
    """Smallest-three encoding: 2-bit index of the largest |component|, 3 x 10-bit others."""
    largest = np.argmax(np.abs(quats), axis=1)
    q = quats * np.sign(quats[np.arange(len(quats)), largest])[:, None]
    others = np.stack([np.delete(row, i) for row, i in zip(q, largest, strict=True)])
    bits = np.rint((others / (2 * ROT) + 0.5) * 1023).astype(np.int64)
    word = (largest << 30) | (bits[:, 0] << 20) | (bits[:, 1] << 10) | bits[:, 2]
    packed: npt.NDArray[np.uint32] = word.astype(np.uint32)
    return packed


def chunk_bounds(n_chunks: int, colors: bool) -> dict[str, tuple[str, npt.NDArray[Any]]]:
    """Distinct bounds per chunk so a vertex decoded with the wrong chunk shows."""
    base = np.arange(n_chunks, dtype=np.float64) * 10
    cols = {f"min_{a}": ("<f4", base - i) for i, a in enumerate("xyz")}
    cols |= {f"max_{a}": ("<f4", base + 1 + i) for i, a in enumerate("xyz")}
    cols |= {f"min_scale_{a}": ("<f4", -6 - base / 10) for a in "xyz"}
    cols |= {f"max_scale_{a}": ("<f4", -1 + base / 10) for a in "xyz"}
    if colors:
        cols |= {f"min_{c}": ("<f4", np.full(n_chunks, -0.25)) for c in "rgb"}
        cols |= {f"max_{c}": ("<f4", np.full(n_chunks, 1.5)) for c in "rgb"}
    return cols


# --- synthetic: every formula --------------------------------------------------------------


@pytest.mark.parametrize("colors", [True, False])
def test_synthetic_pack_decodes_by_the_formulas(colors: bool) -> None:
    n, rng = 300, np.random.default_rng(3)  # 300 vertices: two chunks, the second partial
    pos = np.stack([rng.integers(0, m, n) for m in (2048, 1024, 2048)], 1)
    scl = np.stack([rng.integers(0, m, n) for m in (2048, 1024, 2048)], 1)
    quats = rng.standard_normal((n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    rgba = rng.integers(0, 256, (n, 4))
    rgba[:3, 3] = [0, 255, 128]
    sh = rng.integers(0, 256, (n, 24)).astype(np.uint8)
    sh[0, :3] = [0, 255, 128]
    color_word = (rgba[:, 0] << 24) | (rgba[:, 1] << 16) | (rgba[:, 2] << 8) | rgba[:, 3]
    data = build(
        {
            "chunk": chunk_bounds(2, colors),
            "vertex": {
                "packed_position": ("<u4", pack_11_10_11(pos)),
                "packed_rotation": ("<u4", pack_rotation(quats)),
                "packed_scale": ("<u4", pack_11_10_11(scl)),
                "packed_color": ("<u4", color_word.astype(np.uint32)),
            },
            "sh": {f"f_rest_{i}": ("u1", sh[:, i]) for i in range(24)},
        }
    )
    contents = parse_ply(data)
    g = contents.gaussians
    chunk = np.arange(n) // 256 * 10.0
    t = pos / np.array([2047, 1023, 2047])
    lo, hi = chunk[:, None] - np.arange(3), chunk[:, None] + 1 + np.arange(3)
    np.testing.assert_allclose(g.means, lo * (1 - t) + hi * t, rtol=1e-6, atol=1e-6)
    t = scl / np.array([2047, 1023, 2047])
    lo, hi = (-6 - chunk / 10)[:, None], (-1 + chunk / 10)[:, None]
    np.testing.assert_allclose(g.scales, lo * (1 - t) + hi * t, rtol=1e-6)
    signs = np.sign(quats[np.arange(n), np.argmax(np.abs(quats), 1)])[:, None]
    np.testing.assert_allclose(g.quats, quats * signs, atol=2e-3)
    color = rgba[:, :3] / 255
    color = -0.25 * (1 - color) + 1.5 * color if colors else color
    np.testing.assert_allclose(g.sh0, (color - 0.5) / SH_C0, rtol=1e-6, atol=1e-6)
    alpha = np.clip(rgba[:, 3] / 255, ALPHA_EPS, 1 - ALPHA_EPS)
    np.testing.assert_allclose(g.opacities, np.log(alpha / (1 - alpha)), rtol=1e-6)
    assert abs(g.opacities[0] + 13.8155) < 1e-3 and abs(g.opacities[1] - 13.8155) < 1e-3
    unit = np.where(sh == 0, 0, np.where(sh == 255, 1, (sh + 0.5) / 256))
    expected_sh = ((unit - 0.5) * 8).reshape(n, 3, 8).transpose(0, 2, 1)
    np.testing.assert_allclose(g.shN, expected_sh, rtol=1e-6)
    assert g.shN[0, 0, 0] == -4 and g.shN[0, 1, 0] == 4 and g.shN[0, 2, 0] == 0.015625
    clamped = int(np.count_nonzero((rgba[:, 3] == 0) | (rgba[:, 3] == 255)))
    assert f"clamped {clamped} opacities with alpha byte 0 or 255 to logit ±13.8" in contents.notes


# --- real files ----------------------------------------------------------------------------


def test_detector(samples: Path) -> None:
    assert is_compressed_ply(parse_header((samples / GUITAR).read_bytes()))
    assert is_compressed_ply(parse_header((samples / ENGINE).read_bytes()))
    plain = ply_bytes(Gaussians.empty())
    assert not is_compressed_ply(parse_header(plain))
    with pytest.raises(PlyError, match="not a compressed PLY"):
        parse_compressed_ply(plain)


@pytest.mark.parametrize("rel", [GUITAR, ENGINE])
def test_real_quaternions_are_plausible(samples: Path, rel: Path) -> None:
    data = (samples / rel).read_bytes()
    g = parse_compressed_ply(data, name=str(rel)).gaussians
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1.0, atol=1e-3)
    header = parse_header(data)
    offset = header.size + sum(e.count * 4 * len(e.properties) for e in header.elements[:1])
    words = np.frombuffer(data, "<u4", 4 * len(g), offset).reshape(-1, 4)
    rebuilt = g.quats[np.arange(len(g)), words[:, 1] >> 30]  # the dropped component
    # it is the largest (up to one 10-bit step on near ties) and positive: >= 1/2 for unit q
    assert np.all(np.abs(g.quats).max(axis=1) - rebuilt <= 2e-3)
    assert rebuilt.min() >= 0.5


@pytest.mark.parametrize("cut", [1, 1000])
def test_truncated_file_is_an_error(samples: Path, cut: int) -> None:
    data = (samples / GUITAR).read_bytes()[:-cut]
    with pytest.raises(PlyError, match=r"expected \d+ bytes .* found \d+"):
        parse_compressed_ply(data)


# --- malformed -----------------------------------------------------------------------------


def _minimal(n: int = 4, chunks: int = 1, drop: str = "", sh: int = 0, sh_rows: int = 4) -> bytes:
    """A small compressed PLY, optionally broken by dropping a property or mis-sizing parts."""
    packed = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
    vertex = {p: ("<u4", np.zeros(n, np.uint32)) for p in packed if p != drop}
    elements = {"chunk": chunk_bounds(chunks, True), "vertex": vertex}
    if sh:
        elements["sh"] = {f"f_rest_{i}": ("u1", np.zeros(sh_rows, np.uint8)) for i in range(sh)}
    return build(elements)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_minimal(drop="packed_scale"), "packed_scale"),
        (_minimal(n=300, chunks=1), "need 2 chunk rows, found 1"),
        (_minimal(sh=9, sh_rows=3), "'sh' has 3 rows"),
        (_minimal(sh=10), "found 10 properties"),
    ],
)
def test_malformed_is_a_ply_error(data: bytes, message: str) -> None:
    with pytest.raises(PlyError, match=message):
        parse_compressed_ply(data)


def test_spare_chunk_rows_are_a_note() -> None:
    contents = parse_compressed_ply(_minimal(n=4, chunks=2))
    assert contents.notes[-1] == "ignored 1 chunk rows beyond the 1 needed"


# --- interop with the reference decoder ----------------------------------------------------


def reference_decode(tool: Path, source: Path, tmp_path: Path) -> Gaussians:
    """Decode ``source`` with splat-transform into a plain float PLY and read that back."""
    out = tmp_path / "reference.ply"  # not *.compressed.ply: that would re-compress
    cmd = [str(tool), "-g", "cpu", "-w", str(source), str(out)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    return read_ply(out).gaussians


@pytest.mark.interop
@pytest.mark.parametrize("rel", [GUITAR, ENGINE])
def test_matches_splat_transform_bit_for_bit(
    samples: Path, splat_transform: Path, tmp_path: Path, rel: Path
) -> None:
    ours = parse_compressed_ply((samples / rel).read_bytes()).gaussians
    ref = reference_decode(splat_transform, samples / rel, tmp_path)
    assert ours.sh_bands == ref.sh_bands == (3 if rel == ENGINE else 0)
    for attr in ("means", "scales", "quats", "sh0", "shN"):
        assert np.array_equal(getattr(ours, attr), getattr(ref, attr)), attr
    finite = np.isfinite(ref.opacities)
    assert np.array_equal(ours.opacities[finite], ref.opacities[finite])
    limit = np.float32(math.log((1 - ALPHA_EPS) / ALPHA_EPS))
    assert not finite.all()  # the reference yields +-inf for alpha bytes 255 and 0
    assert np.allclose(ours.opacities[~finite], np.sign(ref.opacities[~finite]) * limit)

"""FreeTimeGS readers: Scene.at(t) equals the FreeTimeGS equations, for every input spelling."""

from __future__ import annotations

import io
import re
import struct
import tracemalloc
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Literal

import numpy as np
import numpy.typing as npt
import pytest

from fixtures_4d import (
    FreeTimeTruth,
    edge_times,
    freetime_expected,
    freetime_npz,
    freetime_ply,
    freetime_truth,
)
from tsog_stream import FormatError, InputError, UnsupportedError
from tsog_stream.codec.bundle import MAX_ENTRIES
from tsog_stream.io.freetimegs import (
    MIN_DURATION,
    is_freetimegs_ply,
    parse_freetimegs_npz,
    parse_freetimegs_ply,
    sniff_freetimegs_npz,
)
from tsog_stream.io.loaded import Loaded4D
from tsog_stream.io.ply import parse_ply, ply_bytes
from tsog_stream.io.ply_header import parse_header
from tsog_stream.model import TimelineType

TRUTH = freetime_truth()
VELOCITY_SPELLINGS = [
    ("velocity_0", "velocity_1", "velocity_2"),
    ("velocity_x", "velocity_y", "velocity_z"),
    ("vx", "vy", "vz"),
    ("motion_0", "motion_1", "motion_2"),
]


def _alpha(logits: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    return 1.0 / (1.0 + np.exp(-logits.astype(np.float64)))


def _check_against_truth(
    loaded: Loaded4D,
    truth: FreeTimeTruth,
    scene_length: float,
    *,
    min_sigma: float = 0.0,
    use_velocity: bool = True,
) -> None:
    """Scene.at(t) = the analytic FreeTimeGS state at several t, including the edges."""
    times = [f * scene_length for f in (0.0, 0.13, 0.5, 0.77, 1.0)]
    times += edge_times(truth, scene_length)
    edge_visible = []
    for t in times:
        visible, means, alpha = freetime_expected(
            truth, t, scene_length, min_sigma=min_sigma, use_velocity=use_velocity
        )
        got = loaded.scene.at(t)
        assert len(got) == int(visible.sum()), t
        np.testing.assert_allclose(got.means, means, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(_alpha(got.opacities), alpha, rtol=1e-5, atol=1e-7)
        base = truth.gaussians.subset(visible)
        np.testing.assert_array_equal(got.scales, base.scales)
        np.testing.assert_allclose(got.sh0, base.sh0)
        np.testing.assert_allclose(got.shN, base.shN)
        quats = base.quats / np.linalg.norm(base.quats, axis=1, keepdims=True)
        np.testing.assert_allclose(got.quats, quats, atol=1e-6)
        edge_visible.append(bool(visible[0]))
    assert edge_visible[-4:] == [True, False, True, False]  # just inside / outside each edge


@pytest.mark.parametrize("velocity_names", VELOCITY_SPELLINGS)
@pytest.mark.parametrize("time_name", ["time", "t"])
def test_ply_spellings_match_the_equations(
    time_name: str, velocity_names: tuple[str, str, str]
) -> None:
    data = freetime_ply(TRUTH, time_name=time_name, velocity_names=velocity_names)
    loaded = parse_freetimegs_ply(data, scene_length_s=2.5)
    _check_against_truth(loaded, TRUTH, 2.5)
    assert not any("unknown properties" in n for n in loaded.notes)


@pytest.mark.parametrize(
    ("duration_name", "linear"),
    [
        ("log_duration", False),
        ("duration", False),
        ("duration", True),
        ("t_scale", False),
        ("t_scale", True),
    ],
)
def test_ply_duration_modes(duration_name: str, linear: bool) -> None:
    data = freetime_ply(TRUTH, duration_name=duration_name, linear=linear)
    mode: Literal["linear", "log"] = "linear" if linear else "log"
    loaded = parse_freetimegs_ply(data, scene_length_s=0.8, duration=mode)
    _check_against_truth(loaded, TRUTH, 0.8)


def test_ply_scene_layout_and_default_time_unit() -> None:
    loaded = parse_freetimegs_ply(freetime_ply(TRUTH))
    scene = loaded.scene
    assert scene.timeline is not None and scene.timeline.type is TimelineType.CENTER_SCALE
    assert scene.timeline.scene_length == 1.0
    assert scene.temporal["means"].shape == (len(TRUTH.gaussians), 1, 3)
    assert any("1 unit read as 1.0 s" in n for n in loaded.notes)
    np.testing.assert_allclose(scene.timeline.t0, TRUTH.times)
    _check_against_truth(loaded, TRUTH, 1.0)


def test_ply_header_comments_are_honoured() -> None:
    comments = ["ftgs_version 1", "time_units normalized", "use_velocity 0", "min_duration 0.02"]
    data = freetime_ply(TRUTH, comments=[*comments, "opacity_floor 0.0001", "n_frames 61"])
    loaded = parse_freetimegs_ply(data, scene_length_s=3.0)
    assert "means" not in loaded.scene.temporal
    assert any("use_velocity 0" in n for n in loaded.notes)
    assert any("opacity_floor" in n for n in loaded.notes)
    assert not any("n_frames" in n for n in loaded.notes)  # scene_length_s was given
    default_notes = parse_freetimegs_ply(data).notes
    assert any(n.startswith("n_frames 61: scene_length_s = (61 - 1) / fps") for n in default_notes)
    _check_against_truth(loaded, TRUTH, 3.0, min_sigma=0.02, use_velocity=False)


def test_ply_unsupported_time_units_and_polynomials() -> None:
    with pytest.raises(UnsupportedError, match="time_units"):
        parse_freetimegs_ply(freetime_ply(TRUTH, comments=["time_units frames"]))
    cubic = {f"motion_{i}": TRUTH.velocity[:, 0] for i in range(3, 9)}
    data = freetime_ply(TRUTH, velocity_names=("motion_0", "motion_1", "motion_2"), more=cubic)
    with pytest.raises(UnsupportedError, match="motion_3"):
        parse_freetimegs_ply(data)


def test_ply_ambiguous_and_contradictory_inputs() -> None:
    both = freetime_ply(TRUTH, more={"t": TRUTH.times})  # 'time' is there too
    with pytest.raises(FormatError, match="ambiguous"):
        parse_freetimegs_ply(both)
    vel = freetime_ply(TRUTH, more={"vx": TRUTH.times, "vy": TRUTH.times, "vz": TRUTH.times})
    with pytest.raises(FormatError, match="ambiguous velocity"):
        parse_freetimegs_ply(vel)
    with pytest.raises(InputError, match="log_duration"):
        parse_freetimegs_ply(freetime_ply(TRUTH), duration="linear")
    with pytest.raises(InputError):
        parse_freetimegs_ply(freetime_ply(TRUTH), duration="cubic")  # type: ignore[arg-type]
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="scene_length_s"):
            parse_freetimegs_ply(freetime_ply(TRUTH), scene_length_s=bad)


def test_ply_without_velocity_is_static_and_unknown_extras_are_noted() -> None:
    data = freetime_ply(TRUTH, velocity_names=(), more={"foo": TRUTH.times})
    loaded = parse_freetimegs_ply(data, scene_length_s=1.0)
    assert loaded.scene.temporal == {}
    assert any(n.startswith("unknown properties kept as extras: foo") for n in loaded.notes)
    _check_against_truth(loaded, TRUTH, 1.0, use_velocity=False)


def test_ply_rows_with_bad_time_values_are_dropped() -> None:
    times = TRUTH.times.copy()
    times[5] = np.nan
    truth = FreeTimeTruth(TRUTH.gaussians, times, TRUTH.log_sigma, TRUTH.velocity)
    loaded = parse_freetimegs_ply(freetime_ply(truth))
    assert len(loaded.scene) == len(TRUTH.gaussians) - 1
    assert any(f"dropped 1 of {len(times)}" in n for n in loaded.notes)


def test_is_freetimegs_ply_on_header_and_contents() -> None:
    data = freetime_ply(TRUTH)
    assert is_freetimegs_ply(parse_header(data))
    assert is_freetimegs_ply(parse_ply(data))
    plain = ply_bytes(TRUTH.gaussians)
    assert not is_freetimegs_ply(parse_header(plain))
    with pytest.raises(FormatError, match="not a FreeTimeGS PLY"):
        parse_freetimegs_ply(plain)


# --- npz -------------------------------------------------------------------------------------


def test_npz_matches_the_equations_with_the_duration_floor() -> None:
    loaded = parse_freetimegs_npz(freetime_npz(TRUTH), scene_length_s=2.0)
    assert loaded.scene.timeline is not None
    assert loaded.scene.timeline.t1.min() >= MIN_DURATION * 2.0 - 1e-12
    _check_against_truth(loaded, TRUTH, 2.0, min_sigma=MIN_DURATION)


def test_a_large_npz_file_is_read_within_1_6_times_its_arrays(tmp_path: Path) -> None:
    """From an open file, member by member into float32 arrays: the reader's own allocations
    peak below 1.6x the scene's arrays (1.49x measured: the float64 times and velocities, a
    block being read; as bytes and float64 they peaked at about 5x), and the scene equals the
    one parsed from bytes."""
    truth = freetime_truth(n=60_000, sh_bands=3)
    path = tmp_path / "big.npz"
    path.write_bytes(freetime_npz(truth))
    raw = sum(a.nbytes for a in vars(truth.gaussians).values())
    tracemalloc.start()
    try:
        with open(path, "rb") as file:
            loaded = parse_freetimegs_npz(file, scene_length_s=2.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1.6 * raw, (peak / raw, raw)
    again = parse_freetimegs_npz(path.read_bytes(), scene_length_s=2.0)
    for name in ("means", "scales", "quats", "opacities", "sh0", "shN"):
        assert np.array_equal(
            getattr(loaded.scene.gaussians, name), getattr(again.scene.gaussians, name)
        )
    assert loaded.scene.gaussians.shN.shape == (60_000, 15, 3)


def test_npz_accepts_flat_shapes_no_sh_and_use_velocity() -> None:
    n = len(TRUTH.gaussians)
    data = freetime_npz(
        TRUTH,
        opacities=TRUTH.gaussians.opacities.reshape(n, 1),
        sh0=TRUTH.gaussians.sh0,
        times=TRUTH.times,
        shN=None,
        use_velocity=np.array(False),
    )
    loaded = parse_freetimegs_npz(data)
    assert loaded.scene.gaussians.sh_bands == 0 and "means" not in loaded.scene.temporal
    visible, means, _ = freetime_expected(TRUTH, 0.5, 1.0, min_sigma=0.02, use_velocity=False)
    np.testing.assert_allclose(loaded.scene.at(0.5).means, means, rtol=1e-6)
    assert len(loaded.scene.at(0.5)) == visible.sum()


def test_npz_non_finite_base_values_are_kept_and_noted() -> None:
    means = TRUTH.gaussians.means.copy()
    means[3, 1] = np.inf
    loaded = parse_freetimegs_npz(freetime_npz(TRUTH, means=means))
    assert len(loaded.scene) == len(TRUTH.gaussians)
    assert "kept 1 Gaussians with non-finite base values as read" in loaded.notes


def test_npz_sniffing() -> None:
    assert sniff_freetimegs_npz(freetime_npz(TRUTH))
    assert not sniff_freetimegs_npz(freetime_npz(TRUTH, times=None))
    assert not sniff_freetimegs_npz(b"PK\x03\x04 not really a zip")
    assert not sniff_freetimegs_npz(freetime_ply(TRUTH))


@pytest.mark.parametrize("key", ["means", "times", "durations", "velocities", "sh0"])
def test_npz_missing_key_is_named(key: str) -> None:
    with pytest.raises(FormatError, match=key):
        parse_freetimegs_npz(freetime_npz(TRUTH, **{key: None}))


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("velocities", np.zeros((48, 2), np.float32)),
        ("times", np.zeros((47, 1), np.float32)),
        ("quats", np.zeros((48, 3), np.float32)),
        ("shN", np.zeros((48, 5, 3), np.float32)),
        ("durations", np.zeros((48, 1), np.int32)),
        ("means", np.array(["a"] * 48)),
        ("means", np.float32(1.0)),
    ],
)
def test_npz_wrong_shape_or_dtype_is_named(key: str, value: npt.NDArray[np.generic]) -> None:
    with pytest.raises(FormatError, match=key):
        parse_freetimegs_npz(freetime_npz(TRUTH, **{key: value}))


def test_npz_pickled_objects_are_refused() -> None:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for key in ("means", "scales", "quats", "opacities", "sh0", "times", "durations"):
            with zf.open(f"{key}.npy", "w") as f:
                np.lib.format.write_array(f, np.zeros((2, 3), np.float32))
        with zf.open("velocities.npy", "w") as f:
            np.lib.format.write_array(f, np.array([{}, {}], dtype=object), allow_pickle=True)
    with pytest.raises(FormatError, match="velocities"):
        parse_freetimegs_npz(buffer.getvalue())


def test_npz_huge_declared_shape_fails_before_allocating() -> None:
    header = {"descr": "<f4", "fortran_order": False, "shape": (10**12, 3)}
    data = freetime_npz(TRUTH)
    with zipfile.ZipFile(io.BytesIO(data)) as src:
        members = {n: src.read(n) for n in src.namelist()}
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for member, content in members.items():
            if member == "means.npy":
                with zf.open(member, "w") as f:
                    np.lib.format.write_array_header_1_0(f, header)
                    f.write(b"\0" * 24)
            else:
                zf.writestr(member, content)
    with pytest.raises(FormatError, match="means"):
        parse_freetimegs_npz(buffer.getvalue())


def test_npz_garbage_and_truncation_raise_format_errors() -> None:
    data = freetime_npz(TRUTH)
    for bad in (
        b"",
        b"garbage" * 10,
        data[: len(data) // 2],
        data[:-30],
        b"PK\x03\x04" + data[4:100],
    ):
        with pytest.raises(FormatError):
            parse_freetimegs_npz(bad)


def _member_data(data: bytes, member: str) -> tuple[int, int]:
    """(offset, length) of a stored member's bytes in an npz."""
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        info = zf.getinfo(member)
    name_length, extra_length = struct.unpack_from("<HH", data, info.header_offset + 26)
    return info.header_offset + 30 + name_length + extra_length, info.file_size


def test_a_local_npz_file_reads_its_stored_members_as_its_bytes_do(tmp_path: Path) -> None:
    """From a file, stored members are read straight into their arrays (two at a time) and
    compressed ones through zipfile: both give what parsing the bytes gives."""
    truth = freetime_truth(n=3000, sh_bands=2)
    stored = tmp_path / "stored.npz"
    stored.write_bytes(freetime_npz(truth))
    compressed = tmp_path / "compressed.npz"
    with zipfile.ZipFile(io.BytesIO(stored.read_bytes())) as src:
        arrays = {n.removesuffix(".npy"): np.load(io.BytesIO(src.read(n))) for n in src.namelist()}
    np.savez_compressed(compressed, **arrays)
    want = parse_freetimegs_npz(stored.read_bytes()).scene
    for path in (stored, compressed):
        with open(path, "rb") as file:
            got = parse_freetimegs_npz(file).scene
        for name in ("means", "scales", "quats", "opacities", "sh0", "shN"):
            assert np.array_equal(getattr(got.gaussians, name), getattr(want.gaussians, name))
        assert got.timeline is not None and want.timeline is not None
        assert np.array_equal(got.timeline.t0, want.timeline.t0)
        assert np.array_equal(got.temporal["means"], want.temporal["means"])


def test_a_damaged_or_cut_npz_file_is_a_format_error_naming_the_array(tmp_path: Path) -> None:
    """A changed byte inside a stored member fails its CRC-32 (a FormatError naming the
    array, as zipfile's own reading says); a file cut inside a member is no readable zip."""
    data = freetime_npz(freetime_truth(n=3000, sh_bands=1))
    offset, length = _member_data(data, "shN.npy")
    damaged = bytearray(data)
    damaged[offset + length - 7] ^= 0x40
    cases = {"damaged": bytes(damaged), "cut": data[: offset + length // 2]}
    for label, content in cases.items():
        path = tmp_path / f"{label}.npz"
        path.write_bytes(content)
        with open(path, "rb") as file, pytest.raises(FormatError) as error:
            parse_freetimegs_npz(file, name=str(path))
        expected = "shN.*CRC-32" if label == "damaged" else "not a readable npz"
        assert re.search(expected, str(error.value)), (label, error.value)


def test_a_member_declaring_gigabytes_past_its_array_is_read_in_bounded_memory(
    tmp_path: Path,
) -> None:
    """A stored member whose zip entry declares 3 GB (its array a few kB): the bytes past the
    array are checked a block at a time up to the file's end, never allocated as declared,
    and the CRC-32 then fails: a FormatError naming the array."""
    data = bytearray(freetime_npz(freetime_truth(n=500, sh_bands=1)))
    entry = data.find(b"shN.npy", data.find(b"PK\x01\x02"))  # its central directory name
    start = data.rfind(b"PK\x01\x02", 0, entry)
    assert start >= 0
    struct.pack_into("<II", data, start + 20, 3 << 30, 3 << 30)  # compressed, uncompressed
    path = tmp_path / "declares.npz"
    path.write_bytes(bytes(data))
    tracemalloc.start()
    try:
        with open(path, "rb") as file, pytest.raises(FormatError, match="shN"):
            parse_freetimegs_npz(file, name=str(path))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20, peak


def _with_member(data: bytes, member: str, write: Callable[[IO[bytes]], None]) -> bytes:
    """``data`` (an npz) with ``member`` rewritten by ``write``, deflated."""
    with zipfile.ZipFile(io.BytesIO(data)) as src:
        members = {n: src.read(n) for n in src.namelist()}
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for name, content in members.items():
            if name == member:
                with zf.open(zipfile.ZipInfo(name), "w") as f:
                    write(f)
            else:
                zf.writestr(name, content)
    return buffer.getvalue()


def test_npz_negative_dimension_is_a_format_error_naming_the_array() -> None:
    """A header may declare (-4, 3): its product is negative, under any size check."""
    header = {"descr": "<f4", "fortran_order": False, "shape": (-4, 3)}

    def lying(f: IO[bytes]) -> None:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(b"\0" * 48)

    data = _with_member(freetime_npz(TRUTH), "means.npy", lying)
    with pytest.raises(FormatError, match="means: negative dimension"):
        parse_freetimegs_npz(data, name="neg.npz")


def test_npz_zip_bomb_is_refused_before_inflating() -> None:
    """A deflated member claiming 4 GB from a few kB (past deflate's 1032:1), its header
    declaring an array of that size: refused by its claim, nothing allocated."""
    header = {"descr": "<f4", "fortran_order": False, "shape": (10**9,)}

    def bomb(f: IO[bytes]) -> None:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(b"\0" * (1 << 16))

    with zipfile.ZipFile(io.BytesIO(freetime_npz(TRUTH))) as src:
        members = {n: src.read(n) for n in src.namelist()}
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, content in members.items():
            if name == "shN.npy":
                with zf.open(name, "w") as f:
                    bomb(f)
            else:
                zf.writestr(name, content)
    data = bytearray(buffer.getvalue())
    entry = data.find(b"shN.npy", data.find(b"PK\x01\x02"))
    start = data.rfind(b"PK\x01\x02", 0, entry)
    struct.pack_into("<I", data, start + 24, 4 * 10**9 + 200)  # uncompressed size
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match=r"bomb.npz: shN: claims 4000000200 bytes"):
            parse_freetimegs_npz(bytes(data), name="bomb.npz")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 * len(data) + (1 << 20), peak


def test_npz_with_too_many_members_is_refused_by_count() -> None:
    buffer = io.BytesIO(freetime_npz(TRUTH))
    with zipfile.ZipFile(buffer, "a") as zf:
        for i in range(MAX_ENTRIES):
            zf.writestr(f"pad{i}.npy", b"")
    with pytest.raises(FormatError, match="members, more than"):
        parse_freetimegs_npz(buffer.getvalue(), name="many.npz")


def test_npz_without_a_length_says_it_was_assumed() -> None:
    """Like a .splatv: the note first and ``duration_assumed``, so tsog info, the player's
    list and the index say "(assumed)"."""
    loaded = parse_freetimegs_npz(freetime_npz(TRUTH))
    assert loaded.duration_assumed and "--scene-length-s" in loaded.notes[0]
    assert not parse_freetimegs_npz(freetime_npz(TRUTH), scene_length_s=1.0).duration_assumed
    assert parse_freetimegs_ply(freetime_ply(TRUTH)).duration_assumed

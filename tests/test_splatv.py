"""splaTV reader: the viewer's equations on hand-built records, real files, hostile bytes."""

from __future__ import annotations

import contextlib
import math
import re
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from fixtures_4d import splatv_bytes, splatv_records
from tsog_stream import FormatError, InputError
from tsog_stream.constants import SH_C0, VISIBILITY_THRESHOLD
from tsog_stream.io.ply import parse_ply, ply_bytes
from tsog_stream.io.readers import ReadOptions, load_scene
from tsog_stream.io.splatv import (
    ASSUMED_DURATION,
    F16_TINY,
    parse_splatv,
    read_splatv,
    sniff_splatv,
)
from tsog_stream.model import Scene, TimelineType

NONFINITE = {  # PROVENANCE.md: (non-finite positions, count)
    "macaburguera_coffeeshort2": (190, 6871),
    "macaburguera_coffee10": (24, 11926),
    "macaburguera_yellow_clip2": (122, 51773),
    "macaburguera_spinach_4": (0, 62442),
    "tztechno_hanabi2_synthetic": (0, 24576),
}
F64 = npt.NDArray[np.float64]


def _two_gaussians() -> npt.NDArray[np.void]:
    """A: moving, rotating, fading; B: zero rotation, infinite temporal scale, a zero scale."""
    r = splatv_records(2)
    r["position"] = [[1, 2, 3], [-1, 0, 0]]
    r["rotation"][0] = [0.75, 0.0, 0.5, 0.0]  # w, x, y, z (exact in float16)
    r["scale"] = [[0.5, 0.25, 2.0], [0.125, 0.0, 1.0]]
    r["rgba"] = [[255, 128, 0, 204], [0, 51, 255, 255]]
    r["motion"][0] = [1, 0, 0, 0, 2, 0, 0, 0, 4]  # linear x, quadratic y, cubic z
    r["omega"][0] = [0.0, 0.5, 0.0, 0.0]
    r["trbf_center"] = [0.5, 0.25]
    r["trbf_scale"] = [0.25, np.inf]
    return r


def _viewer(t_n: float) -> tuple[F64, F64, F64]:
    """What splaTV's shader computes for A and B at normalised time t_n: (means, quats, alpha)."""
    dt = t_n - 0.5
    means = np.array([[1 + dt, 2 + 2 * dt**2, 3 + 4 * dt**3], [-1, 0, 0]], np.float64)
    q = np.array([0.75, 0.5 * dt, 0.5, 0.0])
    quats = np.array([q / np.linalg.norm(q), [1, 0, 0, 0]])
    alpha = np.array([0.8 * math.exp(-((dt / 0.25) ** 2)), 1.0])
    return means, quats, alpha


@pytest.mark.parametrize("duration_s", [None, 2.0])
def test_hand_built_records_follow_the_viewer(duration_s: float | None) -> None:
    loaded = parse_splatv(splatv_bytes(_two_gaussians()), duration_s=duration_s)
    d = duration_s or 1.0
    scene = loaded.scene
    assert scene.timeline is not None and scene.timeline.type is TimelineType.CENTER_SCALE
    assert scene.timeline.scene_length == d
    np.testing.assert_allclose(scene.timeline.t1[0], 0.25 * d / math.sqrt(2))
    assert scene.temporal["means"].shape == (2, 3, 3) and scene.temporal["quats"].shape == (2, 1, 4)
    for t_n in (0.0, 0.2, 0.5, 0.73, 1.0):
        got = scene.at(t_n * d)
        means, quats, alpha = _viewer(t_n)
        visible = np.array([alpha[0] / 0.8 >= VISIBILITY_THRESHOLD, True])
        assert len(got) == visible.sum()
        np.testing.assert_allclose(got.means, means[visible], atol=1e-6)
        np.testing.assert_allclose(got.quats, quats[visible], atol=1e-6)
        got_alpha = 1 / (1 + np.exp(-got.opacities.astype(np.float64)))
        np.testing.assert_allclose(got_alpha, np.minimum(alpha, 1 - 1e-6)[visible], rtol=1e-5)
    g = scene.gaussians
    np.testing.assert_allclose(g.scales, np.log([[0.5, 0.25, 2.0], [0.125, F16_TINY, 1.0]]))
    colour = np.array([[255, 128, 0], [0, 51, 255]]) / 255
    np.testing.assert_allclose(0.5 + SH_C0 * g.sh0, colour, atol=1e-6)
    assert any("identity" in n for n in loaded.notes)
    assert any("infinite temporal scales" in n for n in loaded.notes)


def test_visibility_edge_is_the_viewer_gaussian_with_sigma_s_over_root2() -> None:
    scene = parse_splatv(splatv_bytes(_two_gaussians()[:1])).scene
    half = 0.25 * math.sqrt(math.log(255.0))  # exp(-(dt/s)^2) = 1/255
    assert len(scene.at(0.5 + half * 0.9999)) == 1
    assert len(scene.at(0.5 + half * 1.0001)) == 0
    assert len(scene.at(0.5 - half * 0.9999)) == 1


def test_invalid_records_are_dropped_with_notes() -> None:
    r = np.concatenate([_two_gaussians(), splatv_records(3)])
    r["position"][2] = [np.nan, 0, 0]
    r["rotation"][3:] = [1, 0, 0, 0]
    r["motion"][3] = [np.inf, 0, 0, 0, 0, 0, 0, 0, 0]
    r["trbf_scale"][2:4] = 1.0
    r["trbf_scale"][4] = 0.0  # zero padding: never visible
    loaded = parse_splatv(splatv_bytes(r))
    assert len(loaded.scene) == 2
    notes = " | ".join(loaded.notes)
    assert "dropped 1 of 5 Gaussians with non-finite positions" in notes
    assert "dropped 1 of 5 Gaussians with non-finite rotation" in notes
    assert "dropped 1 of 5 Gaussians with a temporal scale <= 0" in notes


def test_zero_rotation_with_a_rate_becomes_that_rate() -> None:
    r = _two_gaussians()
    r["omega"][1] = [0, 0, 0.375, 0.5]  # exact in float16
    scene = parse_splatv(splatv_bytes(r)).scene
    for t in (0.0, 0.6, 1.0):
        np.testing.assert_allclose(scene.at(t).quats[-1], [0, 0, 0.6, 0.8], atol=1e-6)


def test_all_zero_motion_is_omitted_and_sniffing() -> None:
    r = _two_gaussians()
    r["motion"], r["omega"] = 0, 0
    data = splatv_bytes(r)
    assert parse_splatv(data).scene.temporal == {}
    assert sniff_splatv(data[:8]) and not sniff_splatv(b"ply\n") and not sniff_splatv(b"Kg")


def test_short_payload_and_extra_chunks_are_noted() -> None:
    r = _two_gaussians()
    extra = [{"type": "splat", "size": 128 * 64}, {"type": "other", "size": 0}]
    loaded = parse_splatv(splatv_bytes(r, chunks=extra))
    assert len(loaded.scene) == 2
    assert any("ignored chunk 1" in n for n in loaded.notes)
    loaded = parse_splatv(splatv_bytes(r, slots=4096))
    assert any("declares 4096 slots but holds 2" in n for n in loaded.notes)
    assert any(
        "bytes after the last chunk" in n for n in parse_splatv(splatv_bytes(r, slots=1)).notes
    )


# --- real files ------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=sorted(NONFINITE))
def real(request: pytest.FixtureRequest, optional_samples: Path) -> tuple[str, list[str], Scene]:
    """A real Spacetime Gaussians capture (optional: derived from N3DV, CC-BY-NC-4.0)."""
    name: str = request.param
    loaded = read_splatv(optional_samples / "4d" / "splatv" / f"{name}.splatv")
    return name, loaded.notes, loaded.scene


def test_real_files_nonfinite_counts_match_provenance(
    real: tuple[str, list[str], Scene],
) -> None:
    name, notes, scene = real
    nonfinite, count = NONFINITE[name]
    found = [
        re.fullmatch(r"dropped (\d+) of (\d+) Gaussians with non-finite positions", n)
        for n in notes
    ]
    hits = [(int(m[1]), int(m[2])) for m in found if m]
    assert hits == ([(nonfinite, count)] if nonfinite else [])
    padding = 576 if name.startswith("tztechno") else 0  # zero records filling the texture
    assert len(scene) == count - nonfinite - padding


def test_real_files_have_plausible_values(real: tuple[str, list[str], Scene]) -> None:
    _, _, scene = real
    g, tl = scene.gaussians, scene.timeline
    assert tl is not None
    for values in (g.means, g.scales, g.quats, g.opacities, g.sh0, tl.t0, tl.t1):
        assert np.isfinite(values).all()
    for coeffs in scene.temporal.values():
        assert np.isfinite(coeffs).all()
    norms = np.linalg.norm(g.quats, axis=1)
    assert norms.min() > 0 and 0.5 < np.median(norms) < 2.0
    assert g.scales.max() < math.log(70000) and g.scales.min() >= math.log(F16_TINY) - 1e-6
    assert tl.t0.min() > -0.2 and tl.t0.max() < 1.2  # trbf centres: normalised time


def test_real_files_stay_bounded_over_the_clip(real: tuple[str, list[str], Scene]) -> None:
    """A misread motion field flies apart; the real ones stay near the base bounding box."""
    _, _, scene = real
    lo, hi = np.percentile(scene.gaussians.means, [1, 99], axis=0)
    margin = hi - lo
    for t in np.linspace(0.0, 1.0, 5):
        means = scene.at(float(t)).means
        inside = ((means > lo - margin) & (means < hi + margin)).all(axis=1)
        assert len(means) > 0.5 * len(scene) or len(means) >= 4000
        assert inside.mean() > (0.999 if t == 0.5 else 0.99)  # clip ends: cubic tails


def test_hanabi_frames_are_the_source_plys(samples: Path) -> None:
    """tztechno's converter put frame k's PLY at centre k: compare against those PLYs."""
    scene = read_splatv(samples / "4d" / "splatv" / "tztechno_hanabi2_synthetic.splatv").scene
    assert scene.timeline is not None
    centres = np.unique(scene.timeline.t0)
    assert len(centres) == 6
    for k, centre in enumerate(centres):
        path = samples / "4d" / "tztechno_fireworks_frames" / f"frame_{k:03d}.ply"
        ply = parse_ply(path.read_bytes()).gaussians
        ours = scene.gaussians.subset(scene.timeline.t0 == centre)
        a, b = np.lexsort(ours.means.T[::-1]), np.lexsort(ply.means.T[::-1])
        np.testing.assert_array_equal(ours.means[a], ply.means[b])
        np.testing.assert_allclose(ours.scales[a], ply.scales[b], atol=1e-3)  # f16 rounding
        np.testing.assert_allclose(ours.quats[a], ply.quats[b])
        alpha_ours = 1 / (1 + np.exp(-ours.opacities[a].astype(np.float64)))
        alpha_ply = 1 / (1 + np.exp(-ply.opacities[b].astype(np.float64)))
        assert np.all((alpha_ply - alpha_ours >= -1e-6) & (alpha_ply - alpha_ours < 1 / 255))
        colour_ply = 0.5 + SH_C0 * ply.sh0[b].astype(np.float64)
        colour_ours = 0.5 + SH_C0 * ours.sh0[a].astype(np.float64)
        _, index, counts = np.unique(ply.means[b], axis=0, return_inverse=True, return_counts=True)
        unique = (counts[index] == 1)[:, None]  # rows at a shared position may pair up wrongly
        unclipped = (colour_ply >= 0) & (colour_ply < 1) & unique
        diff = (colour_ply - colour_ours)[unclipped]
        assert np.all((diff >= -1e-6) & (diff < 1 / 255 + 1e-6))


# --- hostile bytes ---------------------------------------------------------------------------


def test_wrong_magic_short_and_garbage_inputs() -> None:
    good = splatv_bytes(_two_gaussians())
    bad_inputs = [
        b"",
        b"Kg\0",
        good[:7],
        b"\0" * 64,
        ply_bytes(parse_splatv(good).scene.gaussians),
        struct.pack("<II", 0x674B, 2) + b"{}",
        struct.pack("<II", 0x674B, 4) + b"\xff\xfe{]",
        struct.pack("<II", 0x674B, 2) + b"[]",
        struct.pack("<II", 0x674B, 12) + b'[{"size":1}]',
        struct.pack("<II", 0x674B, 24) + b'[{"type":"a","size":-1}]',
        struct.pack("<II", 0x674B, 26) + b'[{"type":"a","size":true}]',
        struct.pack("<II", 0x674B, 28) + b'[{"type":"splat","size":65}]',
        splatv_bytes(
            _two_gaussians(), chunks=[{"type": "x", "size": 10**9}, {"type": "splat", "size": 64}]
        ),
    ]
    for bad in bad_inputs:
        with pytest.raises(FormatError):
            parse_splatv(bad)


def test_every_truncation_is_a_format_error_or_a_shorter_scene() -> None:
    good = splatv_bytes(_two_gaussians())
    json_end = 8 + struct.unpack_from("<I", good, 4)[0]
    for cut in range(len(good)):
        if cut >= json_end and (cut - json_end) % 64 == 0:
            assert len(parse_splatv(good[:cut]).scene) == (cut - json_end) // 64
        else:
            with pytest.raises(FormatError):
                parse_splatv(good[:cut])


def test_random_garbage_never_escapes_as_another_exception() -> None:
    rng = np.random.default_rng(3)
    good = bytearray(splatv_bytes(_two_gaussians()))
    for _ in range(300):
        mutated = bytearray(good)
        for pos in rng.integers(0, 40, size=3):  # the preamble and JSON
            mutated[pos] = int(rng.integers(0, 256))
        with contextlib.suppress(FormatError):
            parse_splatv(bytes(mutated))


def test_huge_json_length_fails_without_allocating() -> None:
    data = struct.pack("<II", 0x674B, 0xFFFFFFFF) + b"[" * 8
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match="JSON length"):
            parse_splatv(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


def test_duration_must_be_positive() -> None:
    data = splatv_bytes(_two_gaussians())
    for bad in (0.0, -2.0, math.nan, math.inf):
        with pytest.raises(InputError, match="duration_s"):
            parse_splatv(data, duration_s=bad)


def test_a_length_read_without_duration_s_is_flagged_as_assumed(samples: Path) -> None:
    """A .splatv does not say its length: read without duration_s it is 1 s, and the reader
    says that it assumed it (Loaded4D, then LoadedScene, carry it to the segmenter)."""
    data = splatv_bytes(_two_gaussians())
    assumed = parse_splatv(data)
    assert assumed.duration_assumed is True and assumed.notes[0] == ASSUMED_DURATION
    assert assumed.scene.timeline is not None and assumed.scene.timeline.scene_length == 1.0
    given = parse_splatv(data, duration_s=3.0)
    assert given.duration_assumed is False and ASSUMED_DURATION not in given.notes
    clip = samples / "4d/splatv/tztechno_hanabi2_synthetic.splatv"
    assert load_scene(clip).duration_assumed is True
    assert load_scene(clip, options=ReadOptions(duration_s=2.0)).duration_assumed is False
    assert load_scene(samples / "3dgs/gs3d_pr477_lod5_tile_0.ply").duration_assumed is False

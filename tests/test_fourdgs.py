""".4dgs through the fourdgs package: both directions, refusals, and the missing-extra error.

Tolerances are the file's own: fourdgs quantises every attribute on a grid whose pitch is twice
a declared bound (its Quantization record), so positions are within ``pos``, colours and alpha
within ``rgb``/``alpha``, scales and sigma within a relative ``scale_rel``/``sigma_rel``, rotation
components within ``rot``, SH within half a byte step (4/255), and a velocity within half of its
per-Gaussian pitch (``step_motion`` refined by the Gaussian's life class). Positions at time t
are therefore within pos + half pitch x |t - mu_t|.
"""

from __future__ import annotations

import importlib
import io
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream import FormatError, InputError, Scene, TimelineType, UnsupportedError
from tsog_stream.constants import SH_C0
from tsog_stream.io.fourdgs import encode_4dgs, parse_4dgs, read_4dgs, sniff_4dgs, write_4dgs
from tsog_stream.model import evaluate_all
from tsog_stream.synthetic import small_scene, static_gaussians

F64 = npt.NDArray[np.float64]
FLOAT32 = 1e-5
"""Slack for float32 storage of positions and times (scene extent ~10 units)."""
TIMES = (0.05, 0.5, 0.9, 1.3, 1.85)


@pytest.fixture(scope="module")
def fd() -> ModuleType:
    """The fourdgs package: its absence is a failure (the test command installs the extra)."""
    try:
        return importlib.import_module("fourdgs")
    except ImportError:
        pytest.fail("fourdgs is not installed: pip install -e '.[4dgs]'")


def _sigmoid(x: npt.ArrayLike) -> F64:
    return np.asarray(1.0 / (1.0 + np.exp(-np.asarray(x, np.float64))), np.float64)


def _bounds(fd: ModuleType, data: bytes) -> tuple[dict[str, float], Any]:
    """The file's declared bounds and its Quantization record."""
    quant = fd.read(data).quantization
    return {k: float(v) for k, v in quant.bounds.items()}, quant


def _velocity_half_pitch(fd: ModuleType, quant: Any, scene: Scene, never: bool) -> F64:
    """Half the per-Gaussian velocity pitch fourdgs used (spec section 6.3 life classes)."""
    q = fd.quantization
    tl = scene.timeline
    assert tl is not None
    n = len(scene)
    if never:
        q_sigma, win = np.zeros(n), tl.t1 * tl.seconds_per_unit
    else:
        q_sigma, win = np.rint(np.log(tl.t1) / quant.step_sigma_log), np.ones(n)
    never_fades = np.full(n, never)
    classes = q.life_class(q_sigma, quant.step_sigma_log, never_fades, win, q.support_k(1 / 255))
    return np.asarray(q.motion_steps(classes, quant.step_motion), np.float64) / 2


def test_sniff() -> None:
    data, _ = encode_4dgs(small_scene(TimelineType.CENTER_SCALE, motion_order=1))
    assert sniff_4dgs(data) and sniff_4dgs(b"\x894DGS2\r\n")
    assert not sniff_4dgs(b"ply\nformat") and not sniff_4dgs(b"PK\x03\x04") and not sniff_4dgs(b"")


def test_type2_linear_motion_round_trip(fd: ModuleType, tmp_path: Path) -> None:
    scene = small_scene(TimelineType.CENTER_SCALE, motion_order=1, dynamic=("means",))
    path = tmp_path / "scene.4dgs"
    notes = write_4dgs(path, scene, keep_order=True)
    assert all("clipped" in n for n in notes)  # colours outside [0, 1] only
    back = read_4dgs(path)
    assert back.notes == []  # cutoff 1/255 and no windows: nothing to report
    got = back.scene
    bounds, quant = _bounds(fd, path.read_bytes())
    a, b, ta, tb = scene.gaussians, got.gaussians, scene.timeline, got.timeline
    assert ta is not None and tb is not None and tb.type is TimelineType.CENTER_SCALE
    assert tb.scene_length == pytest.approx(ta.scene_length)
    # static attributes, each within its declared bound
    qa = a.quats / np.linalg.norm(a.quats, axis=1, keepdims=True)
    sign = np.sign(np.sum(qa * b.quats, axis=1, keepdims=True))
    assert np.abs(qa - sign * b.quats).max() <= bounds["rot"] * 2 + 1e-6
    assert np.abs(a.scales - b.scales).max() <= np.log1p(bounds["scale_rel"]) + 1e-6
    assert np.abs(_sigmoid(a.opacities) - _sigmoid(b.opacities)).max() <= bounds["alpha"] + 1e-6
    rgb = 0.5 + SH_C0 * a.sh0.astype(np.float64)
    inside = np.all((rgb >= 0) & (rgb <= 1), axis=1)
    assert np.abs(a.sh0 - b.sh0)[inside].max() <= bounds["rgb"] / SH_C0 + 1e-5
    assert np.abs(a.shN - b.shN).max() <= 4 / 255 + 1e-6
    # timeline: sigma relative bound; centre moved onto the mu grid (<= 2.5 % of sigma)
    assert np.abs(np.log(ta.t1 / tb.t1)).max() <= np.log1p(bounds["sigma_rel"]) + 1e-6
    assert np.all(np.abs(ta.t0 - tb.t0) <= 0.025 * ta.t1 + FLOAT32)
    # trajectories at several t, and opacity at t (fade shifts by the centre/scale error)
    half_pitch = _velocity_half_pitch(fd, quant, got, never=False)
    velocity_err = np.abs(scene.temporal["means"][:, 0] - got.temporal["means"][:, 0])
    assert np.all(velocity_err <= half_pitch[:, None] + 1e-6)
    for t in TIMES:
        ga, _ = evaluate_all(scene, t)
        gb, _ = evaluate_all(got, t)
        tol = bounds["pos"] + half_pitch * np.abs(t - tb.t0) + FLOAT32
        assert np.all(np.abs(ga.means - gb.means) <= tol[:, None])
        fade_err = np.abs(_sigmoid(ga.opacities) - _sigmoid(gb.opacities))
        assert fade_err.max() <= bounds["alpha"] + 0.03


@pytest.mark.parametrize("kind", [TimelineType.FRAME, TimelineType.START_DURATION])
def test_types_0_and_1_become_exact_windows(fd: ModuleType, kind: TimelineType) -> None:
    scene = small_scene(kind, motion_order=1, dynamic=("means",))
    data, notes = encode_4dgs(scene, keep_order=True)
    assert any("reads back as type 1" in n and "fps 5 is not kept" in n for n in notes)
    got = parse_4dgs(data).scene
    ta, tb = scene.timeline, got.timeline
    assert ta is not None and tb is not None and tb.type is TimelineType.START_DURATION
    assert tb.fps is None
    length = np.ones(len(scene)) if kind is TimelineType.FRAME else ta.t1
    np.testing.assert_allclose(tb.t0, ta.t0 / ta.fps, atol=1e-12)  # type: ignore[operator]
    np.testing.assert_allclose(tb.t1, length / ta.fps, atol=1e-12)  # type: ignore[operator]
    bounds, quant = _bounds(fd, data)
    half_pitch = _velocity_half_pitch(fd, quant, got, never=True)
    for t in (0.05, 0.45, 1.01, 1.55, 1.95):  # away from frame edges (multiples of 0.2 s)
        ga, ma = evaluate_all(scene, t)
        gb, mb = evaluate_all(got, t)
        assert np.array_equal(ma, mb)
        tol = bounds["pos"] * 1.01 + half_pitch * np.abs(t - tb.t0) + FLOAT32
        assert np.all(np.abs(ga.means - gb.means)[ma] <= tol[ma, None])


def test_file_written_by_fourdgs_matches_its_own_state_at(fd: ModuleType, samples: Path) -> None:
    convert = importlib.import_module("fourdgs.convert")  # its PLY-sequence importer
    fps = 30.0
    gaussians, duration = convert.convert_ply_sequence(
        str(samples / "4d" / "tztechno_fireworks_frames"), fps=fps
    )
    buffer = io.BytesIO()
    fd.write(buffer, gaussians, duration)
    data = buffer.getvalue()
    reference = fd.read(data)
    loaded = parse_4dgs(data)
    assert any("cuts their fade" in n for n in loaded.notes)
    assert any("threshold=0.05" in n for n in loaded.notes)
    cutoff = float(reference.header.cutoff)
    scene = loaded.scene
    assert len(scene) == 24000 and scene.timeline is not None
    assert scene.timeline.scene_length == pytest.approx(duration)
    for frame in range(6):
        for offset in (0.2, 0.5, 0.8):  # inside the frame's slot, away from its edges
            t = (frame + offset) / fps
            state = reference.state_at(t)
            ours, mask = evaluate_all(scene, t, threshold=cutoff)
            assert np.array_equal(np.flatnonzero(mask), state["indices"])
            seen = ours.subset(mask)
            assert np.abs(seen.means - state["centers"]).max() <= FLOAT32
            assert np.abs(_sigmoid(seen.opacities) - state["opacity"]).max() <= 1e-5
            theirs = np.asarray(state["orientations"])[:, [3, 0, 1, 2]]
            assert np.abs(np.abs(np.sum(seen.quats * theirs, axis=1)) - 1).max() <= 1e-6
            _, wider = evaluate_all(scene, t)
            assert np.all(wider[mask])  # TSOG's 1/255 threshold shows a superset


def test_motion_4dgs_cannot_hold_is_refused_or_dropped() -> None:
    order2 = small_scene(TimelineType.CENTER_SCALE, motion_order=2)
    with pytest.raises(InputError, match="order-2 motion"):
        encode_4dgs(order2)
    _, notes = encode_4dgs(order2, lossy=True)
    assert any(n.startswith("dropped order-2 motion") for n in notes)
    spinning = small_scene(TimelineType.CENTER_SCALE, motion_order=1, dynamic=("means", "quats"))
    with pytest.raises(InputError, match="temporal quats"):
        encode_4dgs(spinning)
    with pytest.raises(InputError, match="profile"):
        encode_4dgs(spinning, profile="best", lossy=True)


def test_static_scene_needs_a_duration(fd: ModuleType) -> None:
    scene = Scene(static_gaussians(50, sh_bands=1))
    with pytest.raises(InputError, match="duration"):
        encode_4dgs(scene)
    data, notes = encode_4dgs(scene, duration=2.0, keep_order=True)
    assert any("never fade" in n for n in notes)
    loaded = parse_4dgs(data)
    tl = loaded.scene.timeline
    assert tl is not None and tl.type is TimelineType.START_DURATION
    assert np.all(tl.t0 == 0.0) and np.all(tl.t1 == 2.0)
    assert any("clipped to it" in n for n in loaded.notes)
    assert len(loaded.scene.at(1.0)) == 50


def test_broken_files_raise_format_errors(fd: ModuleType) -> None:
    data, _ = encode_4dgs(small_scene(TimelineType.CENTER_SCALE, motion_order=1))
    with pytest.raises(FormatError):
        parse_4dgs(data[: len(data) // 2])
    with pytest.raises(FormatError):
        parse_4dgs(b"ply\n" + data[4:])
    with pytest.raises(UnsupportedError):
        parse_4dgs(data[:5] + b"9" + data[6:])


def test_missing_package_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "fourdgs", None)
    with pytest.raises(UnsupportedError, match=r"tsog-stream\[4dgs\]"):
        read_4dgs(b"\x894DGS1\r\n")
    with pytest.raises(UnsupportedError, match=r"tsog-stream\[4dgs\]"):
        encode_4dgs(small_scene(TimelineType.CENTER_SCALE, motion_order=1))

"""Frame sequences stored once: lifespan merging (type 1) and fitted motion, within tolerance."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from helpers import write_ply_frames
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.errors import InputError
from tsog_stream.io.sequence import FrameSequence, open_sequence
from tsog_stream.merge import sequence as sequence_module
from tsog_stream.merge.check import frame_errors
from tsog_stream.merge.features import (
    Steps,
    Tolerance,
    columns,
    quat_tolerance,
    robust_extent,
    tolerances,
)
from tsog_stream.merge.fit import fit_tracks
from tsog_stream.merge.runs import FrameMerger
from tsog_stream.merge.sequence import TemporalMode, merge_frames, merge_sequence, probe_merge
from tsog_stream.model import Gaussians, Scene, TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.synthetic import static_gaussians

FPS = 10.0
FRAMES = 12
F64 = npt.NDArray[np.float64]


def moved(g: Gaussians, offset: npt.ArrayLike) -> Gaussians:
    return Gaussians.from_arrays(
        g.means + np.asarray(offset, np.float32), g.scales, g.quats, g.opacities, g.sh0, shN=g.shN
    )


def write_frames(folder: Path, frames: list[Gaussians], seed: int = 0) -> FrameSequence:
    """Frames as numbered PLYs, each frame's Gaussians in a fresh random order."""
    rng = np.random.default_rng(seed)
    write_ply_frames(folder, (g.subset(rng.permutation(len(g))) for g in frames))
    return open_sequence(folder, fps=FPS)


@pytest.fixture(scope="module")
def parts() -> dict[str, Gaussians]:
    return {
        "static": static_gaussians(3000, sh_bands=1, seed=1),
        "moving": static_gaussians(400, sh_bands=1, seed=2),
        "blink": static_gaussians(200, sh_bands=1, seed=3),
    }


def velocity(n: int) -> F64:
    return np.random.default_rng(9).normal(0, 0.2, (n, 3))  # scene units per second


def sequence_frames(parts: dict[str, Gaussians], *, blink: range = range(3, 8)) -> list[Gaussians]:
    """Static set in every frame, a linearly moving set, and a set alive in ``blink`` only."""
    v = velocity(len(parts["moving"]))
    frames = []
    for k in range(FRAMES):
        members = [parts["static"], moved(parts["moving"], v * k / FPS)]
        if k in blink:
            members.append(parts["blink"])
        frames.append(Gaussians.concat(members))
    return frames


def test_static_set_is_stored_once_and_blinking_set_gets_its_lifespan(
    tmp_path: Path, parts: dict[str, Gaussians]
) -> None:
    seq = write_frames(tmp_path / "seq", sequence_frames(parts))
    scene, stats = merge_sequence(seq, "merge")
    assert scene is not None
    n_static, n_moving, n_blink = (len(parts[k]) for k in ("static", "moving", "blink"))
    assert len(scene) == n_static + n_moving * FRAMES + n_blink
    assert stats.gaussians_in == n_static * FRAMES + n_moving * FRAMES + n_blink * 5
    tl = scene.timeline
    assert tl is not None and tl.type is TimelineType.START_DURATION and tl.fps == FPS
    spans = sorted(zip(tl.t0.tolist(), tl.t1.tolist(), strict=True))
    assert spans.count((0.0, float(FRAMES))) == n_static
    assert spans.count((3.0, 5.0)) == n_blink
    assert spans.count((5.0, 1.0)) == n_moving  # moving ones: one frame each
    assert not scene.temporal


def test_fit_stores_a_linear_mover_once(tmp_path: Path, parts: dict[str, Gaussians]) -> None:
    seq = write_frames(tmp_path / "seq", sequence_frames(parts, blink=range(0)))
    scene, stats = merge_sequence(seq, "fit")
    assert scene is not None
    assert len(scene) == len(parts["static"]) + len(parts["moving"])
    assert stats.moving_out == len(parts["moving"])
    coeffs = scene.temporal["means"]
    moving = np.any(coeffs != 0, axis=(1, 2))
    v = np.sort(velocity(len(parts["moving"])), axis=0)
    np.testing.assert_allclose(np.sort(coeffs[moving, 0], axis=0), v, atol=1e-4)


def matched_errors(source: Gaussians, decoded: Gaussians) -> dict[str, float]:
    """Largest error per attribute after pairing decoded Gaussians with the source's."""
    errors, unpaired = frame_errors(source, decoded)
    assert unpaired == 0
    return errors


@pytest.mark.parametrize("mode", ["merge", "fit"])
def test_every_frame_decodes_within_the_budget(
    tmp_path: Path, parts: dict[str, Gaussians], mode: str
) -> None:
    frames = sequence_frames(parts)
    seq = write_frames(tmp_path / "seq", frames)
    scene, _ = merge_sequence(seq, mode)  # type: ignore[arg-type]
    assert scene is not None
    out = tmp_path / "m.tsogs"
    segment_scene(scene, out, SegmentOptions(window_s=0.5, policy="hybrid", workers=1))
    steps = Steps.of(frames[0])
    tol = tolerances(columns(frames[0]), steps, Tolerance()).max(axis=0)
    with open_stream(out) as reader:
        for k in (0, 4, FRAMES - 1):
            own = decode_chunk(encode_chunk(Scene(frames[k]))).gaussians  # a per-frame SOG
            alone = matched_errors(frames[k], own)
            merged = matched_errors(frames[k], reader.frame_at(k / FPS))
            budget = {
                "means": tol[:3].max(),
                "scales": tol[3],
                "sh0": tol[6],
                "alpha": tol[9],
                "shN": tol[10:].max(),
                "quats": quat_tolerance(Tolerance()),
            }
            for name, value in merged.items():
                assert value <= alone[name] + budget[name] + 1e-6, (k, name, value, alone)


def test_reordered_and_jittered_frames_still_merge(
    tmp_path: Path, parts: dict[str, Gaussians]
) -> None:
    static = parts["static"]
    steps = Steps.of(static)
    tol = tolerances(columns(static), steps, Tolerance())
    rng = np.random.default_rng(4)
    frames = []
    for _ in range(FRAMES):
        jitter = rng.uniform(-0.4, 0.4, (len(static), 3)) * tol[:, 0:3]
        frames.append(moved(static, jitter))
    scene, _ = merge_sequence(write_frames(tmp_path / "seq", frames), "merge")
    assert scene is not None
    assert len(scene) == len(static)


def test_merging_past_the_memory_bound_gives_up(
    tmp_path: Path, parts: dict[str, Gaussians]
) -> None:
    seq = write_frames(tmp_path / "seq", sequence_frames(parts)[:4])
    scene, stats = merge_sequence(seq, "merge", max_held=len(parts["static"]) + 100)
    assert scene is None and stats.frames == 1  # the first frame alone holds more


def test_frames_without_correspondence_are_probed_not_merged(tmp_path: Path) -> None:
    """Independently made frames: a probe of a few frames finds that nothing carries over, so
    the whole sequence is never merged (merging a 50-frame flipbook that way took 85 s)."""
    frames = [static_gaussians(1500, seed=100 + k) for k in range(6)]
    seq = write_frames(tmp_path / "seq", frames)
    for mode in ("merge", "fit"):
        assert probe_merge(seq, mode)[0] is None
        scene, stats = merge_sequence(seq, mode)
        assert scene is None and "not merged" in stats.note and stats.frames == 0
    # merged anyway (no probe), the result is no larger than one Gaussian per frame
    merged_scene, merged_stats = merge_frames(frames, fps=FPS, sh_coeffs=0, mode="merge")
    assert merged_scene is not None and len(merged_scene) == merged_stats.gaussians_in == 9000
    scene = merged_scene
    options = SegmentOptions(window_s=0.5, policy="hybrid", workers=1)
    flip = segment_sequence(seq, tmp_path / "off.tsogs", options)
    merged = segment_scene(scene, tmp_path / "merge.tsogs", options)
    off_size = (tmp_path / "off.tsogs").stat().st_size
    merge_size = (tmp_path / "merge.tsogs").stat().st_size
    assert merge_size <= off_size * 1.02, (merge_size, off_size, flip, merged)


def test_a_probe_that_fitting_finds_nothing_in_is_not_merged_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Fitting looks for everything merging looks for, from the same start: a probe run in
    which fitting paired no Gaussian with the frame before is not merged a second time, and
    the decision is the one both would give."""
    frames = [static_gaussians(1500, seed=200 + k) for k in range(8)]
    for mode in ("merge", "fit"):
        _, stats = merge_frames(frames, fps=FPS, sh_coeffs=0, mode=mode)
        assert stats.pairs == 0 and stats.gaussians_out == stats.gaussians_in
    seq = write_frames(tmp_path / "seq", frames)
    calls: list[str] = []
    real = sequence_module.merge_frames

    def counted(frames: Any, *, mode: TemporalMode, **options: Any) -> Any:
        calls.append(mode)
        return real(frames, mode=mode, **options)

    monkeypatch.setattr(sequence_module, "merge_frames", counted)
    worth, why = probe_merge(seq, "fit")
    assert worth is None and "fit 100%, merge 100%" in why
    assert calls == ["fit"]  # one probe run of 8 frames, fitted once, not merged again


def test_pairs_count_the_gaussians_that_continue_a_run(parts: dict[str, Gaussians]) -> None:
    """Each frame's Gaussians that continue a run from the frame before are counted: a scene
    unchanged over four frames pairs every Gaussian three times."""
    frames = [parts["static"]] * 4
    for mode in ("merge", "fit"):
        _, stats = merge_frames(frames, fps=FPS, sh_coeffs=3, mode=mode)
        assert stats.pairs == 3 * len(parts["static"])
        assert stats.gaussians_out == len(parts["static"])


def test_fit_orders_are_the_lowest_that_fit() -> None:
    t = np.arange(8, dtype=np.float64)
    tracks = np.stack(
        [
            np.stack([np.full(8, 2.0)] * 3, axis=1),
            np.stack([1 + 0.5 * t] * 3, axis=1),
            np.stack([1 + 0.5 * t - 0.1 * t**2] * 3, axis=1),
            np.stack([0.01 * t**3] * 3, axis=1),
            np.stack([np.sin(3 * t)] * 3, axis=1),
        ]
    )
    orders, coeffs, worst = fit_tracks(tracks, np.full((5, 3), 1e-6))
    assert orders.tolist() == [0, 1, 2, 3, -1]
    np.testing.assert_allclose(coeffs[2, :3, 0], [1, 0.5, -0.1], atol=1e-9)
    assert np.all(worst[:4] <= 1e-6) and np.all(worst[4] > 0.1)


def test_bad_options_are_input_errors(tmp_path: Path, parts: dict[str, Gaussians]) -> None:
    with pytest.raises(InputError, match="tolerance"):
        Tolerance(position=-1)
    with pytest.raises(InputError, match="tolerance-steps"):
        Tolerance(steps=float("nan"))
    seq = write_frames(tmp_path / "seq", sequence_frames(parts)[:2])
    with pytest.raises(InputError, match="merge or fit"):
        merge_sequence(seq, "off")


def test_cli_segment_temporal_reports_and_falls_back(
    tmp_path: Path, parts: dict[str, Gaussians], capsys: pytest.CaptureFixture[str]
) -> None:
    write_frames(tmp_path / "seq", sequence_frames(parts))
    out = tmp_path / "fit.tsogs"
    args = ["segment", str(tmp_path / "seq"), "--fps", str(FPS), "-o", str(out), "-q"]
    assert main([*args, "--temporal", "fit", "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert "temporal fit:" in text and "with motion" in text
    assert "worst error after encoding (frames 0, 3, 6, 8, 11)" in text
    with open_stream(out) as reader:
        assert reader.index.manifest.scene.timeline_type == 1
        assert len(reader.frame_at(0.0)) == len(parts["static"]) + len(parts["moving"])
    fresh = [static_gaussians(500, seed=200 + k) for k in range(3)]
    write_frames(tmp_path / "fresh", fresh)
    args = ["segment", str(tmp_path / "fresh"), "-o", str(tmp_path / "f.tsogs"), "-q"]
    assert main(args) == 0
    assert "stored one per frame (type 0)" in capsys.readouterr().out
    with open_stream(tmp_path / "f.tsogs") as reader:
        assert reader.index.manifest.scene.timeline_type == 0
    bad = ["segment", str(tmp_path / "seq"), "-o", str(tmp_path / "x.tsogs"), "--tolerance", "-1"]
    assert main(bad) == 1
    assert "tolerance" in capsys.readouterr().err


def test_fit_follows_fading_and_turning_gaussians(
    tmp_path: Path, parts: dict[str, Gaussians]
) -> None:
    """Opacity fading (linear in logit) and a steady turn about z: one Gaussian each, with
    temporal opacity and rotation coefficients; every frame within budget."""
    base = parts["blink"]
    n = len(base)
    frames = []
    for k in range(FRAMES):
        t = k / FPS
        half = 0.5 * np.radians(20.0) * t  # 20 degrees per second
        turn = np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
        w1, v1 = turn[0], turn[1:]
        q = base.quats.astype(np.float64)
        w2, v2 = q[:, 0], q[:, 1:]
        vec = w1 * v2 + w2[:, None] * v1 + np.cross(v1, v2)
        quats = np.column_stack([w1 * w2 - v2 @ v1, vec])
        fading = base.opacities - 0.8 * t
        frames.append(
            Gaussians.from_arrays(base.means, base.scales, quats, fading, base.sh0, shN=base.shN)
        )
    seq = write_frames(tmp_path / "seq", frames)
    scene, stats = merge_sequence(seq, "fit")
    assert scene is not None
    assert len(scene) == n and stats.moving_out == n
    assert {"opacity", "quats"} <= set(scene.temporal) and "means" not in scene.temporal
    out = tmp_path / "turn.tsogs"
    segment_scene(scene, out, SegmentOptions(window_s=0.5, workers=1))
    with open_stream(out) as reader:
        for k in (0, 5, FRAMES - 1):
            own = decode_chunk(encode_chunk(Scene(frames[k]))).gaussians
            alone = matched_errors(frames[k], own)
            merged = matched_errors(frames[k], reader.frame_at(k / FPS))
            assert merged["alpha"] <= alone["alpha"] + 1 / 255 + 1e-6, (k, merged, alone)
            assert merged["quats"] <= alone["quats"] + 0.01, (k, merged, alone)


def test_floaters_do_not_widen_the_search_reach() -> None:
    """The reach is a fraction of the frame's extent: a blob with 2 % floaters 200 units out
    keeps the blob's extent (a min-max extent of 400 made matching quadratic), and a frame
    without floaters keeps its min-max extent."""
    rng = np.random.default_rng(0)
    blob = rng.normal(size=(2000, 3)) * 0.4
    floaters = rng.normal(size=(40, 3))
    floaters = 200 * floaters / np.linalg.norm(floaters, axis=1, keepdims=True)
    extent = robust_extent(np.concatenate([blob, floaters]))
    spread = np.ptp(np.concatenate([blob, floaters]), axis=0)
    assert np.all(spread > 300) and np.all((extent > np.ptp(blob, axis=0)) & (extent < 5))
    np.testing.assert_allclose(robust_extent(blob), blob.max(axis=0) - blob.min(axis=0))
    np.testing.assert_array_equal(robust_extent(np.full((3, 3), np.nan)), np.zeros(3))


def test_fitted_tracks_hold_only_the_frames_seen(parts: dict[str, Gaussians]) -> None:
    """A fitting merge keeps each open run's track as wide as the longest run so far (a probe
    of 8 frames held 32 frames of track per Gaussian: 3.5 kB each), up to its frame limit."""
    frames = sequence_frames(parts, blink=range(0))
    first = frames[0]
    merger = FrameMerger(
        Steps.of(first), Tolerance(), FPS, first.shN.shape[1], fit=True, max_frames=8
    )
    for k, g in enumerate(frames, start=1):
        merger.add(g)
        assert merger._open is not None
        assert merger._open.history.shape[1] == min(k, 8), k
    assert len(merger.scene()) > 0

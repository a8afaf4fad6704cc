"""The segmenter's cost model (segment/layout.py): what it chooses for each kind of content, and
that its estimates are what a written container then measures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream import open_stream
from tsog_stream.cli.main import main
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.container.header import PREFIX_SIZE
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Scene
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.segment.layout import (
    FILE_SLACK,
    SEEK_TARGET,
    Choice,
    Costs,
    Lifespans,
    choose_layout,
    sample_times,
    why_not_merged,
)
from tsog_stream.synthetic import freetime_scene, static_gaussians

FIREWORKS = "4d/tztechno_fireworks_frames"


def test_independent_frames_get_one_chunk_per_frame() -> None:
    life = Lifespans.of_frames([31658] * 50, fps=30.0)
    choice = choose_layout(life, Costs(per_gaussian=6.7, per_chunk=5000.0, max_count=1 << 24))
    chosen = choice.chosen
    assert chosen.layout.window_s == pytest.approx(1 / 30)
    assert "a window per frame" in choice.reason and not choice.explicit
    assert chosen.meets_target and chosen.overfetch < SEEK_TARGET
    assert chosen.chunks == 50


def test_a_window_given_is_kept_and_estimated() -> None:
    life = Lifespans.of_frames([31658] * 50, fps=30.0)
    costs = Costs(per_gaussian=6.7, per_chunk=5000.0, max_count=1 << 24)
    choice = choose_layout(life, costs, window_s=1.0, policy="hybrid")
    assert choice.explicit and choice.chosen.layout.window_s == 1.0
    assert choice.chosen.overfetch > 20  # a 30-frame chunk for a one-frame seek


@pytest.fixture(scope="module")
def short_lived() -> Scene:
    """20k Gaussians, each visible for 1-4 % of a 10 s clip, moving linearly."""
    return freetime_scene(static_gaussians(20_000, seed=3), duration_s=10.0, lifespan=(0.01, 0.04))


def test_the_estimates_are_what_the_written_container_measures(
    short_lived: Scene, tmp_path: Path
) -> None:
    out = tmp_path / "short.tsogs"
    report = segment_scene(short_lived, out, SegmentOptions(workers=1))
    assert report.layout is not None
    chosen = report.layout.chosen
    life = Lifespans.of_scene(short_lived)
    with open_stream(out) as stream:
        in_prefix = stream.index.header.index_offset < PREFIX_SIZE
        opening = PREFIX_SIZE + (0 if in_prefix else stream.index.header.index_length)
        seeks = [stream.seek_cost(float(t)) for t in sample_times(life)]
    measured = opening + np.mean([s.bytes for s in seeks])
    assert out.stat().st_size == pytest.approx(chosen.file_bytes, rel=0.10)
    assert measured == pytest.approx(chosen.seek_mean, rel=0.15)
    assert 1 + np.mean([s.requests for s in seeks]) == pytest.approx(chosen.requests, rel=0.2)


def test_the_file_is_never_inflated_to_make_seeks_cheap(short_lived: Scene) -> None:
    """Duplicating short-lived Gaussians into many short windows makes seeks cheap and the
    file several times larger; playback reads the whole file, so that is never chosen."""
    sample = short_lived.subset(np.arange(4096))
    costs = Costs(
        per_gaussian=len(bundle_bytes(encode_chunk(sample))) / 4096,
        per_chunk=6000.0,
        max_count=1 << 24,
    )
    choice = choose_layout(Lifespans.of_scene(short_lived), costs)
    smallest = min(e.file_bytes for e in choice.tried)
    assert choice.chosen.file_bytes <= FILE_SLACK * smallest
    cheapest_seek = min(choice.tried, key=lambda e: e.overfetch)
    assert cheapest_seek.file_bytes > 2 * smallest  # the trade the model refuses exists
    fitting = [e for e in choice.tried if e.file_bytes <= FILE_SLACK * smallest]
    least = min(e.overfetch for e in fitting)
    assert choice.chosen.meets_target or choice.chosen.overfetch == least


def test_a_flipbook_is_stored_one_frame_per_chunk_and_no_larger_than_its_frames(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The in-repo PLY frames (independent fireworks frames): the default layout stores each
    frame in its own chunk, a seek reads one frame, and the container (compact: no 16 KiB
    prefix) is no larger than one SOG per frame."""
    frames = samples / FIREWORKS
    out = tmp_path / "fw.tsogs"
    assert main(["segment", str(frames), "-o", str(out), "-q"]) == 0
    printed = capsys.readouterr()
    assert "a window per frame" in printed.out and "warning" not in printed.err
    seq = open_sequence(frames)
    own = [len(bundle_bytes(encode_chunk(seq.read(k, k + 1).scene))) for k in range(seq.count)]
    assert out.stat().st_size <= sum(own)
    with open_stream(out) as stream:
        assert len(stream.index.manifest.chunks) == seq.count
        for k in range(seq.count):
            cost = stream.seek_cost((k + 0.5) / seq.fps)
            assert cost.chunks == 1 and cost.bytes <= 1.05 * own[k]


def test_an_explicit_layout_that_over_fetches_is_warned(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fw6.tsogs"
    assert main(["segment", str(samples / FIREWORKS), "--window", "6f", "-o", str(out)]) == 0
    printed = capsys.readouterr()
    assert "layout (as given): window 6 frames" in printed.out
    assert "tsog: warning: this layout makes a seek fetch about" in printed.err


def _frames_choice() -> Choice:
    """50 frames of 4225 Gaussians each, one chunk per frame (the wave flipbook's shape)."""
    life = Lifespans.of_frames([4225] * 50, fps=30.0)
    return choose_layout(life, Costs(per_gaussian=7.0, per_chunk=3000.0, max_count=1 << 24))


def _merged_life(durations: npt.NDArray[np.float64]) -> Lifespans:
    """Merged Gaussians of a 50-frame, 30 fps sequence with the given lifespans (seconds)."""
    start = np.random.default_rng(0).uniform(0.0, 50 / 30 - durations)
    return Lifespans(start, start + durations, np.ones(start.size), 0.0, 50 / 30, 30.0)


def test_a_merge_whose_seeks_read_many_frames_is_not_kept() -> None:
    """Merged, 19k Gaussians living 10-50 frames with motion coefficients: a smaller file, but
    a seek reads the long-lived ones' shared chunks, several frames' worth."""
    life = _merged_life(np.random.default_rng(1).uniform(10, 50, 19_000) / 30)
    merged = choose_layout(life, Costs(per_gaussian=20.0, per_chunk=9000.0, max_count=1 << 24))
    frames = _frames_choice()
    assert frames.chosen.layout.window_s == pytest.approx(1 / 30) and frames.chosen.meets_target
    why = why_not_merged(frames, merged)
    assert merged.chosen.file_bytes < _frames_choice().chosen.file_bytes
    assert why is not None and "a seek" in why and "frame's own chunk" in why


def test_a_merge_of_a_static_set_is_kept() -> None:
    """The same 4225 Gaussians in every frame merge into one chunk a seek reads whole: smaller
    and no dearer to seek than one frame."""
    life = _merged_life(np.full(4225, 50 / 30))
    merged = choose_layout(life, Costs(per_gaussian=7.0, per_chunk=3000.0, max_count=1 << 24))
    assert why_not_merged(_frames_choice(), merged) is None

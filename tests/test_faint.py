"""Gaussians too faint to store below quality 100 (precision.faint_at, spec §5.1): which they
are, and that `tsog encode` and the segmenter (a scene in memory; frame windows read here and
in worker processes) store every other Gaussian and none of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helpers import write_ply_frames
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes, read_bundle
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.codec.precision import (
    ALPHA_BYTE_ZERO,
    FAINT_AT_ZERO,
    budget_fraction,
    faint_at,
    without_faint,
)
from tsog_stream.io.ply import write_ply
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Gaussians, Scene
from tsog_stream.opacity import alpha_to_logit, logit_to_alpha
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.synthetic import freetime_scene, static_gaussians

ALPHAS = np.array([0.0005, 0.0015, 0.005, 0.02, 0.05, 0.5])
"""One Gaussian each: below half an alpha byte, within it, and above it by steps."""


def _with_alphas(gaussians: Gaussians, alphas: np.ndarray) -> Gaussians:
    """``gaussians`` with their alphas set, cycling through ``alphas``."""
    cycle = np.resize(alphas, len(gaussians))
    opacities = alpha_to_logit(cycle).astype(np.float32).reshape(gaussians.opacities.shape)
    g = gaussians
    return Gaussians(g.means, g.scales, g.quats, opacities, g.sh0, g.shN)


@pytest.mark.parametrize(
    ("quality", "faint"),
    [
        (100, [False] * 6),  # today's precision: every Gaussian
        (99, [True, True, False, False, False, False]),  # alpha byte 0 (up to 0.00196) only
        (90, [True, True, False, False, False, False]),  # 0.002: about byte 0 still
        (55, [True, True, True, True, False, False]),  # 0.0405
        (0, [True, True, True, True, True, False]),  # 0.2
    ],
)
def test_faint_gaussians_are_those_whose_alpha_the_quality_lets_go_to_zero(
    quality: int, faint: list[bool]
) -> None:
    scene = Scene(_with_alphas(static_gaussians(6, seed=1), ALPHAS))
    assert faint_at(scene, quality).tolist() == faint
    limit = max(budget_fraction(quality) * FAINT_AT_ZERO, ALPHA_BYTE_ZERO)
    if quality < 100:  # the rule, on many alphas
        many = Scene(_with_alphas(static_gaussians(4000, seed=2), np.geomspace(1e-5, 1, 4000)))
        alphas = logit_to_alpha(many.gaussians.opacities.ravel())
        assert np.array_equal(faint_at(many, quality), alphas <= limit)


def test_none_is_faint_when_opacity_moves_or_every_one_is() -> None:
    scene = freetime_scene(
        _with_alphas(static_gaussians(50, seed=3), ALPHAS), duration_s=4.0, lifespan=(0.6, 1.0)
    )
    assert faint_at(scene, 0).any()
    scene.temporal["opacity"] = np.zeros((len(scene), 1, 1), np.float32)
    assert not faint_at(scene, 0).any()  # its alpha over time is not bounded here
    all_faint = Scene(_with_alphas(static_gaussians(20, seed=4), np.array([0.001])))
    assert not faint_at(all_faint, 0).any()  # a chunk holds at least one Gaussian
    assert without_faint(all_faint, 0) is all_faint


def test_encode_leaves_the_faint_out_and_stores_the_rest_as_the_library_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = _with_alphas(static_gaussians(3000, seed=5), ALPHAS)
    write_ply(tmp_path / "in.ply", source)
    out = tmp_path / "out.sog"
    assert main(["encode", str(tmp_path / "in.ply"), str(out), "--quality", "55", "-q"]) == 0
    kept = Scene(source).subset(np.flatnonzero(~faint_at(Scene(source), 55)))
    assert len(kept) == 3000 * 2 // 6  # alphas 0.05 and 0.5
    assert f"{len(kept)} Gaussians" in (said := capsys.readouterr().out)
    assert "(2000 too faint at quality 55 left out)" in said
    assert out.read_bytes() == bundle_bytes(encode_chunk(kept, quality=55))
    decoded = decode_chunk(read_bundle(out.read_bytes())).gaussians
    alphas = logit_to_alpha(decoded.opacities.ravel())
    assert len(decoded) == len(kept) and alphas.min() > 0.02  # none of the faint ones
    assert main(["encode", str(tmp_path / "in.ply"), str(tmp_path / "all.sog"), "-q", "-f",
                 "--quality", "100"]) == 0  # fmt: skip
    assert "3000 Gaussians" in capsys.readouterr().out


def _chunk_counts(path: Path) -> tuple[int, int, list[float]]:
    """(the index's Gaussians, the chunks' stored count, the smallest decoded alpha)."""
    with open_stream(path) as reader:
        manifest = reader.index.manifest
        counts = sum(c.count for c in manifest.chunks if c.holds_gaussians)
        lowest = [
            float(logit_to_alpha(reader.chunk_scene(c.id).gaussians.opacities.ravel()).min())
            for c in manifest.chunks
            if c.holds_gaussians
        ]
        return manifest.scene.gaussians, counts, lowest


def test_segmenting_a_scene_stores_every_gaussian_but_the_faint(tmp_path: Path) -> None:
    scene = freetime_scene(
        _with_alphas(static_gaussians(3000, seed=6), ALPHAS), duration_s=4.0, lifespan=(0.6, 1.0)
    )
    kept = int(np.count_nonzero(~faint_at(scene, 55)))
    path = tmp_path / "s.tsogs"
    report = segment_scene(scene, path, SegmentOptions(quality=55, window_s=1.0))
    gaussians, counts, lowest = _chunk_counts(path)
    assert gaussians == report.gaussians == kept == 1000
    assert report.faint == 2000
    assert counts == report.stored >= kept  # copies of Gaussians crossing windows counted
    assert min(lowest) > 0.02
    every = segment_scene(scene, tmp_path / "all.tsogs", SegmentOptions(window_s=1.0))
    assert every.gaussians == 3000


@pytest.mark.parametrize("workers", [1, 2])
def test_segmenting_frames_leaves_each_window_s_faint_out(tmp_path: Path, workers: int) -> None:
    """Windows read here (one process) and by the workers themselves (window jobs) alike."""
    frames = [
        _with_alphas(static_gaussians(600, seed=10 + k), np.roll(ALPHAS, k)) for k in range(8)
    ]
    kept = sum(int(np.count_nonzero(~faint_at(Scene(frame), 55))) for frame in frames)
    write_ply_frames(tmp_path / "frames", frames)
    seq = open_sequence(tmp_path / "frames")
    path = tmp_path / f"w{workers}.tsogs"
    options = SegmentOptions(quality=55, workers=workers, window_s=1 / seq.fps, layers=1)
    report = segment_sequence(seq, path, options)
    gaussians, counts, lowest = _chunk_counts(path)
    assert gaussians == counts == report.gaussians == report.stored == kept == 8 * 200
    assert report.faint == 8 * 400
    assert min(lowest) > 0.02


def test_tsog_segment_says_how_many_it_left_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "frames"
    write_ply_frames(
        folder, (_with_alphas(static_gaussians(600, seed=k), ALPHAS) for k in range(3))
    )
    out = tmp_path / "out.tsogs"
    argv = ["segment", str(folder), "-o", str(out), "--quality", "55", "--workers", "1", "-q"]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert "600 Gaussians, 600 stored copies (1200 too faint at quality 55 left out)" in said

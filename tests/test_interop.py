"""Interop with PlayCanvas's reference SOG tool, @playcanvas/splat-transform (pinned in npm).

(a) our .sog -> splat-transform -> PLY equals our own decode; (b) splat-transform's .sog -> our
decoder equals its own decode, and our Morton order equals its texel order; (c) a TSOG chunk is
read by splat-transform as a static SOG with the base values; codebook quality no worse.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from tsog_stream import Gaussians, Scene, TimelineType
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.codec.sog_encode import scale_importance
from tsog_stream.compare import rotation_angles_deg
from tsog_stream.io.chunks import read_chunk
from tsog_stream.io.ply import read_ply
from tsog_stream.synthetic import small_scene

pytestmark = pytest.mark.interop

INPUTS = ["3dgs/supersplat_pr291_fruit_drops_minimal.ply", "3dgs/v3dg_donut_fused.ply"]


def run_tool(tool: Path, *args: str | Path) -> None:
    """Run splat-transform on the CPU, failing the test with its output on error."""
    cmd = [str(tool), "-w", "-g", "cpu", *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout}\n{proc.stderr}"


def assert_same_gaussians(a: Gaussians, b: Gaussians) -> None:
    """Equal to float32 rounding (opacity logits and quaternions up to their decode formulas)."""
    np.testing.assert_allclose(a.means, b.means, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(a.scales, b.scales, rtol=1e-6, atol=1e-6)
    assert rotation_angles_deg(a.quats, b.quats).max() < 1e-2
    np.testing.assert_allclose(a.opacities, b.opacities, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(a.sh0, b.sh0, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(a.shN, b.shN, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("name", INPUTS)
def test_a_reference_decodes_our_sog_like_we_do(
    name: str, samples: Path, splat_transform: Path, tmp_path: Path
) -> None:
    scene = Scene(read_ply(samples / name).gaussians)
    ours = tmp_path / "ours.sog"
    ours.write_bytes(bundle_bytes(encode_chunk(scene)))
    run_tool(splat_transform, ours, tmp_path / "theirs.ply")
    theirs = read_ply(tmp_path / "theirs.ply").gaussians
    assert_same_gaussians(read_chunk(ours).gaussians, theirs)


@pytest.mark.parametrize("name", INPUTS)
def test_b_we_decode_reference_sog_like_it_does(
    name: str, samples: Path, splat_transform: Path, tmp_path: Path
) -> None:
    source = read_ply(samples / name).gaussians
    run_tool(splat_transform, samples / name, tmp_path / "ref.sog")
    run_tool(splat_transform, tmp_path / "ref.sog", tmp_path / "ref.ply")
    ours = read_chunk(tmp_path / "ref.sog").gaussians
    assert_same_gaussians(ours, read_ply(tmp_path / "ref.ply").gaussians)
    # Same texel order: the reference's texel i decodes near our Morton order's Gaussian i.
    ordered = source.subset(texel_order(Scene(source)))
    extent = np.ptp(source.means, axis=0).max()
    assert np.abs(ordered.means - ours.means).max() < 1e-3 * extent


@pytest.mark.parametrize("name", INPUTS)
def test_codebooks_no_worse_than_reference(
    name: str, samples: Path, splat_transform: Path, tmp_path: Path
) -> None:
    source = Scene(read_ply(samples / name).gaussians)
    src = source.subset(texel_order(source)).gaussians
    run_tool(splat_transform, samples / name, tmp_path / "ref.sog")
    theirs = read_chunk(tmp_path / "ref.sog").gaussians
    ours = decode_chunk(encode_chunk(source)).gaussians
    for attr in ("scales", "sh0", "shN"):
        ref = getattr(src, attr)
        if ref.size == 0:
            continue
        # the scale codebook minimises the error a view shows (scale_importance's weights),
        # not the count's: judged on that, with the plain error bounded (measured: weighted
        # 0.40x / 0.84x the reference's, plain 1.43x / 1.16x, fruit drops / donut)
        weights = scale_importance(src) if attr == "scales" else np.ones(ref.shape)
        err_ours, err_theirs = (getattr(ours, attr) - ref) ** 2, (getattr(theirs, attr) - ref) ** 2
        mse_ours = float(np.sum(weights * err_ours) / np.sum(weights))
        mse_theirs = float(np.sum(weights * err_theirs) / np.sum(weights))
        assert mse_ours <= mse_theirs * 1.0001 + 1e-12, (
            f"{attr}: ours {mse_ours:.3e} > reference {mse_theirs:.3e}"
        )
        assert float(np.mean(err_ours)) <= 1.6 * float(np.mean(err_theirs)) + 1e-12, attr


def test_c_reference_reads_tsog_chunk_as_static_sog(splat_transform: Path, tmp_path: Path) -> None:
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=2, dynamic=("means", "quats"))
    chunk = tmp_path / "dynamic.sog"
    chunk.write_bytes(bundle_bytes(encode_chunk(scene)))
    run_tool(splat_transform, chunk, tmp_path / "base.ply")
    base = read_ply(tmp_path / "base.ply").gaussians
    decoded = read_chunk(chunk)
    assert decoded.timeline is not None and decoded.temporal
    assert_same_gaussians(decoded.gaussians, base)

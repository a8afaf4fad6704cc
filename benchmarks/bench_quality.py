"""Rendered quality beside size: PSNR/SSIM of every lossy path against its source.

    .venv/bin/python benchmarks/bench_quality.py [--quick]

Renders (tsog_stream.render, CPU) the source and each candidate from the same orbit cameras at
the same times and reports mean and worst PSNR/SSIM (8-bit images, 3DGS SSIM convention):
static SOG (ours and splat-transform's) on real scenes; TSOG and `.4dgs` on the 4D inputs;
`--temporal off|merge|fit` on frame sequences; and the paper's ablation, 16-bit temporal
coefficients (ours) against the same coefficients rounded to 8 bits. Writes
benchmarks/results/quality.json and the "quality" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bench_temporal import generated_sequence
from common import sample, write_section
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.io.fourdgs import encode_4dgs, parse_4dgs
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import load_scene
from tsog_stream.io.sequence import open_sequence
from tsog_stream.merge import merge_sequence
from tsog_stream.model import Gaussians, Scene, evaluate_at
from tsog_stream.render import Camera, render, scene_orbit, to_uint8
from tsog_stream.render.evaluate import mean_psnr
from tsog_stream.render.metrics import psnr, ssim
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.synthetic import SceneSpec, generate_scene
from tsog_stream.temporal import time_range

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
TOOL = REPO / "node_modules" / ".bin" / "splat-transform"
At = Callable[[float], Gaussians]


def score(
    reference: At, candidate: At, times: Sequence[float], cameras: Sequence[Camera]
) -> dict[str, float]:
    """Mean and worst PSNR/SSIM over times x cameras (cameras chosen on the reference)."""
    values = []
    for t in times:
        ref, cand = reference(t), candidate(t)
        for cam in cameras:
            a, b = to_uint8(render(ref, cam)), to_uint8(render(cand, cam))
            values.append((psnr(a, b), ssim(a, b)))
    p = np.array([v[0] for v in values])
    s = np.array([v[1] for v in values])
    return {
        "psnr_mean": mean_psnr(list(p)),
        "identical": int(np.isinf(p).sum()),
        "psnr_worst": float(p.min()),
        "ssim_mean": float(s.mean()),
        "ssim_worst": float(s.min()),
        "renders": 2 * len(values),
    }


def static(scene: Scene) -> At:
    return lambda t: scene.gaussians


def dynamic(scene: Scene) -> At:
    return lambda t: evaluate_at(scene, t)


def static_rows(work: Path, views: int, size: tuple[int, int]) -> list[dict[str, Any]]:
    """Real static scenes through our SOG and splat-transform's."""
    rows = []
    for name, path in (
        ("donut (45k, SH0)", sample("3dgs/v3dg_donut_fused.ply")),
        ("guitar (91k, SH0)", sample("3dgs/pc_guitar.compressed.ply")),
        ("lod2 tile (7k, SH3)", sample("3dgs/gs3d_pr477_lod2_tile_0.ply")),
    ):
        source = load_scene(path).scene
        cameras = scene_orbit(source.gaussians, views, *size)
        files = encode_chunk(source)
        ours = decode_chunk(files)
        row: dict[str, Any] = {"group": "static SOG", "case": name, "variant": "ours"}
        row.update(
            bytes=len(bundle_bytes(files)), **score(static(source), static(ours), [0.0], cameras)
        )
        rows.append(row)
        if TOOL.exists():
            ply, sog = work / "in.ply", work / "theirs.sog"
            write_ply(ply, source.gaussians)
            done = subprocess.run(
                [str(TOOL), "-w", "-g", "cpu", str(ply), str(sog)],
                capture_output=True,
                timeout=1800,
                check=False,
            )
            if done.returncode == 0:
                theirs = load_scene(sog).scene
                row = {"group": "static SOG", "case": name, "variant": "splat-transform 3.7.0"}
                row.update(
                    bytes=sog.stat().st_size,
                    **score(static(source), static(theirs), [0.0], cameras),
                )
                rows.append(row)
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def four_d_rows(work: Path, views: int, size: tuple[int, int], times: int) -> list[dict[str, Any]]:
    """4D inputs: the TSOG chunk and .4dgs against the source at ``times`` times."""
    rows = []
    inputs = [
        (
            "hanabi2 .splatv",
            load_scene(sample("4d/splatv/tztechno_hanabi2_synthetic.splatv")).scene,
        ),
        (
            "generated SH3, moving means",
            generate_scene(
                SceneSpec(
                    sh_bands=3,
                    background=8000,
                    objects=8,
                    per_object=1000,
                    dynamic=("means",),
                    seed=5,
                )
            ),
        ),
    ]
    for name, scene in inputs:
        if scene.timeline is None:
            continue
        first, last = time_range(scene.timeline)
        ts = list(np.linspace(first, last, times + 2)[1:-1])
        cameras = scene_orbit(evaluate_at(scene, ts[0]), views, *size)
        files = encode_chunk(scene)
        tsog = decode_chunk(files)
        row: dict[str, Any] = {
            "group": "4D inputs",
            "case": name,
            "variant": "TSOG chunk (16-bit coefficients)",
        }
        row.update(
            bytes=len(bundle_bytes(files)), **score(dynamic(scene), dynamic(tsog), ts, cameras)
        )
        rows.append(row)
        eight = Scene(
            scene.gaussians, scene.timeline, {k: eight_bit(v) for k, v in scene.temporal.items()}
        )
        eight_back = decode_chunk(encode_chunk(eight))
        row = {
            "group": "4D inputs",
            "case": name,
            "variant": "coefficients rounded to 8 bits (ablation)",
        }
        row.update(bytes=None, **score(dynamic(scene), dynamic(eight_back), ts, cameras))
        rows.append(row)
        try:
            data, _ = encode_4dgs(scene, keep_order=True, lossy=True)
            back = parse_4dgs(data).scene
            row = {"group": "4D inputs", "case": name, "variant": ".4dgs (fourdgs, lossy)"}
            row.update(bytes=len(data), **score(dynamic(scene), dynamic(back), ts, cameras))
            rows.append(row)
        except Exception as exc:  # the fourdgs package refuses some motion: say so
            rows.append(
                {"group": "4D inputs", "case": name, "variant": ".4dgs", "error": str(exc)[:120]}
            )
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def eight_bit(coeffs: np.ndarray) -> np.ndarray:
    """Coefficients rounded to 8 bits over each order's per-channel range (the ablation)."""
    lo = coeffs.min(axis=0, keepdims=True)
    hi = coeffs.max(axis=0, keepdims=True)
    span = np.where(hi > lo, hi - lo, 1.0)
    rounded: npt.NDArray[np.float32] = (
        lo + np.rint((coeffs - lo) / span * 255) / 255 * span
    ).astype(np.float32)
    return rounded


def frame_lookup(frames: dict[int, Gaussians], fps: float) -> At:
    """The source frame shown at time t."""
    return lambda t: frames[round(t * fps)]


def sequence_rows(
    work: Path, views: int, size: tuple[int, int], samples: int
) -> list[dict[str, Any]]:
    """Frame sequences through --temporal off / merge / fit, against the source frames."""
    rows = []
    generated = work / "generated"
    generated_sequence(generated, 60, 10_000)
    for name, folder, fps in (
        ("wave SOG flipbook (50)", sample("4d/pc_flipbook_wave", in_tree=False), 30.0),
        ("fireworks PLY sequence (6)", sample("4d/tztechno_fireworks_frames"), 6.0),
        ("generated, 70% static (60 frames)", generated, 30.0),
    ):
        seq = open_sequence(folder, fps=fps)
        frames = sorted({round(x) for x in np.linspace(0, seq.count - 1, samples)})
        source = {k: seq.read(k, k + 1).scene.gaussians for k in frames}
        cameras = scene_orbit(source[frames[0]], views, *size)
        ts = [k / fps for k in frames]
        reference = frame_lookup(source, fps)
        for mode in ("off", "merge", "fit"):
            out = work / f"{mode}.tsogs"
            if mode == "off":
                segment_sequence(seq, out, SegmentOptions())
            else:
                scene, _ = merge_sequence(seq, mode)
                if scene is None:
                    continue
                segment_scene(scene, out, SegmentOptions())
            with open_stream(out) as reader:
                row: dict[str, Any] = {
                    "group": "frame sequences",
                    "case": name,
                    "variant": f"--temporal {mode}",
                }
                row.update(
                    bytes=out.stat().st_size, **score(reference, reader.frame_at, ts, cameras)
                )
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def _db(x: float) -> str:
    return "inf" if not np.isfinite(x) else f"{x:.2f}"


def markdown(rows: list[dict[str, Any]], stamp: str, size: tuple[int, int], views: int) -> str:
    lines = [
        f"## Rendered quality (`tsog_stream.render`, {stamp})\n",
        "PSNR / SSIM of each candidate against its source, both rendered by our CPU rasterizer at",
        f"{size[0]}x{size[1]} from {views} orbit cameras around the source (8-bit images, SSIM with",
        "the 3DGS evaluation's 11x11 Gaussian window, zero padding); mean and worst over views x",
        "times (identical images, PSNR = inf, are left out of the mean). Bytes: the candidate's",
        "file (container for sequences). The 8-bit row rounds the temporal coefficients to 8 bits",
        "over each order's range before encoding (the paper's ablation); ours store 16 bits.\n",
        "| group | case | variant | bytes | PSNR mean | PSNR worst | SSIM mean | SSIM worst |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        if "error" in r:
            lines.append(
                f"| {r['group']} | {r['case']} | {r['variant']} | | refused: {r['error']} | | | |"
            )
            continue
        size_cell = "" if r.get("bytes") is None else str(r["bytes"])
        lines.append(
            f"| {r['group']} | {r['case']} | {r['variant']} | {size_cell} | {_db(r['psnr_mean'])} | "
            f"{_db(r['psnr_worst'])} | {r['ssim_mean']:.4f} | {r['ssim_worst']:.4f} |"
        )
    return "\n".join(lines) + "\n\n"


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="fewer views, times and frames")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    args = parser.parse_args()
    views, times, samples = (2, 2, 3) if args.quick else (4, 5, 6)
    size = (args.width, args.height)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = static_rows(work, views, size) + four_d_rows(work, views, size, times)
        rows += sequence_rows(work, views, size, samples)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "quality.json").write_text(json.dumps(rows, indent=1))
    write_section(
        "quality", markdown(rows, dt.date.today().isoformat(), size, views), "bench_quality.py"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

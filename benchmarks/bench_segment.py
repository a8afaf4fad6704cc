"""Segmenter benchmark: policies and window lengths by seek cost; throughput and peak memory.

    .venv/bin/python benchmarks/bench_segment.py policies     # policy x window table (minutes)
    .venv/bin/python benchmarks/bench_segment.py scale        # PLY sequences: 10 and 100 frames
    .venv/bin/python benchmarks/bench_segment.py scale --frames 10 --per-frame 300000

Results go to benchmarks/results/segment-*.json and the matching sections of
docs/benchmarks.md. Seek cost at t = bytes (and coalesced requests) of the chunks showing t
needs, against the bytes of the Gaussians actually visible at t.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from common import run_measured, sample, write_section
from tsog_stream import TimelineType
from tsog_stream.client import open_stream
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import ReadOptions, load_scene
from tsog_stream.model import Scene
from tsog_stream.segment.segmenter import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
TSOG = REPO / ".venv" / "bin" / "tsog"


def seek_stats(path: Path, samples: int, seed: int) -> dict[str, float]:
    """Mean/max bytes, requests and overfetch over random times of the scene."""
    with open_stream(path) as reader:
        scene = reader.index.manifest.scene
        times = np.random.default_rng(seed).uniform(scene.start_s, scene.end_s, samples)
        costs = [reader.seek_cost(float(t)) for t in times]
    fetched = np.array([c.bytes for c in costs], float)
    visible = np.array([c.visible_bytes for c in costs], float)
    return {
        "mean_bytes": float(fetched.mean()),
        "max_bytes": float(fetched.max()),
        "mean_percent": float(np.mean([c.percent_of_file for c in costs])),
        "mean_requests": float(np.mean([c.requests for c in costs])),
        "max_requests": float(np.max([c.requests for c in costs])),
        "overfetch": float(fetched.sum() / max(1.0, visible.sum())),
    }


def policy_rows(
    name: str, scene: Scene, windows: list[float], work: Path, samples: int
) -> list[dict[str, Any]]:
    """Every policy x window on one scene."""
    rows = []
    for window in windows:
        for policy in ("duplicate", "hierarchy", "hybrid"):
            out = work / f"{name}-{policy}-{window}.tsogs"
            start = time.monotonic()
            report = segment_scene(
                scene, out, SegmentOptions(window_s=window, policy=policy, workers=2)
            )
            row = {
                "scene": name,
                "policy": policy,
                "window_s": window,
                "bytes": report.bytes,
                "chunks": report.chunks,
                "stored": report.stored,
                "gaussians": report.gaussians,
                "seconds": round(time.monotonic() - start, 1),
                **seek_stats(out, samples, seed=1),
            }
            print(json.dumps(row), flush=True)
            rows.append(row)
            out.unlink()
    return rows


def policies(args: argparse.Namespace) -> None:
    """The policy x window comparison on a synthetic scene and a real .splatv."""
    scenes = {
        "synthetic type 2 (10 s)": generate_scene(
            SceneSpec(
                timeline_type=TimelineType.CENTER_SCALE,
                background=40_000,
                objects=40,
                per_object=2000,
                duration=10.0,
                sh_bands=0,
                dynamic=("means",),
                seed=3,
            )
        ),
        "spinach .splatv (real, 5 s)": load_scene(
            sample("4d/splatv/macaburguera_spinach_4.splatv"), options=_splatv_options()
        ).scene,
    }
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="tsog-seg-") as tmp:
        for name, scene in scenes.items():
            rows += policy_rows(name, scene, args.windows, Path(tmp), args.samples)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    (RESULTS / "segment-policies.json").write_text(
        json.dumps({"date": stamp, "rows": rows}, indent=2)
    )
    lines = [
        "## Segmenter policies and window length",
        "",
        f"Run {stamp}. {args.samples} random t per row (seeded). *bytes to show t*: chunks "
        "fetched for one frame; *overfetch*: fetched bytes / bytes of the Gaussians visible at t "
        "(1.0 = nothing wasted); *requests*: byte ranges after merging adjacent chunks.",
        "",
        "| scene | policy | window s | file MB | stored / source | mean MB to show t | max MB | mean % of file | requests mean / max | overfetch |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['policy']} | {r['window_s']:g} | {r['bytes'] / 1e6:.2f} | "
            f"{r['stored'] / max(1, r['gaussians']):.2f} | {r['mean_bytes'] / 1e6:.2f} | "
            f"{r['max_bytes'] / 1e6:.2f} | {r['mean_percent']:.1f} | {r['mean_requests']:.1f} / "
            f"{r['max_requests']:.0f} | {r['overfetch']:.2f} |"
        )
    write_section("segment-policies", "\n".join(lines) + "\n", "bench_segment.py")


def _splatv_options() -> ReadOptions:
    """Read the spinach clip as 5 s long (its length is not stored in the file)."""
    return ReadOptions(duration_s=5.0)


def make_sequence(folder: Path, frames: int, per_frame: int, bands: int) -> int:
    """A PLY sequence: a static set that drifts a little each frame. Returns its bytes."""
    folder.mkdir(parents=True, exist_ok=True)
    base = static_gaussians(per_frame, sh_bands=bands, seed=11)
    total = 0
    for f in range(frames):
        g = base.subset(np.arange(len(base)))
        g.means += np.float32(0.001 * f)
        path = folder / f"frame_{f:04d}.ply"
        write_ply(path, g)
        total += path.stat().st_size
    return total


def scale(args: argparse.Namespace) -> None:
    """Segment PLY sequences of two lengths in a child process: time, throughput, peak RSS."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="tsog-scale-", dir=args.tmp) as tmp:
        for frames in args.frames:
            folder = Path(tmp) / f"seq{frames}"
            ply_bytes = make_sequence(folder, frames, args.per_frame, args.bands)
            out = Path(tmp) / f"seq{frames}.tsogs"
            cmd = [
                str(TSOG),
                "segment",
                str(folder),
                "--fps",
                "30",
                "--window",
                args.window,
                "-o",
                str(out),
                "--workers",
                "2",
                "-q",
            ]
            m = run_measured(cmd)
            if not m["finished"]:
                raise SystemExit(f"{cmd} failed:\n{m.get('error', '')}")
            del m["finished"]
            gaussians = frames * args.per_frame
            row = {
                "frames": frames,
                "per_frame": args.per_frame,
                "sh_bands": args.bands,
                "gaussians": gaussians,
                "ply_bytes": ply_bytes,
                "tsogs_bytes": out.stat().st_size,
                "gaussians_per_s": round(gaussians / m["seconds"]),
                **m,
            }
            print(json.dumps(row), flush=True)
            rows.append(row)
            for p in folder.iterdir():
                p.unlink()
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    name = f"segment-scale-sh{args.bands}"
    (RESULTS / f"{name}.json").write_text(json.dumps({"date": stamp, "rows": rows}, indent=2))
    lines = [
        f"## Segmenting PLY sequences (SH{args.bands}): throughput and peak memory",
        "",
        f"Run {stamp}: `tsog segment --window {args.window} --workers 2` as a child process on "
        "generated sequences (a drifting static set; see bench_segment.py). Peak RSS is the "
        "largest of the CLI process and its encoder processes (ru_maxrss of the waited child).",
        "",
        "| frames | Gaussians | PLY GB | .tsogs MB | saving | seconds | Gaussians/s | peak RSS MiB |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['frames']} | {r['gaussians']:,} | {r['ply_bytes'] / 1e9:.2f} | "
            f"{r['tsogs_bytes'] / 1e6:.1f} | {100 * (1 - r['tsogs_bytes'] / r['ply_bytes']):.1f}% | "
            f"{r['seconds']} | {r['gaussians_per_s']:,} | {r['peak_mib']} |"
        )
    write_section(name, "\n".join(lines) + "\n", "bench_segment.py")


def main() -> int:
    """Dispatch the benchmark parts."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="part", required=True)
    p = sub.add_parser("policies")
    p.add_argument("--windows", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    p.add_argument("--samples", type=int, default=50)
    p = sub.add_parser("scale")
    p.add_argument("--frames", type=int, nargs="+", default=[10, 100])
    p.add_argument("--per-frame", type=int, default=300_000)
    p.add_argument("--bands", type=int, default=0)
    p.add_argument("--window", default="1s")
    p.add_argument("--tmp", default=None, help="folder for the generated sequences (needs ~2 GB)")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    {"policies": policies, "scale": scale}[args.part](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

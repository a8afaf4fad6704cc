"""Rate and distortion: bytes against rendered PSNR of TSOG at each `--quality`, beside `.4dgs`.

    .venv/bin/python benchmarks/bench_rate.py [--views 4] [--times 3]

For FreeTimeGS-style scenes built from the real 45k-Gaussian donut (long, medium and short
lifespans, linear motion) and the real `.splatv` captures: encodes one TSOG chunk at quality
100, 90, 75, 50, 25 and 0 and the scene as `.4dgs` (fourdgs defaults), renders each and the
exact source (tsog_stream.render, CPU) at the same times from the same orbit cameras, and
reports bytes per Gaussian, mean and worst PSNR, and TSOG's bytes against `.4dgs`'s. Writes
benchmarks/results/rate.json and the "rate" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench_quality import dynamic, score
from common import sample, write_section
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.errors import TsogError
from tsog_stream.io.fourdgs import encode_4dgs, parse_4dgs
from tsog_stream.io.readers import load_scene
from tsog_stream.model import Scene
from tsog_stream.render.camera import scene_orbit
from tsog_stream.synthetic import freetime_scene
from tsog_stream.temporal import evaluate_at, time_range

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
QUALITIES = (100, 90, 75, 50, 25, 0)
LIFESPANS = {"long": (0.5, 1.0), "medium": (0.05, 0.2), "short": (0.005, 0.02)}
SIZE = (320, 240)


def scenes() -> list[tuple[str, Scene]]:
    """(name, scene) of every input measured."""
    donut = load_scene(sample("3dgs/v3dg_donut_fused.ply")).scene.gaussians
    out = [
        (f"donut FreeTimeGS {label}", freetime_scene(donut, duration_s=10.0, lifespan=life, seed=7))
        for label, life in LIFESPANS.items()
    ]
    for clip in ("coffee10", "spinach_4"):
        path = sample(f"4d/splatv/macaburguera_{clip}.splatv", in_tree=False)
        out.append((f"{clip}.splatv", load_scene(path).scene))
    return out


def rows_for(name: str, scene: Scene, views: int, times: int) -> list[dict[str, Any]]:
    """One row per quality and one for .4dgs."""
    assert scene.timeline is not None
    first, last = time_range(scene.timeline)
    ts = list(np.linspace(first, last, times + 2)[1:-1])
    cameras = scene_orbit(evaluate_at(scene, ts[0]), views, *SIZE)
    n = len(scene)
    rows: list[dict[str, Any]] = []
    for quality in QUALITIES:
        start = time.monotonic()
        files = encode_chunk(scene, quality=quality)
        seconds = time.monotonic() - start
        size = len(bundle_bytes(files))
        got = score(dynamic(scene), dynamic(decode_chunk(files)), ts, cameras)
        rows.append(
            {
                "scene": name,
                "variant": f"TSOG q{quality}",
                "quality": quality,
                "bytes": size,
                "per_gaussian": size / n,
                "encode_s": seconds,
                **got,
            }
        )
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    try:
        data, _ = encode_4dgs(scene, lossy=True)  # its defaults (it reorders the Gaussians)
        got = score(dynamic(scene), dynamic(parse_4dgs(data).scene), ts, cameras)
        rows.append(
            {
                "scene": name,
                "variant": ".4dgs",
                "bytes": len(data),
                "per_gaussian": len(data) / n,
                **got,
            }
        )
    except TsogError as exc:
        rows.append({"scene": name, "variant": ".4dgs", "error": str(exc)[:120]})
    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def at_psnr(rows: list[dict[str, Any]], target: float) -> tuple[float, bool] | None:
    """TSOG bytes at ``target`` PSNR, linearly interpolated between the measured qualities,
    and whether that is exact (False: even the lowest quality is above the target, so equal
    quality would take fewer bytes than this); None when no quality reaches it."""
    points = sorted((r["psnr_mean"], r["bytes"]) for r in rows if "quality" in r)
    if points and points[0][0] >= target:
        return float(points[0][1]), False
    for (p0, b0), (p1, b1) in itertools.pairwise(points):
        if p0 <= target <= p1:
            return float(b0 + (b1 - b0) * (target - p0) / (p1 - p0)) if p1 > p0 else float(b0), True
    return None


def markdown(all_rows: list[dict[str, Any]], stamp: str, views: int, times: int) -> str:
    """The rate section of docs/benchmarks.md."""
    lines = [
        "## Rate and distortion: `--quality` against `.4dgs`",
        "",
        f"Run {stamp} (`benchmarks/bench_rate.py`): one TSOG chunk per scene at each quality "
        f"and the scene as `.4dgs` (fourdgs defaults), each rendered with the CPU rasterizer "
        f"against the exact source at {times} times x {views} orbit views ({SIZE[0]}x{SIZE[1]}); "
        "PSNR in dB (mean over the images; worst image). *x .4dgs*: bytes against `.4dgs`'s; "
        "at `.4dgs`'s PSNR, interpolated between qualities (< when even quality 0 is above it).",
        "",
        "| scene | variant | B/Gaussian | PSNR mean | PSNR worst | x .4dgs bytes | encode s |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name in dict.fromkeys(r["scene"] for r in all_rows):
        rows = [r for r in all_rows if r["scene"] == name]
        ref = next((r for r in rows if r["variant"] == ".4dgs" and "bytes" in r), None)
        for r in rows:
            if "error" in r:
                lines.append(f"| {name} | {r['variant']} | {r['error']} | | | | |")
                continue
            ratio = f"{r['bytes'] / ref['bytes']:.2f}" if ref else "–"
            secs = f"{r['encode_s']:.2f}" if "encode_s" in r else ""
            lines.append(
                f"| {name} | {r['variant']} | {r['per_gaussian']:.2f} | {r['psnr_mean']:.1f} | "
                f"{r['psnr_worst']:.1f} | {ratio} | {secs} |"
            )
        if ref is not None:
            same = at_psnr(rows, ref["psnr_mean"])
            if same is None:
                said = "not reached"
            else:
                said = f"{'' if same[1] else '< '}{same[0] / ref['bytes']:.2f}x"
            lines.append(
                f"| {name} | TSOG at `.4dgs`'s {ref['psnr_mean']:.1f} dB (interpolated) | | | | "
                f"{said} | |"
            )
    return "\n".join(lines) + "\n"


def main() -> int:
    """Measure every scene, write the results."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--views", type=int, default=4, help="orbit views per time")
    parser.add_argument("--times", type=int, default=3, help="times per scene")
    parser.add_argument(
        "--report", action="store_true", help="only rewrite the section from results/rate.json"
    )
    args = parser.parse_args()
    if args.report:
        saved = json.loads((RESULTS / "rate.json").read_text())
        body = markdown(saved["rows"], saved["date"], args.views, args.times)
        write_section("rate", body, "bench_rate.py")
        return 0
    rows: list[dict[str, Any]] = []
    for name, scene in scenes():
        rows += rows_for(name, scene, args.views, args.times)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "rate.json").write_text(json.dumps({"date": stamp, "rows": rows}, indent=2))
    write_section("rate", markdown(rows, stamp, args.views, args.times), "bench_rate.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

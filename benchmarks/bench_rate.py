"""Rate and distortion: bytes against rendered PSNR of TSOG at each `--quality`, beside `.4dgs`.

    .venv/bin/python benchmarks/bench_rate.py [--views 4] [--times 3]

For FreeTimeGS-style scenes built from two real static scenes, the 45k-Gaussian donut and
PlayCanvas's 91k-Gaussian guitar (long, medium and short lifespans, linear motion), every real
`.splatv` capture and a PLY frame sequence (the fireworks
frames, type 0): encodes one TSOG chunk at quality
100, 90, 75, 50, 25 and 0, the paper's 8-bit ablation (timeline and motion codes rounded to
their high byte), the scene as `.4dgs` (fourdgs defaults) and as a flipbook of one SOG per
frame at 30 fps (our SOG v2 encoder: splat-transform's sizes within 1 %, bench_codec), renders
each and the exact source (tsog_stream.render, CPU) at the same times from the same orbit
cameras, and reports bytes per Gaussian, mean and worst PSNR, and bytes against `.4dgs`'s; at
`.4dgs`'s PSNR, the lowest quality reaching it is found by bisection and measured. Writes
benchmarks/results/rate.json, the "rate" section of docs/benchmarks.md and one
rate-distortion chart per scene, docs/rate/<scene>.png.
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import math
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench_quality import dynamic, score
from common import sample, write_section
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, read_meta
from tsog_stream.codec.precision import QUALITY_MAX, without_faint
from tsog_stream.codec.webp import decode_webp, encode_webp
from tsog_stream.errors import TsogError
from tsog_stream.io.fourdgs import encode_4dgs, parse_4dgs
from tsog_stream.io.readers import load_scene
from tsog_stream.model import Gaussians, Scene, evaluate_at
from tsog_stream.render.camera import scene_orbit
from tsog_stream.render.plot import Series, line_chart, write_png
from tsog_stream.synthetic import freetime_scene
from tsog_stream.temporal import time_range

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
CHARTS = REPO / "docs" / "rate"
TSOG_COLOUR = (31, 119, 180)
PEER_COLOUR = (214, 39, 40)
FLIPBOOK_COLOUR = (44, 160, 44)
ABLATION_COLOUR = (148, 103, 189)
FLIPBOOK_FPS = 30.0
OFF_CHART = 3.0
"""A variant over this many times TSOG's largest size is named under the chart, not drawn."""
ABLATION = "TSOG q100, 8-bit timeline and motion"
FLIPBOOK = f"SOG per frame, {FLIPBOOK_FPS:g} fps"
QUALITIES = (100, 90, 75, 50, 25, 0)
LIFESPANS = {"long": (0.5, 1.0), "medium": (0.05, 0.2), "short": (0.005, 0.02)}
SIZE = (320, 240)
ENCODE_ROUNDS = 5
"""Rounds of encodes at every quality whose median time is reported (at least)."""
ENCODE_BUDGET_S = 30.0
"""Seconds of encoding a scene's timing may take: more rounds for a small scene."""


BASES = {
    "donut": ("3dgs/v3dg_donut_fused.ply", True),
    "guitar": ("3dgs/pc_guitar.compressed.ply", False),
}
"""Real static scenes the FreeTimeGS-style scenes are built from: (sample, in the repository)."""


def scenes() -> list[tuple[str, Scene]]:
    """(name, scene) of every input measured."""
    out = []
    for base, (rel, in_tree) in BASES.items():
        static = load_scene(sample(rel, in_tree=in_tree)).scene.gaussians
        out += [
            (
                f"{base} FreeTimeGS {label}",
                freetime_scene(static, duration_s=10.0, lifespan=life, seed=7),
            )
            for label, life in LIFESPANS.items()
        ]
    for clip in ("coffee10", "coffeeshort2", "spinach_4", "yellow_clip2"):  # every real .splatv
        path = sample(f"4d/splatv/macaburguera_{clip}.splatv", in_tree=False)
        out.append((f"{clip}.splatv", load_scene(path).scene))
    frames = load_scene(sample("4d/tztechno_fireworks_frames")).scene  # type 0, 30 fps
    out.append(("fireworks PLY frames", frames))
    return out


def encode_times(scene: Scene) -> dict[int, float]:
    """Seconds to encode the scene at each quality: the median of at least ENCODE_ROUNDS
    rounds (more for a small scene, ENCODE_BUDGET_S in all), each round every quality in turn
    (this machine's speed drifts by 10-20 % within a minute)."""
    taken: dict[int, list[float]] = {q: [] for q in QUALITIES}
    start = time.perf_counter()
    encode_chunk(scene, quality=QUALITIES[0])  # warm: first-touch memory, caches
    one = time.perf_counter() - start
    rounds = max(ENCODE_ROUNDS, math.ceil(ENCODE_BUDGET_S / (one * len(QUALITIES))))
    for _ in range(rounds):
        for quality in QUALITIES:
            start = time.perf_counter()
            encode_chunk(without_faint(scene, quality), quality=quality)  # as `tsog encode`
            taken[quality].append(time.perf_counter() - start)
    return {q: float(np.median(t)) for q, t in taken.items()}


def rows_for(name: str, scene: Scene, views: int, times: int) -> list[dict[str, Any]]:
    """One row per quality and one for .4dgs."""
    assert scene.timeline is not None
    first, last = time_range(scene.timeline)
    ts = list(np.linspace(first, last, times + 2)[1:-1])
    cameras = scene_orbit(evaluate_at(scene, ts[0]), views, *SIZE)
    n = len(scene)
    rows: list[dict[str, Any]] = []
    seconds = encode_times(scene)
    for quality in QUALITIES:
        rows.append(
            {
                "scene": name,
                "variant": f"TSOG q{quality}",
                "quality": quality,
                **measured_at(scene, quality, views=(ts, cameras)),
                "encode_s": seconds[quality],
                "encode_x_q100": seconds[quality] / seconds[QUALITY_MAX],
            }
        )
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    files = eight_bit(encode_chunk(scene))
    got = score(dynamic(scene), dynamic(decode_chunk(files)), ts, cameras)
    size = len(bundle_bytes(files))
    rows.append(
        {"scene": name, "variant": ABLATION, "bytes": size, "per_gaussian": size / n, **got}
    )
    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    size, shown = flipbook(scene, ts)
    got = score(dynamic(scene), shown, ts, cameras)
    rows.append(
        {"scene": name, "variant": FLIPBOOK, "bytes": size, "per_gaussian": size / n, **got}
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
    if "psnr_mean" in rows[-1]:
        target = rows[-1]["psnr_mean"]
        rows.append(lowest_quality_at(name, scene, rows, target, views=(ts, cameras)))
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def lowest_quality_at(
    name: str,
    scene: Scene,
    rows: list[dict[str, Any]],
    target: float,
    *,
    views: tuple[list[float], list[Any]],
) -> dict[str, Any]:
    """The row of the lowest quality whose mean PSNR reaches ``target``, found by bisection
    over the integer qualities (the measured ones reused): a file measured at that PSNR rather
    than a line between two qualities. Quality 0 when even it is above the target."""
    measured = {r["quality"]: r for r in rows if "quality" in r}

    def at(quality: int) -> dict[str, Any]:
        if quality not in measured:
            measured[quality] = measured_at(scene, quality, views=views)
        return measured[quality]

    low, high = 0, QUALITY_MAX
    if at(low)["psnr_mean"] >= target:
        high = low
    while high - low > 1:
        mid = (low + high) // 2
        if at(mid)["psnr_mean"] >= target:
            high = mid
        else:
            low = mid
    row = {k: v for k, v in at(high).items() if k in ("bytes", "per_gaussian") or "psnr" in k}
    return {"scene": name, "variant": MATCHED, "matched_quality": high, **row}


def measured_at(
    scene: Scene, quality: int, *, views: tuple[list[float], list[Any]]
) -> dict[str, Any]:
    """Bytes and rendered PSNR/SSIM of the scene as one TSOG chunk at ``quality``, at the
    given (times, cameras) against the exact source; stored as `tsog encode` does, less the
    Gaussians too faint for the quality (bytes per Gaussian of the source)."""
    files = encode_chunk(without_faint(scene, quality), quality=quality)
    size = len(bundle_bytes(files))
    ts, cameras = views
    got = score(dynamic(scene), dynamic(decode_chunk(files)), ts, cameras)
    return {"bytes": size, "per_gaussian": size / len(scene), **got}


MATCHED = "TSOG, the lowest quality at `.4dgs`'s PSNR"
"""The variant of :func:`lowest_quality_at`'s row."""


def eight_bit(files: dict[str, bytes]) -> dict[str, bytes]:
    """The paper's 8-bit ablation of a TSOG chunk: every timeline and motion code rounded to its
    high byte (the ``_l`` planes all zero); the SOG attributes as they were."""
    meta = read_meta(files, where="ablation")
    pairs = [(tuple(meta.timeline.files), 2)] if meta.timeline is not None else []
    for entry in (meta.temporal or {}).values():
        channels = len(entry.mins[0])
        pairs += [(tuple(entry.files[k : k + 2]), channels) for k in range(0, len(entry.files), 2)]
    out = dict(files)
    for (low_name, high_name), channels in pairs:
        low = decode_webp(files[low_name], where=low_name).copy()
        high = decode_webp(files[high_name], where=high_name).copy()
        codes = low[..., :channels].astype(np.int64) | (high[..., :channels].astype(np.int64) << 8)
        high[..., :channels] = np.minimum((codes + 128) >> 8, 255)
        low[..., :channels] = 0
        out[low_name], out[high_name] = encode_webp(low), encode_webp(high)
    return out


def flipbook(scene: Scene, ts: list[float]) -> tuple[int, Callable[[float], Gaussians]]:
    """(bytes, the frame shown at t) of the scene as one SOG per frame at FLIPBOOK_FPS, each
    frame the Gaussians visible at its start (an empty frame costs nothing)."""
    assert scene.timeline is not None
    first, last = time_range(scene.timeline)
    count = int(np.floor((last - first) * FLIPBOOK_FPS)) + 1
    wanted = {min(int((t - first) * FLIPBOOK_FPS), count - 1) for t in ts}
    size, kept = 0, {}
    for k in range(count):
        frame = evaluate_at(scene, first + k / FLIPBOOK_FPS)
        if len(frame) == 0:
            continue
        files = encode_chunk(Scene(frame))
        size += len(bundle_bytes(files))
        if k in wanted:
            kept[k] = decode_chunk(files).gaussians
    empty = evaluate_at(scene, first).subset(np.zeros(0, np.intp))

    def shown(t: float) -> Gaussians:
        return kept.get(min(int((t - first) * FLIPBOOK_FPS), count - 1), empty)

    return size, shown


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


def chart_name(scene: str) -> str:
    """The chart file of a scene: its name in lower case, runs of other characters as '-'."""
    return re.sub(r"[^a-z0-9]+", "-", scene.lower()).strip("-") + ".png"


def write_charts(all_rows: list[dict[str, Any]]) -> None:
    """One PNG per scene: TSOG's PSNR against bytes per Gaussian over the qualities, and the
    other variants' points (one far off the chart, a flipbook, is named below it instead)."""
    CHARTS.mkdir(parents=True, exist_ok=True)
    for name in dict.fromkeys(r["scene"] for r in all_rows):
        rows = [r for r in all_rows if r["scene"] == name and "bytes" in r]
        tsog = sorted(
            (r["per_gaussian"], r["psnr_mean"], r["quality"]) for r in rows if "quality" in r
        )
        points = [(size, psnr) for size, psnr, _ in tsog]
        tags = [f"q{quality}" for _, _, quality in tsog]
        series = [Series("TSOG, quality 0 to 100", TSOG_COLOUR, points, tags=tags)]
        widest = OFF_CHART * max(size for size, _ in points)
        off = [r for r in rows if r["per_gaussian"] > widest]
        for variant, label, colour in (
            (ABLATION, "8-bit timeline and motion (paper's ablation)", ABLATION_COLOUR),
            (FLIPBOOK, FLIPBOOK, FLIPBOOK_COLOUR),
            (".4dgs", ".4dgs (fourdgs defaults)", PEER_COLOUR),
        ):
            series += [
                Series(label, colour, [(r["per_gaussian"], r["psnr_mean"])], joined=False)
                for r in rows
                if r["variant"] == variant and r not in off
            ]
        note = "; ".join(
            f"off the chart: {r['variant']} {r['per_gaussian']:.0f} B, {r['psnr_mean']:.1f} dB"
            for r in off
        )
        image = line_chart(
            f"{name}: rendered PSNR (mean over views and times) against size",
            ("bytes per Gaussian", "PSNR\n(dB)"),
            series,
            note=note,
        )
        write_png(image, CHARTS / chart_name(name))


def markdown(all_rows: list[dict[str, Any]], stamp: str, views: int, times: int) -> str:
    """The rate section of docs/benchmarks.md."""
    lines = [
        "## Rate and distortion: `--quality` against `.4dgs`",
        "",
        f"Run {stamp} (`benchmarks/bench_rate.py`): one TSOG chunk per scene at each quality, "
        "the paper's 8-bit ablation (TSOG q100 with every timeline and motion code rounded to "
        f"its high byte), the scene as `.4dgs` (fourdgs defaults) and as one SOG per frame at "
        f"{FLIPBOOK_FPS:g} fps (a flipbook; our SOG v2 encoder), each rendered with the CPU rasterizer "
        f"against the exact source at {times} times x {views} orbit views ({SIZE[0]}x{SIZE[1]}); "
        "PSNR in dB (mean over the images; worst image). *x .4dgs*: bytes against `.4dgs`'s; "
        "at `.4dgs`'s PSNR, interpolated between qualities and, measured, the lowest quality "
        "whose mean PSNR reaches it (bisection over 0..100; < when even quality 0 is above it). "
        f"*encode s*: the median of {ENCODE_ROUNDS} or more rounds (~{ENCODE_BUDGET_S:g} s of "
        "encoding in all) encoding the scene at every quality in turn; *encode x q100*: "
        "against quality 100 in the same rounds (against the encoder of the day issue 17 was "
        "filed: bench_encode_then's section).",
        "Charts: "
        + ", ".join(
            f"[{name}](rate/{chart_name(name)})"
            for name in dict.fromkeys(r["scene"] for r in all_rows)
        )
        + ".",
        "",
        "| scene | variant | B/Gaussian | PSNR mean | PSNR worst | x .4dgs bytes | encode s "
        "| encode x q100 |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name in dict.fromkeys(r["scene"] for r in all_rows):
        rows = [r for r in all_rows if r["scene"] == name]
        ref = next((r for r in rows if r["variant"] == ".4dgs" and "bytes" in r), None)
        for r in rows:
            if "error" in r:
                lines.append(f"| {name} | {r['variant']} | {r['error']} | | | | | |")
                continue
            ratio = f"{r['bytes'] / ref['bytes']:.2f}" if ref else "–"
            variant = r["variant"]
            if "matched_quality" in r:
                variant = f"TSOG q{r['matched_quality']}, the lowest quality at `.4dgs`'s PSNR"
                ratio = f"{r['bytes'] / ref['bytes']:.3f}" if ref else "–"  # the target's edge
                if r["matched_quality"] == 0:
                    ratio = f"< {ratio}"
            secs = f"{r['encode_s']:.3f}" if "encode_s" in r else ""
            slower = f"{r['encode_x_q100']:.2f}" if "encode_x_q100" in r else ""
            lines.append(
                f"| {name} | {variant} | {r['per_gaussian']:.2f} | {r['psnr_mean']:.1f} | "
                f"{r['psnr_worst']:.1f} | {ratio} | {secs} | {slower} |"
            )
        if ref is not None:
            same = at_psnr(rows, ref["psnr_mean"])
            if same is None:
                said = "not reached"
            else:
                said = f"{'' if same[1] else '< '}{same[0] / ref['bytes']:.2f}x"
            lines.append(
                f"| {name} | TSOG at `.4dgs`'s {ref['psnr_mean']:.1f} dB (interpolated) | | | | "
                f"{said} | | |"
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
        write_charts(saved["rows"])
        return 0
    rows: list[dict[str, Any]] = []
    for name, scene in scenes():
        rows += rows_for(name, scene, args.views, args.times)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "rate.json").write_text(json.dumps({"date": stamp, "rows": rows}, indent=2))
    write_section("rate", markdown(rows, stamp, args.views, args.times), "bench_rate.py")
    write_charts(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Segmenter benchmark: policies and window lengths by seek cost; throughput and peak memory.

    .venv/bin/python benchmarks/bench_segment.py content      # default layout per input (minutes)
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
import functools
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from fourdgs.indexed_reader import open_indexed  # type: ignore[import-untyped]
from fourdgs.readable import BytesReadable  # type: ignore[import-untyped]

from common import SPLAT_TRANSFORM, run_measured, sample, write_section
from tsog_stream import TimelineType
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.container.header import PREFIX_SIZE
from tsog_stream.errors import TsogError
from tsog_stream.io.fourdgs import encode_4dgs
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import ReadOptions, load_scene
from tsog_stream.model import Scene
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, freetime_scene, generate_scene, static_gaussians
from tsog_stream.temporal import time_range

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


FLIPBOOKS = {
    "monkey flipbook (50 SOG)": "4d/pc_flipbook_monkey",
    "wave flipbook (50 SOG)": "4d/pc_flipbook_wave",
    "fireworks (6 PLY frames)": "4d/tztechno_fireworks_frames",
}
SPLATV = ("coffee10", "coffeeshort2", "spinach_4", "yellow_clip2")
LIFESPANS = {"short": (0.005, 0.02), "medium": (0.05, 0.2), "long": (0.5, 1.0)}
"""FreeTimeGS-style scenes from the real 45k donut: lifespans as fractions of a 10 s clip."""


def _seek_figures(path: Path, reference: list[int] | None, samples: int) -> dict[str, float]:
    """Mean bytes and requests to show a random t, opening included, and the ratio to what
    is shown: the frame's own file (``reference``, a flipbook) or the visible Gaussians."""
    with open_stream(path) as reader:
        header = reader.index.header
        opening = PREFIX_SIZE + (0 if header.index_offset < PREFIX_SIZE else header.index_length)
        scene = reader.index.manifest.scene
        times = np.random.default_rng(1).uniform(scene.start_s, scene.end_s, samples)
        costs = [reader.seek_cost(float(t)) for t in times]
        fps = reader.index.manifest.scene.fps
    fetched = np.array([c.bytes for c in costs], float) + opening
    if reference is not None and fps:
        frame = np.minimum(((times - scene.start_s) * fps).astype(int), len(reference) - 1)
        shown = np.array([reference[k] for k in frame], float)
    else:
        shown = np.array([c.visible_bytes for c in costs], float)
    return {
        "seek_bytes": float(fetched.mean()),
        "shown_bytes": float(shown.mean()),
        "seek_ratio": float(fetched.mean() / (shown.mean() + PREFIX_SIZE)),
        "requests": 1 + float(np.mean([c.requests for c in costs])),
    }


def _fourdgs_figures(scene: Scene, samples: int) -> dict[str, float]:
    """.4dgs (fourdgs defaults) bytes and mean bytes a seek reads: the chunks covering t plus
    everything that is not a chunk (header, index), which an opening reads at most."""
    try:
        data, _ = encode_4dgs(scene, lossy=True)
    except TsogError as exc:
        return {"4dgs_error": str(exc)[:120]}  # type: ignore[dict-item]
    indexed = open_indexed(BytesReadable(data))
    chunks = sum(e.chunk_length + sum(b[2] for b in e.bands) for e in indexed.index)
    first, last = time_range(scene.timeline) if scene.timeline is not None else (0.0, 1.0)
    times = np.random.default_rng(1).uniform(first, last, samples)
    seeks = [indexed.bytes_for_time(float(t), max_sh_band=3) for t in times]
    return {"4dgs_bytes": len(data), "4dgs_seek": len(data) - chunks + float(np.mean(seeks))}


def _content_cases(work: Path) -> list[tuple[str, Path, list[int] | None, Scene | None]]:
    """(name, input path, per-frame file sizes of a flipbook, scene for .4dgs) per input."""
    cases: list[tuple[str, Path, list[int] | None, Scene | None]] = []
    for name, rel in FLIPBOOKS.items():
        folder = sample(rel, in_tree=False) if "monkey" in name else sample(rel)
        files = sorted(p for p in folder.iterdir() if p.suffix in (".sog", ".ply"))
        cases.append((name, folder, [_own_sog_bytes(p) for p in files], None))
    generated = work / "independent"
    generated.mkdir()
    sizes = []
    for k in range(12):  # independently made frames: nothing corresponds
        path = generated / f"frame_{k:03d}.sog"
        path.write_bytes(bundle_bytes(encode_chunk(Scene(static_gaussians(30_000, seed=50 + k)))))
        sizes.append(path.stat().st_size)
    cases.append(("12 independent generated frames (SOG)", generated, sizes, None))
    resampled, sizes = _resampled_frames(work)
    cases.append(("12 re-sampled donut frames (splat-transform SOG)", resampled, sizes, None))
    for clip in SPLATV:
        path = sample(f"4d/splatv/macaburguera_{clip}.splatv", in_tree=False)
        cases.append((f"{clip}.splatv (1 s)", path, None, load_scene(path).scene))
    donut = load_scene(sample("3dgs/v3dg_donut_fused.ply")).scene.gaussians
    for label, life in LIFESPANS.items():
        scene = freetime_scene(donut, duration_s=10.0, lifespan=life, seed=7)
        path = work / f"donut-{label}.sog"  # a 4D chunk is an input like any other
        path.write_bytes(bundle_bytes(encode_chunk(scene)))
        cases.append((f"donut FreeTimeGS {label} ({life[0]:.1%}-{life[1]:.0%})", path, None, scene))
    return cases


def _resampled_frames(work: Path, count: int = 12) -> tuple[Path, list[int]]:
    """A flipbook as a user would hold one of separately trained frames of a real scene: each
    frame 90 % of the real donut's Gaussians, drawn anew, moved by up to about their smallest
    axis and with every attribute perturbed (so nothing corresponds within a merge's
    tolerance), written by splat-transform, the reference SOG codec. Its folder and sizes."""
    donut = load_scene(sample("3dgs/v3dg_donut_fused.ply")).scene.gaussians
    folder = work / "resampled"
    folder.mkdir()
    for k in range(count):
        rng = np.random.default_rng(100 + k)
        g = donut.subset(np.sort(rng.choice(len(donut), int(0.9 * len(donut)), replace=False)))
        axis = np.exp(g.scales.astype(np.float64)).min(axis=1, keepdims=True)
        g = replace(
            g,
            means=_noisy(rng, g.means, axis),
            scales=_noisy(rng, g.scales, 0.05),
            opacities=_noisy(rng, g.opacities, 0.2),
            sh0=_noisy(rng, g.sh0, 0.03),
            quats=_noisy(rng, g.quats, 0.03),
        )
        ply = work / "frame.ply"
        write_ply(ply, g)
        out = folder / f"frame_{k:03d}.sog"
        m = run_measured([str(SPLAT_TRANSFORM), "-w", "-g", "cpu", str(ply), str(out)], 600)
        if not m["finished"] or not out.exists():
            raise SystemExit(f"splat-transform failed on frame {k}: {m.get('error', '')}")
    return folder, [p.stat().st_size for p in sorted(folder.iterdir())]


def _noisy(rng: np.random.Generator, values: np.ndarray, sigma: np.ndarray | float) -> np.ndarray:
    """``values`` plus normal noise of deviation ``sigma``, as float32."""
    return (values + rng.normal(0.0, 1.0, values.shape) * sigma).astype(np.float32)


def _own_sog_bytes(frame: Path) -> int:
    """Bytes of a frame as a SOG of its own: the file for a .sog, our encoding of a PLY."""
    if frame.suffix == ".sog":
        return frame.stat().st_size
    return len(bundle_bytes(encode_chunk(load_scene(frame).scene)))


def _frames_encode_seconds(folder: Path, work: Path) -> tuple[float, float, float]:
    """Seconds to encode each frame of a folder to its own SOG, one after another: with
    `tsog encode FRAME` per frame (as a user would, each a process), and in one process; and
    the largest peak RSS (MiB) of those `tsog encode` processes."""
    frames = sorted(folder.iterdir())
    start = time.monotonic()
    peak = 0.0
    for frame in frames:
        out = work / "frame.sog"
        m = run_measured([str(TSOG), "encode", str(frame), str(out), "-f", "-q"])
        if not m["finished"]:
            raise SystemExit(f"tsog encode {frame} failed: {m.get('error', '')}")
        peak = max(peak, m["peak_mib"])
    processes = time.monotonic() - start
    start = time.monotonic()
    for frame in frames:
        bundle_bytes(encode_chunk(load_scene(frame).scene))
    return processes, time.monotonic() - start, peak


def _memory_figures(folder: Path, work: Path) -> dict[str, float]:
    """What segmenting a frame folder holds beyond a process's fixed cost (see
    :func:`_fixed_cost_mib`), and one frame's decoded arrays (MiB)."""
    g = load_scene(sorted(folder.iterdir())[0]).scene.gaussians
    arrays = sum(a.nbytes for a in (g.means, g.scales, g.quats, g.opacities, g.sh0, g.shN))
    return {"baseline_mib": _fixed_cost_mib(work), "window_arrays_mib": arrays / 2**20}


def _one_frame_memory(folder: Path, work: Path) -> dict[str, float]:
    """What encoding one frame alone holds (MiB) above the same command on a 64-Gaussian frame
    (the fewest of two runs each): ours (`tsog encode`) and the reference SOG codec's
    (splat-transform), the floor a window's encoder sets under segmenting's memory."""
    _fixed_cost_mib(work)  # makes work/tiny
    frame, tiny = sorted(folder.iterdir())[0], work / "tiny" / "frame_000.sog"
    out = {}
    for tool in ("ours", "reference"):
        peaks = [
            min(
                run_measured(_encode_command(tool, src, work / "one.sog"))["peak_mib"]
                for _ in range(2)
            )
            for src in (frame, tiny)
        ]
        out[f"one_frame_{tool}_mib"] = peaks[0] - peaks[1]
    return out


def _encode_command(tool: str, frame: Path, out: Path) -> list[str]:
    """The command encoding ``frame`` to the SOG ``out``: ours or the reference codec's."""
    if tool == "ours":
        return [str(TSOG), "encode", str(frame), str(out), "-f", "-q"]
    return [str(SPLAT_TRANSFORM), "-w", "-g", "cpu", str(frame), str(out)]


@functools.cache
def _fixed_cost_mib(work: Path) -> float:
    """The peak RSS of `tsog segment` on two frames of 64 Gaussians (imports, worker
    processes, the renderer that draws the thumbnail): measured once per run."""
    tiny = work / "tiny"
    tiny.mkdir()
    for k in range(2):  # one file is not a sequence: the command would only fail
        frame = bundle_bytes(encode_chunk(Scene(static_gaussians(64, seed=k))))
        (tiny / f"frame_{k:03d}.sog").write_bytes(frame)
    cmd = [str(TSOG), "segment", str(tiny), "-o", str(work / "tiny.tsogs"), "-f", "-q"]
    base = run_measured([*cmd, "--workers", "2"])
    if not (work / "tiny.tsogs").exists():
        raise SystemExit("the baseline segmentation did not write its container")
    return float(base["peak_mib"])


def content(args: argparse.Namespace) -> None:
    """The default layout on every kind of input: file, seek bytes against what is shown,
    requests, time and peak RSS of `tsog segment`, beside the flipbook and .4dgs."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="tsog-content-") as tmp:
        for name, path, frames, scene in _content_cases(Path(tmp)):
            out = Path(tmp) / "out.tsogs"
            cmd = [str(TSOG), "segment", str(path), "-o", str(out), "-f", "-q", "--workers", "2"]
            m = run_measured(cmd)
            if not m["finished"]:
                raise SystemExit(f"{cmd} failed:\n{m.get('error', '')}")
            size = _input_bytes(path)
            row: dict[str, Any] = {
                "input": name,
                "input_bytes": size,
                "bytes": out.stat().st_size,
                "layout": _layout_of(out),
                "seconds": m["seconds"],
                "peak_mib": m["peak_mib"],
                **_seek_figures(out, frames, args.samples),
            }
            if frames is not None:
                row["own_bytes"] = sum(frames)
            if frames is not None and path.name in ("independent", "resampled"):
                by_process, in_process, encode_peak = _frames_encode_seconds(path, Path(tmp))
                row["frames_encode_s"] = round(by_process, 2)
                row["frames_encode_in_process_s"] = round(in_process, 2)
                row["frame_encode_peak_mib"] = encode_peak
                row.update(_memory_figures(path, Path(tmp)))
                row.update(_one_frame_memory(path, Path(tmp)))
            if scene is not None:
                row.update(_fourdgs_figures(scene, args.samples))
            print(json.dumps(row), flush=True)
            rows.append(row)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    (RESULTS / "segment-content.json").write_text(
        json.dumps({"date": stamp, "rows": rows}, indent=2)
    )
    write_section("segment-content", _content_table(stamp, rows, args.samples), "bench_segment.py")


def _input_bytes(path: Path) -> int:
    """Bytes of an input file or of every file of a frame folder."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    return path.stat().st_size


def _layout_of(path: Path) -> str:
    """'50 windows of 1 frame, hybrid, 50 chunks' from a written container."""
    with open_stream(path) as reader:
        manifest = reader.index.manifest
        fps = manifest.scene.fps
        window = manifest.window_s
        frames = f"{window * fps:.3g} frame(s)" if fps else f"{window:.3g} s"
        return f"{frames}, {manifest.policy}, {len(manifest.chunks)} chunks"


def _content_table(stamp: str, rows: list[dict[str, Any]], samples: int) -> str:
    """The markdown table of the content part."""
    lines = [
        "## Segmenting real content: the layout chosen per input",
        "",
        f"Run {stamp}: default `tsog segment INPUT -o OUT --workers 2` as a child process "
        f"(time and peak RSS of it and its workers). *seek*: mean bytes to show one of "
        f"{samples} random t (seeded), the 16 KiB opening included; *shown*: that frame's own "
        "file for a flipbook, else the bytes of the Gaussians visible at t in a chunk of their "
        "own; *ratio*: seek / (shown + 16 KiB), target <= 1.25; *x own SOGs*: the container "
        "against every frame as a SOG of its own (the flipbook's files; our encoding of PLY "
        "frames). `.4dgs`: fourdgs defaults "
        "(lossy where it cannot hold the motion); its seek is the chunks covering t plus "
        "everything in the file that is not a chunk.",
        "",
        "| input | input MB | layout chosen | .tsogs MB | x input | x own SOGs | seek kB | shown kB | ratio | requests | s | peak MiB | .4dgs MB | .4dgs seek kB |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        fourdgs = (
            f"{r['4dgs_bytes'] / 1e6:.2f} | {r['4dgs_seek'] / 1e3:.0f}"
            if "4dgs_bytes" in r
            else "– | –"
        )
        own = f"{r['bytes'] / r['own_bytes']:.2f}" if "own_bytes" in r else "–"
        lines.append(
            f"| {r['input']} | {r['input_bytes'] / 1e6:.2f} | {r['layout']} | "
            f"{r['bytes'] / 1e6:.2f} | {r['bytes'] / r['input_bytes']:.2f} | {own} | "
            f"{r['seek_bytes'] / 1e3:.0f} | {r['shown_bytes'] / 1e3:.0f} | {r['seek_ratio']:.2f} | "
            f"{r['requests']:.1f} | {r['seconds']:.1f} | {r['peak_mib']:.0f} | {fourdgs} |"
        )
    timed = [r for r in rows if "frames_encode_s" in r]
    for r in timed:
        lines += [
            "",
            f"{r['input']}: segmenting took {r['seconds']:.1f} s against "
            f"{r['frames_encode_s']:.1f} s for `tsog encode` on each frame "
            f"({r['seconds'] / r['frames_encode_s']:.2f}x) and "
            f"{r['frames_encode_in_process_s']:.1f} s to encode them one by one inside one "
            f"process ({r['seconds'] / r['frames_encode_in_process_s']:.2f}x; segmenting "
            "includes its process start, about 0.7 s).",
            f"Memory: segmenting peaked at {r['peak_mib']:.0f} MiB (the largest of the process "
            f"and its 2 workers), against {r['baseline_mib']:.0f} MiB for segmenting two "
            f"frames of 64 Gaussians the same way (the fixed cost: imports, workers, the "
            f"renderer that draws the thumbnail; before 2026-11-26 a one-file baseline that "
            f"failed was measured) and "
            f"{r['frame_encode_peak_mib']:.0f} MiB for `tsog encode` of one frame: above the "
            f"fixed cost it holds {r['peak_mib'] - r['baseline_mib']:.0f} MiB, "
            f"{(r['peak_mib'] - r['baseline_mib']) / r['window_arrays_mib']:.1f}x one window's "
            f"decoded arrays ({r['window_arrays_mib']:.1f} MiB: one frame), the encoder's "
            "working arrays included. Encoding that one frame alone holds, above the same "
            f"command on a 64-Gaussian frame: `tsog encode` {r['one_frame_ours_mib']:.0f} MiB "
            f"({r['one_frame_ours_mib'] / r['window_arrays_mib']:.1f}x), splat-transform, the "
            f"reference SOG codec, {r['one_frame_reference_mib']:.0f} MiB "
            f"({r['one_frame_reference_mib'] / r['window_arrays_mib']:.1f}x).",
        ]
    return "\n".join(lines) + "\n"


def main() -> int:
    """Dispatch the benchmark parts."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="part", required=True)
    p = sub.add_parser("content")
    p.add_argument("--samples", type=int, default=64)
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
    {"content": content, "policies": policies, "scale": scale}[args.part](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

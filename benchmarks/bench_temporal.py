"""Frame sequences stored once: ``tsog segment --temporal off|merge|fit`` on real and generated
sequences, against the PLY sequence and one SOG per frame (what a flipbook player loads).

    .venv/bin/python benchmarks/bench_temporal.py [--quick]

Sequences: the monkey and wave SOG flipbooks (50 frames each), the fireworks PLY sequence and a
generated 300-frame sequence (70% static background, 30% moving along smooth paths). For each
mode: container size, Gaussians stored, merge + segment seconds, and the worst per-frame error
per attribute against the source frames (sampled frames, decoded from the container), beside
the worst error of one SOG per frame on the same frames. Writes benchmarks/results/temporal.json
and the "temporal" section of docs/benchmarks.md.
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

from common import sample, write_section
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.io.objects import size_of
from tsog_stream.io.ply import ply_bytes, write_ply
from tsog_stream.io.sequence import FrameSequence, open_sequence
from tsog_stream.merge import merge_sequence
from tsog_stream.merge.check import frame_errors
from tsog_stream.model import Gaussians, Scene
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.synthetic import static_gaussians

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
MODES = ("off", "merge", "fit")
ERROR_KEYS = ("means", "scales", "quats", "sh0", "alpha")


def generated_sequence(folder: Path, frames: int, count: int, fps: float = 30.0) -> None:
    """``frames`` PLY frames of ``count`` Gaussians: 70% static, 30% on quadratic paths."""
    moving_n = int(count * 0.3)
    background = static_gaussians(count - moving_n, sh_bands=1, seed=11)
    movers = static_gaussians(moving_n, sh_bands=1, seed=12)
    rng = np.random.default_rng(13)
    velocity = rng.normal(0, 0.3, (moving_n, 3))
    accel = rng.normal(0, 0.1, (moving_n, 3))
    folder.mkdir(parents=True)
    for k in range(frames):
        t = k / fps
        path = movers.means + velocity * t + accel * t * t
        moved = Gaussians.from_arrays(
            path, movers.scales, movers.quats, movers.opacities, movers.sh0, shN=movers.shN
        )
        write_ply(folder / f"frame_{k:04d}.ply", Gaussians.concat([background, moved]))


def sampled(count: int, samples: int) -> list[int]:
    """Up to ``samples`` frame numbers spread over the sequence."""
    return sorted({round(x) for x in np.linspace(0, count - 1, min(samples, count))})


def per_frame_sog(seq: FrameSequence, frames: list[int]) -> tuple[int, dict[str, float]]:
    """Bytes of one SOG per frame (the files for SOG input, else our encoder) and the worst
    error of those SOGs on ``frames``."""
    total, worst = 0, dict.fromkeys(ERROR_KEYS, 0.0)
    for k in range(seq.count):
        path = seq.frames.paths[k]
        g = seq.read(k, k + 1).scene.gaussians
        if seq.frames.kind == "sog":
            total += size_of(path)
            continue
        files = encode_chunk(Scene(g))
        total += len(bundle_bytes(files))
        if k in frames:
            errors, _ = frame_errors(g, decode_chunk(files).gaussians)
            for key in ERROR_KEYS:
                worst[key] = max(worst[key], errors.get(key, 0.0))
    return total, worst


def ply_sequence_bytes(seq: FrameSequence) -> int:
    """Bytes of the sequence as float 3DGS PLYs (the files themselves for PLY input)."""
    if seq.frames.kind == "ply":
        return sum(size_of(p) for p in seq.frames.paths)
    return sum(len(ply_bytes(seq.read(k, k + 1).scene.gaussians)) for k in range(seq.count))


def run_mode(seq: FrameSequence, mode: str, out: Path, frames: list[int]) -> dict[str, Any]:
    """Segment ``seq`` with --temporal ``mode``; size, count, seconds, worst frame errors."""
    options = SegmentOptions()
    start = time.monotonic()
    if mode == "off":
        report = segment_sequence(seq, out, options)
        stored = report.stored
    else:
        scene, stats = merge_sequence(seq, mode, max_held=None)  # type: ignore[arg-type]
        if scene is None:
            raise RuntimeError("merge_sequence gave no scene without a memory bound")
        report = segment_scene(scene, out, options)
        stored = stats.gaussians_out
    seconds = time.monotonic() - start
    worst, unpaired = dict.fromkeys(ERROR_KEYS, 0.0), 0
    with open_stream(out) as reader:
        for k in frames:
            errors, missing = frame_errors(
                seq.read(k, k + 1).scene.gaussians, reader.frame_at(k / seq.fps)
            )
            unpaired += missing
            for key in ERROR_KEYS:
                worst[key] = max(worst[key], errors.get(key, 0.0))
    return {
        "bytes": out.stat().st_size,
        "stored": stored,
        "seconds": round(seconds, 2),
        "worst": worst,
        "unpaired": unpaired,
    }


def measure(name: str, source: Path, fps: float, work: Path, samples: int) -> dict[str, Any]:
    """Every mode on one sequence, with the two baselines."""
    seq = open_sequence(source, fps=fps)
    frames = sampled(seq.count, samples)
    print(f"{name}: {seq.count} frames, {seq.gaussians} Gaussians", file=sys.stderr)
    sog_bytes, sog_worst = per_frame_sog(seq, frames)
    row: dict[str, Any] = {
        "name": name,
        "frames": seq.count,
        "gaussians": seq.gaussians,
        "ply_bytes": ply_sequence_bytes(seq),
        "sog_bytes": sog_bytes,
        "sog_worst": sog_worst if seq.frames.kind == "ply" else None,
        "frames_checked": frames,
    }
    for mode in MODES:
        row[mode] = run_mode(seq, mode, work / f"{mode}.tsogs", frames)
        print(f"  {mode}: {row[mode]}", file=sys.stderr)
    return row


def _errors(worst: dict[str, float] | None) -> str:
    if worst is None:
        return "(input)"
    return " / ".join(f"{worst[k]:.2g}" for k in ERROR_KEYS)


def markdown(rows: list[dict[str, Any]], stamp: str) -> str:
    """The benchmarks.md section."""
    lines = [
        f"## Frame sequences stored once (`--temporal`, {stamp})\n",
        "Container sizes of `tsog segment --temporal off|merge|fit` (default tolerance), against",
        "the sequence as float PLYs and as one SOG per frame (the flipbook files themselves for",
        "the SOG inputs, our encoder for PLY inputs). Worst error on the checked frames, decoded",
        "from the container and paired with the source frame by position: means (scene units) /",
        "log-scales / quaternion components / f_dc / alpha. Seconds: merge + segment, 2 workers.\n",
        "| sequence | frames | Gaussians | PLY | SOG per frame | mode | container | vs PLY | vs SOG per frame | vs off | stored | seconds | worst error |",
        "| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for row in rows:
        ply, sog, off = row["ply_bytes"], row["sog_bytes"], row["off"]["bytes"]
        lines.append(
            f"| {row['name']} | {row['frames']} | {row['gaussians']} | {ply} | {sog} | SOG per "
            f"frame | {sog} | {sog / ply:.3f} | 1 | | {row['gaussians']} | | {_errors(row['sog_worst'])} |"
        )
        for mode in MODES:
            r = row[mode]
            lines.append(
                f"| | | | | | {mode} | {r['bytes']} | {r['bytes'] / ply:.3f} | "
                f"{r['bytes'] / sog:.3f} | {r['bytes'] / off:.3f} | {r['stored']} | "
                f"{r['seconds']} | {_errors(r['worst'])} |"
            )
    lines.append("")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="a 60-frame generated sequence")
    parser.add_argument("--samples", type=int, default=8, help="frames checked per sequence")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        frames = 60 if args.quick else 300
        generated = work / "generated"
        generated_sequence(generated, frames, 10_000)
        inputs = [
            ("monkey SOG flipbook", sample("4d/pc_flipbook_monkey", in_tree=False), 30.0),
            ("wave SOG flipbook", sample("4d/pc_flipbook_wave", in_tree=False), 30.0),
            ("fireworks PLY sequence", sample("4d/tztechno_fireworks_frames"), 6.0),
            (f"generated, 70% static ({frames} frames)", generated, 30.0),
        ]
        for name, source, fps in inputs:
            folder = work / name.split()[0]
            folder.mkdir(exist_ok=True)
            rows.append(measure(name, source, fps, folder, args.samples))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "temporal.json").write_text(json.dumps(rows, indent=1))
    stamp = dt.date.today().isoformat()
    write_section("temporal", markdown(rows, stamp), "bench_temporal.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

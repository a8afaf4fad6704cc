"""Sizes and errors of TSOG versus each 4D input format and versus ``.4dgs`` on the same scene.

    .venv/bin/python benchmarks/bench_inputs.py

For every input: its own size, the baselines of the TSOG paper computed from the same scene
(a PLY sequence at the scene's frame rate; one extended FreeTimeGS-style PLY), the TSOG chunk,
the segmented ``.tsogs`` container (defaults), and ``.4dgs`` written by the ``fourdgs`` package
(default profile; motion it cannot hold is dropped and said so). Errors: worst position error
and mean opacity error over 9 times, against the input evaluated directly.
Writes benchmarks/results/inputs.json and the "inputs" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from common import sample, write_section
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.demo import errors_over_time, extended_ply_size
from tsog_stream.io.fourdgs import encode_4dgs, parse_4dgs
from tsog_stream.io.readers import ReadOptions, load_scene
from tsog_stream.model import Scene
from tsog_stream.segment import segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene
from tsog_stream.temporal import time_range

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
PLY_ROW_FLOATS = 17  # x y z nx ny nz f_dc*3 opacity scale*3 rot*4, before SH rest
PLY_HEADER = 400
FPS = 30.0


def inputs() -> list[tuple[str, Path | None, ReadOptions]]:
    """The inputs measured (their files found when the benchmark runs, not at import)."""
    return [
        (
            "fireworks PLY sequence (6 frames)",
            sample("4d/tztechno_fireworks_frames"),
            ReadOptions(fps=6),
        ),
        (
            "wave SOG flipbook (50 frames)",
            sample("4d/pc_flipbook_wave", in_tree=False),
            ReadOptions(fps=30),
        ),
        (
            "monkey SOG flipbook (50 frames)",
            sample("4d/pc_flipbook_monkey", in_tree=False),
            ReadOptions(fps=30),
        ),
        (
            "hanabi2 .splatv (synthetic)",
            sample("4d/splatv/tztechno_hanabi2_synthetic.splatv"),
            ReadOptions(),
        ),
        (
            "coffee10 .splatv (real)",
            sample("4d/splatv/macaburguera_coffee10.splatv"),
            ReadOptions(),
        ),
        (
            "spinach_4 .splatv (real)",
            sample("4d/splatv/macaburguera_spinach_4.splatv"),
            ReadOptions(duration_s=5.0),
        ),
        ("synthetic FreeTimeGS-like (SH3)", None, ReadOptions()),
    ]


def input_bytes(path: Path | None) -> int:
    """Bytes of an input file or of the files of an input folder."""
    if path is None:
        return 0
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    return path.stat().st_size


def ply_sequence_bytes(scene: Scene, fps: float) -> int:
    """Bytes of the scene exported as one PLY per frame (the paper's first baseline)."""
    first, last = time_range(scene.timeline) if scene.timeline else (0.0, 0.0)
    frames = max(1, round((last - first) * fps))
    row = 4 * (PLY_ROW_FLOATS + 3 * scene.gaussians.shN.shape[1])
    visible = [len(scene.at(first + (k + 0.5) / fps)) for k in range(frames)]
    return sum(PLY_HEADER + n * row for n in visible)


def error_summary(source: Scene, candidate: Scene, times: np.ndarray) -> dict[str, float]:
    """Worst position error and mean alpha error over ``times`` (index-aligned scenes)."""
    rows = [r for r in errors_over_time(source, candidate, times.tolist()) if r["count"] > 0]
    return {
        "pos_max": max((r["means_max"] for r in rows), default=0.0),
        "alpha_mean": float(np.mean([r["opacity_mean"] for r in rows])) if rows else 0.0,
    }


def fourdgs_row(scene: Scene, times: np.ndarray) -> dict[str, Any]:
    """.4dgs size, notes and errors (lossy where the model cannot hold the motion)."""
    try:
        data, notes = encode_4dgs(scene, keep_order=True, lossy=True)
    except Exception as exc:
        return {"4dgs_error": str(exc)[:200]}
    back = parse_4dgs(data).scene
    return {
        "4dgs_bytes": len(data),
        "4dgs_notes": notes,
        **{f"4dgs_{k}": v for k, v in error_summary(scene, back, times).items()},
    }


def measure(name: str, path: Path | None, options: ReadOptions, work: Path) -> dict[str, Any]:
    """Every size and error for one input."""
    if path is None:
        scene = generate_scene(
            SceneSpec(
                sh_bands=3, background=8000, objects=8, per_object=1000, dynamic=("means",), seed=5
            )
        )
    else:
        scene = load_scene(path, options=options).scene
    if scene.timeline is None:
        raise SystemExit(f"{name}: not a 4D scene")
    first, last = time_range(scene.timeline)
    times = np.linspace(first, last, 9)
    files = encode_chunk(scene)
    chunk = bundle_bytes(files)
    decoded = decode_chunk(files)
    aligned = scene.subset(texel_order(scene))
    container = work / "x.tsogs"
    report = segment_scene(scene, container)
    row: dict[str, Any] = {
        "input": name,
        "gaussians": len(scene),
        "input_bytes": input_bytes(path),
        "ply_sequence_bytes": ply_sequence_bytes(scene, scene.timeline.fps or FPS),
        "extended_ply_bytes": extended_ply_size(scene),
        "tsog_bytes": len(chunk),
        "tsogs_bytes": report.bytes,
        **{f"tsog_{k}": v for k, v in error_summary(aligned, decoded, times).items()},
        **fourdgs_row(scene, times),
    }
    print(json.dumps({k: v for k, v in row.items() if k != "4dgs_notes"}), flush=True)
    return row


def pct(a: int, b: int) -> str:
    """a relative to b as a signed percentage."""
    return f"{100.0 * (a / b - 1):+.1f}%" if b else "—"


def markdown(rows: list[dict[str, Any]], stamp: str) -> str:
    """The inputs section of docs/benchmarks.md."""
    lines = [
        "## TSOG versus the 4D input formats and `.4dgs`",
        "",
        f"Run {stamp} (`benchmarks/bench_inputs.py`). Sizes in MB; percentages are TSOG chunk "
        "size relative to each baseline (the paper reported -96.88 % against PLY sequences and "
        "-91.85 % against the FreeTimeGS PLY). PLY sequence: one float PLY per frame of the "
        "scene at its frame rate (30 fps when it has none); extended PLY: one float PLY with "
        "timeline and coefficients as extra properties. Errors: worst position error (scene "
        "units) and mean alpha error over 9 times against the input.",
        "",
        "| input | N | input | PLY seq | ext. PLY | TSOG chunk | vs input | vs PLY seq | vs ext. PLY | .tsogs | .4dgs | TSOG pos max / alpha | .4dgs pos max / alpha |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        fdgs = f"{r['4dgs_bytes'] / 1e6:.2f}" if "4dgs_bytes" in r else "refused"
        ferr = f"{r['4dgs_pos_max']:.2e} / {r['4dgs_alpha_mean']:.4f}" if "4dgs_bytes" in r else "—"
        lines.append(
            f"| {r['input']} | {r['gaussians']:,} | {r['input_bytes'] / 1e6:.2f} | {r['ply_sequence_bytes'] / 1e6:.1f} | "
            f"{r['extended_ply_bytes'] / 1e6:.2f} | {r['tsog_bytes'] / 1e6:.2f} | {pct(r['tsog_bytes'], r['input_bytes'])} | "
            f"{pct(r['tsog_bytes'], r['ply_sequence_bytes'])} | {pct(r['tsog_bytes'], r['extended_ply_bytes'])} | "
            f"{r['tsogs_bytes'] / 1e6:.2f} | {fdgs} | {r['tsog_pos_max']:.2e} / {r['tsog_alpha_mean']:.4f} | {ferr} |"
        )
    notes = sorted({n for r in rows for n in r.get("4dgs_notes", [])})[:8]
    if notes:
        lines += ["", "What `.4dgs` could not hold (from `encode_4dgs` notes):", ""]
        lines += [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def main() -> int:
    """Measure every input and write the results."""
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="tsog-inputs-") as tmp:
        for name, path, options in inputs():
            rows.append(measure(name, path, options, Path(tmp)))
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "inputs.json").write_text(json.dumps({"date": stamp, "rows": rows}, indent=2))
    write_section("inputs", markdown(rows, stamp), "bench_inputs.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

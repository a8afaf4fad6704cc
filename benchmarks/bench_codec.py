"""Codec benchmark: encode/decode SH0 and SH3 scenes of 100k and 1M Gaussians, ours vs splat-transform.

Each encode/decode runs in its own process so wall time and peak memory (max RSS) are measured
alike for both tools. Errors are measured against the source in texel order. Decoding is also
timed against reading the same Gaussians from the float PLY (both files in the page cache,
alternated, medians), in a process of its own and inside this one. Results go to
benchmarks/results/codec.json and the "codec" section of docs/benchmarks.md.

    .venv/bin/python benchmarks/bench_codec.py                 # 100k and 1M, SH0 and SH3
    .venv/bin/python benchmarks/bench_codec.py --sizes 100000 --reference-timeout 3600
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from common import SPLAT_TRANSFORM as TOOL
from common import run_measured, write_section
from tsog_stream import Scene
from tsog_stream.codec.chunk import decode_chunk, decode_chunk_bytes, texel_order
from tsog_stream.compare import attribute_errors
from tsog_stream.io.chunks import read_chunk_files
from tsog_stream.io.ply import read_ply, write_ply
from tsog_stream.synthetic import static_gaussians

REPO = Path(__file__).resolve().parents[1]
TSOG = REPO / ".venv" / "bin" / "tsog"
RESULTS = REPO / "benchmarks" / "results" / "codec.json"
DECODE_REPEATS = 9


def errors_of(chunk: Path, source: Scene) -> dict[str, float]:
    """Per-attribute errors of a decoded chunk against the source in texel order."""
    decoded = decode_chunk(read_chunk_files(chunk), where=str(chunk)).gaussians
    aligned = source.subset(texel_order(source)).gaussians
    e = attribute_errors(aligned, decoded).as_dict()
    keys = ("means_max", "rotation_deg_mean", "scales_mean", "sh0_mean", "opacity_mean", "shN_rms")
    return {k: round(e[k], 6) for k in keys}


def decode_against_ply(ply: Path, chunk: Path) -> dict[str, float]:
    """Median seconds to decode the chunk and to read the PLY, files read each time, in turn."""
    read_ply(ply), decode_chunk_bytes(chunk.read_bytes())  # both files in the page cache
    ply_s, decode_s = [], []
    for _ in range(DECODE_REPEATS):
        start = time.perf_counter()
        read_ply(ply)
        ply_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        decode_chunk_bytes(chunk.read_bytes())
        decode_s.append(time.perf_counter() - start)
    return {
        "ply_read_s": round(statistics.median(ply_s), 4),
        "decode_s": round(statistics.median(decode_s), 4),
    }


def decode_in_fresh_process(ply: Path, chunk: Path) -> dict[str, float]:
    """:func:`decode_against_ply` in a process of its own (``--time-decode``): nothing before it
    has warmed the heap, as for a command or a player's first chunks. Inside this process,
    after the rows before, the PLY read's arrays are often pages the heap already holds: at
    1M SH0 the read took 61-63 ms there against 94-104 ms in fresh processes, the decode
    82 against 77-97 ms (2026-11-28)."""
    argv = [sys.executable, __file__, "--time-decode", str(ply), str(chunk)]
    done = subprocess.run(argv, check=True, capture_output=True, text=True, timeout=900)
    figures: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return figures


def bench_case(n: int, bands: int, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """One input size and SH degree through both tools."""
    source = Scene(static_gaussians(n, sh_bands=bands, seed=7))
    ply = work / f"in_{n}_{bands}.ply"
    write_ply(ply, source.gaussians)
    row: dict[str, Any] = {"gaussians": n, "sh_bands": bands, "ply_bytes": ply.stat().st_size}
    ours = work / "ours.sog"
    encode = [str(TSOG), "encode", str(ply), str(ours), "-f", "-q", "--quality", "100"]
    row["ours_encode"] = run_measured(encode, 3600)  # full precision, as splat-transform
    row["ours_decode"] = run_measured(
        [str(TSOG), "decode", str(ours), str(work / "o.ply"), "-q"], 3600
    )
    row["ours_bytes"] = ours.stat().st_size
    row["in_process"] = decode_against_ply(ply, ours)
    row["fresh_process"] = decode_in_fresh_process(ply, ours)
    row["ours_errors"] = errors_of(ours, source)
    default = work / "ours_default.sog"  # what `tsog encode` writes without --quality
    subprocess.run([str(TSOG), "encode", str(ply), str(default), "-f", "-q"], check=True)
    row["default_bytes"] = default.stat().st_size
    row["fresh_default"] = decode_in_fresh_process(ply, default)
    if not args.skip_reference:
        theirs = work / "theirs.sog"
        iters = (
            ["-i", str(args.reference_iterations)]
            if bands and n >= args.reference_fast_above
            else []
        )
        cmd = [str(TOOL), "-w", "-g", "cpu", *iters, str(ply), str(theirs)]
        row["reference_options"] = " ".join(["-w", "-g", "cpu", *iters])
        row["reference_encode"] = run_measured(cmd, args.reference_timeout)
        if row["reference_encode"]["finished"]:
            back = [str(TOOL), "-w", str(theirs), str(work / "t.ply")]
            row["reference_decode"] = run_measured(back, 3600)
            row["reference_bytes"] = theirs.stat().st_size
            row["reference_errors"] = errors_of(theirs, source)
    print(json.dumps(row), flush=True)
    return row


def _cell(row: dict[str, Any], key: str, field: str) -> str:
    """A table cell: a measured figure, or why there is none."""
    m = row.get(key)
    if m is None:
        return "—"
    if not m.get("finished"):
        return f"> {m['seconds']:.0f} s (stopped)"
    return f"{m[field]}"


def _megabytes(n: int | None) -> str:
    """Bytes as MB, or a dash when there is no figure."""
    return "—" if n is None else f"{n / 1e6:.2f}"


def markdown(rows: list[dict[str, Any]], stamp: str) -> str:
    """The codec section of docs/benchmarks.md."""
    lines = [
        "## SOG codec: ours vs splat-transform",
        "",
        f"Run {stamp} on this project's 2-core machine; synthetic static scenes "
        "(`tsog_stream.synthetic.static_gaussians`, seed 7). Wall time and peak RSS of a whole "
        "CLI process each; ours with `--quality 100` (full precision, as splat-transform; the "
        "CLI's default 90 moves faint Gaussians' positions further, spec §5.1). splat-transform "
        "3.7.0 on the CPU (`-g cpu`); options per row: at "
        "100k and 1M with SH its palette k-means runs one iteration (`-i 1`) instead of its "
        "default 10, which would take over 40 minutes at 100k (see design/quantizers.md for "
        "our palette against a faithful 10-iteration re-implementation).",
        "",
        "| N | SH | PLY MB | ours enc s | ref enc s | ratio | ours dec s | ref dec s | ours peak MiB |"
        " ref peak MiB | ours MB | ref MB | ref options |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        oe, re_ = r["ours_encode"], r.get("reference_encode", {})
        ratio = (
            f"{re_['seconds'] / oe['seconds']:.1f}x"
            if re_.get("finished") and oe.get("finished")
            else "—"
        )
        lines.append(
            f"| {r['gaussians']:,} | {r['sh_bands']} | {r['ply_bytes'] / 1e6:.1f} | {_cell(r, 'ours_encode', 'seconds')}"
            f" | {_cell(r, 'reference_encode', 'seconds')} | {ratio} | {_cell(r, 'ours_decode', 'seconds')}"
            f" | {_cell(r, 'reference_decode', 'seconds')} | {_cell(r, 'ours_encode', 'peak_mib')}"
            f" | {_cell(r, 'reference_encode', 'peak_mib')} | {r['ours_bytes'] / 1e6:.2f}"
            f" | {_megabytes(r.get('reference_bytes'))} | `{r.get('reference_options', '')}` |"
        )
    lines += [
        "",
        "Decoding against reading the same Gaussians from the float PLY (`read_ply`), both files "
        f"in the page cache, in turn, median of {DECODE_REPEATS}: in a process of its own (nothing "
        "before it, as a command or a player's first chunks), and inside this benchmark's "
        "process after the rows before it, whose heap often holds the PLY read's pages already "
        "(docs/design/chunk-codec.md, 'Decoding as fast as reading a PLY'); and the chunk "
        "`tsog encode` writes at its default quality (90: its SH palette merged within the "
        "bands' slack, docs/spec.md §5.1), in a process of its own:",
        "",
        "| N | SH | own process: PLY read s | decode s | decode / PLY read "
        "| after the rows before: PLY read s | decode s | decode / PLY read "
        "| default quality, own process: MB | PLY read s | decode s | decode / PLY read |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        cells = [
            f"{p['ply_read_s']:.3f} | {p['decode_s']:.3f} | {p['decode_s'] / p['ply_read_s']:.2f}x"
            if (p := r.get(key))
            else "— | — | —"
            for key in ("fresh_process", "in_process", "fresh_default")
        ]
        size = _megabytes(r.get("default_bytes"))
        lines.append(
            f"| {r['gaussians']:,} | {r['sh_bands']} | {cells[0]} | {cells[1]} | {size} | {cells[2]} |"
        )
    lines += [
        "",
        "Errors against the source (positions: max, scene units; rotation: mean degrees; scales, "
        "sh0: mean |Δ| in ln σ and f_dc; opacity: mean |Δ alpha|; shN: RMS of f_rest):",
        "",
        "| N | SH | tool | pos max | rot mean ° | scale mean | sh0 mean | alpha mean | shN RMS |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        for tool, key in (("ours", "ours_errors"), ("splat-transform", "reference_errors")):
            e = r.get(key)
            if e:
                lines.append(
                    f"| {r['gaussians']:,} | {r['sh_bands']} | {tool} | {e['means_max']:.2e}"
                    f" | {e['rotation_deg_mean']:.3f} | {e['scales_mean']:.4f} | {e['sh0_mean']:.4f}"
                    f" | {e['opacity_mean']:.4f} | {e['shN_rms']:.4f} |"
                )
    return "\n".join(lines) + "\n"


def main() -> int:
    """Run the benchmark grid and write the results."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--bands", type=int, nargs="+", default=[0, 3])
    parser.add_argument("--skip-reference", action="store_true", help="only run tsog-stream")
    parser.add_argument(
        "--reference-timeout", type=float, default=1800, help="seconds per reference encode"
    )
    parser.add_argument("--reference-iterations", type=int, default=1, help="-i for big SH cases")
    parser.add_argument(
        "--reference-fast-above", type=int, default=100_000, help="use -i from this N"
    )
    parser.add_argument(
        "--time-decode",
        nargs=2,
        metavar=("PLY", "CHUNK"),
        help="only time decoding CHUNK against reading PLY here (one JSON line; see "
        "decode_in_fresh_process)",
    )
    args = parser.parse_args()
    if args.time_decode:
        ply, chunk = (Path(a) for a in args.time_decode)
        print(json.dumps(decode_against_ply(ply, chunk)), flush=True)
        return 0
    rows = []
    with tempfile.TemporaryDirectory(prefix="tsog-bench-") as tmp:
        for n in args.sizes:
            for bands in args.bands:
                rows.append(bench_case(n, bands, Path(tmp), args))
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"date": stamp, "rows": rows}, indent=2))
    write_section("codec", markdown(rows, stamp), "bench_codec.py")
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())

"""Encode time at every quality against the encoder of the day issue 17 was filed.

Issue 17's target: encode time at any quality <= 1.1x "today's" (the encoder of 2026-11-24).
bench_rate reports each quality against quality 100 of the same run, which every speed-up of
the shared path makes look worse; this runs the encoder of that day itself (``REFERENCE``,
checked out into a temporary git worktree) in turns with today's, on the same files: each
input is read by each version's own reader and encoded in a child process (medians of
``ENCODES`` encodes; ``ROUNDS`` rounds, old and new in turn, as this machine drifts). Inputs:
the real `.splatv` captures, the two real SH3 captures (their palette fitted, and below
quality 100 merged within its slack), and FreeTimeGS-style clips from the donut (short,
medium, long lifespans) written as chunks and read back (few distinct scales and colours: the codebooks
are stored exactly, so the budgets' own cost shows plainly). Figures go to the
"encode-then" section of docs/benchmarks.md and benchmarks/results/encode_then.json.

    TSOG_SAMPLE_DATA=../shared/data .venv/bin/python benchmarks/bench_encode_then.py
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from common import REPO, alti_gaussians, sample, write_section
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import load_scene
from tsog_stream.synthetic import freetime_scene

REFERENCE = "6db039e"
"""The repository's head on 2026-11-24, the day issue 17 was filed (its encoder has one
precision: what quality 100 keeps)."""
QUALITIES = (100, 90, 75, 50, 25, 0)
ENCODES = 7
ROUNDS = 3
SPLATV = ("coffee10", "coffeeshort2", "spinach_4", "yellow_clip2")
LIFESPANS = {"short": (0.005, 0.02), "medium": (0.05, 0.2), "long": (0.5, 1.0)}
RESULTS = REPO / "benchmarks" / "results" / "encode_then.json"

TIMER = """
import statistics, sys, time
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import load_scene
scene = load_scene(sys.argv[1]).scene
qualities = [int(q) for q in sys.argv[3].split(",")] if len(sys.argv) > 3 else [None]
def encode(q):
    if q is None:
        return bundle_bytes(encode_chunk(scene))
    from tsog_stream.codec.precision import without_faint  # today's, as `tsog encode` does
    return bundle_bytes(encode_chunk(without_faint(scene, q), quality=q))
for q in qualities:
    encode(q)
for q in qualities:
    taken = []
    for _ in range(int(sys.argv[2])):
        start = time.perf_counter()
        encode(q)
        taken.append(time.perf_counter() - start)
    print(q if q is not None else "then", statistics.median(taken))
"""
"""Run in a child with one version on its path: the median seconds of each quality."""


@contextlib.contextmanager
def reference_tree(work: Path) -> Iterator[Path]:
    """The REFERENCE revision checked out in a worktree under ``work`` (removed after)."""
    tree = work / "then"
    made = subprocess.run(
        ["git", "-C", str(REPO), "worktree", "add", "--detach", str(tree), REFERENCE],
        capture_output=True,
        text=True,
        check=False,
    )
    if made.returncode != 0:
        raise SystemExit(f"cannot check out {REFERENCE} (a full clone is needed): {made.stderr}")
    try:
        yield tree / "src"
    finally:
        subprocess.run(
            ["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)],
            capture_output=True,
            check=False,  # a worktree already gone is fine
        )


def timed(source: Path | None, path: Path, qualities: tuple[int, ...] | None) -> dict[str, float]:
    """Median encode seconds per quality of ``path`` in a child process, with the package
    from ``source`` (the reference's src) or today's (None)."""
    env = dict(os.environ)
    if source is not None:
        env["PYTHONPATH"] = str(source)
    argv = [sys.executable, "-c", TIMER, str(path), str(ENCODES)]
    argv += [",".join(map(str, qualities))] if qualities else []
    done = subprocess.run(argv, env=env, capture_output=True, text=True, check=True)
    return {
        key: float(value)
        for key, value in (line.split() for line in done.stdout.split("\n") if line)
    }


def inputs(work: Path) -> dict[str, Path]:
    """The files both versions encode: the captures, and the donut clips as chunks."""
    chosen = {
        f"{name}.splatv": sample(f"4d/splatv/macaburguera_{name}.splatv", in_tree=False)
        for name in SPLATV
    }
    alti = work / "alti.ply"
    write_ply(alti, alti_gaussians())
    chosen["alti (real, SH3), as a PLY"] = alti
    chosen["fruit drops (real, SH3)"] = sample(
        "3dgs/supersplat_pr291_fruit_drops_minimal.ply", in_tree=False
    )
    donut = load_scene(sample("3dgs/v3dg_donut_fused.ply")).scene.gaussians
    for label, life in LIFESPANS.items():
        path = work / f"donut-{label}.sog"
        clip = freetime_scene(donut, duration_s=10.0, lifespan=life, seed=7)
        path.write_bytes(bundle_bytes(encode_chunk(clip)))
        chosen[f"donut FreeTimeGS {label}, read back from its chunk"] = path
    return chosen


def measure(source: Path, files: dict[str, Path]) -> dict[str, dict[str, list[float]]]:
    """Per input, each round's medians: the reference's ("then") and today's per quality."""
    out: dict[str, dict[str, list[float]]] = {}
    for name, path in files.items():
        rounds: dict[str, list[float]] = {}
        for _ in range(ROUNDS):
            for key, seconds in (timed(source, path, None) | timed(None, path, QUALITIES)).items():
                rounds.setdefault(key, []).append(seconds)
        out[name] = rounds
        worst = max(statistics.median(rounds[str(q)]) for q in QUALITIES)
        print(
            f"{name}: then {statistics.median(rounds['then']):.3f} s, today's slowest {worst:.3f} s",
            flush=True,
        )
    return out


def section(results: dict[str, dict[str, list[float]]]) -> str:
    """The docs/benchmarks.md section."""
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    head = "| input | then s | " + " | ".join(f"q{q} s (x then)" for q in QUALITIES) + " |"
    rows = [head, "|---|---:|" + "---:|" * len(QUALITIES)]
    worst = 0.0
    for name, rounds in results.items():
        then = statistics.median(rounds["then"])
        cells = []
        for q in QUALITIES:
            now = statistics.median(rounds[str(q)])
            worst = max(worst, now / then)
            cells.append(f"{now:.3f} ({now / then:.2f})")
        rows.append(f"| {name} | {then:.3f} | " + " | ".join(cells) + " |")
    return (
        "## Encode time against the encoder of the day issue 17 was filed\n\n"
        f"Run {when} (`benchmarks/bench_encode_then.py`), 2 cores: `encode_chunk` of {REFERENCE} "
        "(2026-11-24; one precision, what quality 100 keeps) from a git worktree, in turns with "
        "today's at every quality (the faint Gaussians left out first, as `tsog encode` does), "
        "each in a child process reading the file with its own "
        f"reader; medians of {ENCODES} encodes, the median of {ROUNDS} rounds. Target (issue "
        "17): <= 1.1x at any quality.\n\n" + "\n".join(rows) + "\n\n"
        f"Slowest quality against then, over every input: {worst:.2f}x.\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, reference_tree(Path(tmp)) as source:
        results = measure(source, inputs(Path(tmp)))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))
    write_section("encode-then", section(results), "bench_encode_then.py")


if __name__ == "__main__":
    main()

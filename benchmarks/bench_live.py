"""Live streams (issue 57): frames written in real time, `tsog live`, `tsog serve` and
`tsog play --live` on loopback, as a user runs them.

    .venv/bin/python benchmarks/bench_live.py            # 60 s a run (--seconds 600: the issue's)

Each source's frames (PLY; SOG flipbooks decoded to PLY first) are written into a folder at the
frame rate, cyclically for the run's length, each under a hidden name and renamed in. `tsog
live` publishes into a served folder; `tsog play --live --json` follows from the first
publication, a second one joins half way through. Per run: whether the encoder kept up (each
window's publication after its last frame arrived, first and last quarter of the run), the
players' latency p50/p95 from a frame's arrival to its showing, stalls, the late joiner's
distance from the edge and first picture, CPU of `tsog live`, and the stream's bytes against
`tsog segment` of the same frames (--window 1s --layers 1, and its own choice). Writes the
"live" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
import psutil

from common import sample, write_section
from tsog_stream import open_stream
from tsog_stream.io.ply import ply_bytes
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Gaussians
from tsog_stream.synthetic import static_gaussians

TSOG = [sys.executable, "-m", "tsog_stream.cli.main"]
SOURCES = {
    "fireworks (4k, PLY)": "4d/tztechno_fireworks_frames",
    "wave (4.2k, SOG)": "4d/pc_flipbook_wave",
    "monkey (31.7k, SOG)": "4d/pc_flipbook_monkey",
    "generated (30k, SH1)": "",
}
ENDING_S = 300.0
"""How long after its last frame a live run may take to end before the benchmark stops it."""
DISTINCT_FRAMES = 24
"""Frames of a source written (cyclically) at most: enough to vary, few to decode."""


def source_frames(rel: str) -> list[bytes]:
    """A source's frames as PLY files' bytes."""
    if not rel:
        base = static_gaussians(30_000, sh_bands=1, seed=7)
        frames = []
        for k in range(DISTINCT_FRAMES):
            moved = base.means + np.float32(0.01 * k)
            frames.append(
                Gaussians.from_arrays(
                    moved, base.scales, base.quats, base.opacities, base.sh0, shN=base.shN
                )
            )
        return [ply_bytes(g) for g in frames]
    seq = open_sequence(sample(rel))
    count = min(seq.count, DISTINCT_FRAMES)
    return [ply_bytes(seq.read(k, k + 1).scene.gaussians) for k in range(count)]


@dataclass
class LiveRun:
    """One run's figures."""

    name: str
    fps: float
    frames: int
    lag_first_s: float
    lag_last_s: float
    lag_max_s: float
    kept_up: bool
    play: dict[str, object]
    joiner: dict[str, object]
    cpu_percent: float
    live_bytes: int
    segment_bytes: int
    segment_auto_bytes: int


def write_frames(folder: Path, frames: list[bytes], fps: float, seconds: float) -> int:
    """Write ``frames`` cyclically at ``fps`` for ``seconds`` (hidden name, then rename), then
    the end marker; returns how many were written."""
    began = time.monotonic()
    count = int(seconds * fps)
    for k in range(count):
        time.sleep(max(0.0, began + k / fps - time.monotonic()))
        hidden = folder / f".frame_{k:06d}.part"
        hidden.write_bytes(frames[k % len(frames)])
        os.replace(hidden, folder / f"frame_{k:06d}.ply")
    (folder / "END").write_bytes(b"")
    return count


def free_port() -> int:
    import socket  # noqa: PLC0415

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def follow(url: str, duration: float | None = None) -> subprocess.Popen[str]:
    """``tsog play URL --live --json`` in a process of its own."""
    argv = [*TSOG, "play", url, "--live", "--json", "-q", "--timeout", "60"]
    argv += ["--duration", str(duration)] if duration else []
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_file(path: Path, limit_s: float) -> None:
    deadline = time.monotonic() + limit_s
    while not path.exists():
        if time.monotonic() > deadline:
            raise SystemExit(f"{path} did not appear in {limit_s} s")
        time.sleep(0.05)


def cpu_of(proc: psutil.Process) -> float:
    """CPU seconds of a process, its children that ended (replaced workers) and those alive."""
    t = proc.cpu_times()
    total = float(t.user + t.system + t.children_user + t.children_system)
    for child in proc.children(recursive=True):
        try:
            c = child.cpu_times()
            total += float(c.user + c.system)
        except psutil.NoSuchProcess:
            pass
    return total


def lags(manifest_path: Path, fps: float) -> list[float]:
    """Each window's publication after its last frame arrived (seconds)."""
    m = json.loads(manifest_path.read_bytes())
    per_window = round(m["window_s"] * fps)
    return [
        w["published_s"] - (w["arrived_s"] + (per_window - 1) / fps) for w in m["live"]["windows"]
    ]


def run(name: str, frames: list[bytes], fps: float, seconds: float, root: Path) -> LiveRun:
    """One live event of ``seconds`` at ``fps`` (the bytes compared on its first seconds)."""
    src, media = root / "src", root / "media"
    shutil.rmtree(root, ignore_errors=True)
    src.mkdir(parents=True)
    media.mkdir()
    port = free_port()
    server = subprocess.Popen(
        [*TSOG, "serve", str(media), "--port", str(port), "--workers", "1", "-q"]
    )
    live = subprocess.Popen(
        [
            *TSOG,
            "live",
            str(src),
            "-o",
            str(media / "event"),
            "--fps",
            str(fps),
            "--idle",
            "5",
            "-q",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    watched = psutil.Process(live.pid)
    writer = threading.Thread(target=write_frames, args=(src, frames, fps, seconds))
    began = time.monotonic()
    writer.start()
    cpu_samples: list[float] = []
    try:
        wait_file(media / "event" / "manifest.json", 60)
        url = f"http://127.0.0.1:{port}/files/event/"
        player = follow(url)
        time.sleep(max(0.0, seconds / 2 - (time.monotonic() - began)))
        joiner = follow(url, duration=min(10.0, seconds / 4))
        while live.poll() is None:
            if time.monotonic() - began > seconds + ENDING_S:
                live.kill()
                raise SystemExit(f"tsog live did not end within {ENDING_S} s of its last frame")
            cpu_samples.append(cpu_of(watched))
            time.sleep(0.5)
        writer.join()
        _, err = live.communicate()
        if live.returncode != 0:
            raise SystemExit(f"tsog live failed: {err[-2000:]}")
        play = json.loads(player.communicate(timeout=120)[0])
        joined = json.loads(joiner.communicate(timeout=120)[0])
    finally:
        server.terminate()
        server.wait(30)
    elapsed = time.monotonic() - began
    waited = lags(media / "event" / "manifest.json", fps)
    quarter = max(1, len(waited) // 4)
    first, last = float(np.median(waited[:quarter])), float(np.median(waited[-quarter:]))
    live_bytes, segment_bytes, auto_bytes = compare_bytes(src, media / "event", fps, root)
    return LiveRun(
        name,
        fps,
        int(seconds * fps),
        first,
        last,
        max(waited),
        last <= first + 0.5 and max(waited) < 2.0,
        play,
        joined,
        100 * (cpu_samples[-1] if cpu_samples else 0.0) / elapsed,
        live_bytes,
        segment_bytes,
        auto_bytes,
    )


COMPARE_S = 10
"""Seconds of frames (whole windows from the start) whose bytes are set against tsog segment's:
enough for every layout choice, bounded so a long run of large frames stays quick to compare."""


def compare_bytes(src: Path, event: Path, fps: float, root: Path) -> tuple[int, int, int]:
    """The live stream's chunk bytes for its first COMPARE_S seconds, and `tsog segment`'s for
    the same frames: one-second windows and one layer, and its own choices."""
    m = json.loads((event / "manifest.json").read_bytes())
    windows = [n for n in m["nodes"] if n["level"] == 0][: max(1, round(COMPARE_S / m["window_s"]))]
    live_bytes = sum(m["chunks"][c]["length"] for n in windows for c in n["chunks"])
    count = min(len(list(src.glob("frame_*.ply"))), round(len(windows) * m["window_s"] * fps))
    frames = root / "compared"
    frames.mkdir()
    for k in range(count):
        os.link(src / f"frame_{k:06d}.ply", frames / f"frame_{k:06d}.ply")
    sizes = []
    for name, extra in (
        ("one.tsogs", ["--window", "1s", "--layers", "1", "--temporal", "off"]),
        ("auto.tsogs", []),
    ):
        argv = [
            *TSOG,
            "segment",
            str(frames),
            "-o",
            str(root / name),
            "--fps",
            str(fps),
            "-q",
            *extra,
        ]
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
        with open_stream(root / name) as s:
            sizes.append(s.index.manifest.payload_bytes)
    return live_bytes, sizes[0], sizes[1]


def table(runs: list[LiveRun], seconds: float) -> list[str]:
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "## Live streams (issue 57)",
        "",
        f"Run {when} (`benchmarks/bench_live.py --seconds {seconds:g}`), 2 cores shared by the "
        "frame writer, `tsog live` (2 workers, 1 s windows, quality 90), `tsog serve` and two "
        "`tsog play --live` followers. *Publish lag*: a window's publication after its last frame "
        "arrived (median of the first and last quarter of the run, and the most); it kept up "
        "when the last quarter's is within 0.5 s of the first's and none reached 2 s. Latency: "
        "from a frame's arrival in the source to its showing (`tsog play --live`, p50/p95; the "
        "target is the window + 1.5 s = 2.5 s). Bytes: the live stream's first "
        f"{COMPARE_S} s against `tsog segment` of the same frames with one-second windows and one "
        "layer, and with its own choices.",
        "",
        "| source | fps | frames | publish lag first / last / most | kept up | latency p50 / p95 | stalls | late joiner: behind edge, first picture | CPU of tsog live | bytes vs segment 1 s / auto |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in runs:
        lines.append(
            f"| {r.name} | {r.fps:g} | {r.frames} | {r.lag_first_s:.2f} / {r.lag_last_s:.2f} / "
            f"{r.lag_max_s:.2f} s | {'yes' if r.kept_up else 'no'} | {r.play['latency_p50_s']} / "
            f"{r.play['latency_p95_s']} s | {r.play['stalls']} | {r.joiner['joined_behind_s']} s, "
            f"{r.joiner['first_picture_s']} s | {r.cpu_percent:.0f} % | "
            f"{r.live_bytes / r.segment_bytes:.2f}x / {r.live_bytes / r.segment_auto_bytes:.2f}x |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each event")
    parser.add_argument("--fps", type=float, nargs="+", default=[10.0, 30.0])
    parser.add_argument("--only", help="run only the sources whose name contains this")
    parser.add_argument("--no-write", action="store_true", help="print, do not write the doc")
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-live-") as scratch:
        for name, rel in SOURCES.items():
            if args.only and args.only not in name:
                continue
            frames = source_frames(rel)
            for fps in args.fps:
                r = run(name, frames, fps, args.seconds, Path(scratch) / "run")
                print(r, flush=True)
                runs.append(r)
    lines = table(runs, args.seconds)
    print("\n".join(lines))
    if not args.no_write:
        write_section("live", "\n".join(lines), "bench_live.py")


if __name__ == "__main__":
    main()

"""Segmenting on one machine's engines: the local process pool against a Dask LocalCluster.

    .venv/bin/python benchmarks/bench_cluster.py [--gaussians 1000000] [--frames 24]
        [--checkpoint 5000000] [--checkpoint-only]
    .venv/bin/python benchmarks/bench_cluster.py --layers-phase 2000000

Two inputs, each segmented in one run by every engine with 1 and 2 workers, each run in a
fresh process: wall time,
Gaussians per second, CPU use (the parent's, its children's and the Dask workers'), peak RSS
of the parent and of each worker, and whether every container of an input is byte-identical.
- A generated FreeTimeGS-style SH3 clip (10 s, lifespans 60-100 % of it: the issue's kind of
  scene, at a size this machine segments in a minute): a scene in memory, so the client sends
  each job its Gaussians.
- A generated sequence of SH3 PLY frames on disk (a flipbook of a capture): each job is a
  window that its worker reads itself; the bytes sent to a worker per window (the pickled job)
  are set against the window's arrays, and the bytes that come back (the chunks).
- A generated 5M-Gaussian SH3 FreeTimeGS checkpoint (`.npz`) through `tsog segment` as a user
  runs it (`--checkpoint N`, 0 skips it; `--checkpoint-only`): wall, CPU, first progress line,
  peak RSS of the CLI and its workers against the issue's targets.
- ``--layers-phase N`` alone: an N-Gaussian checkpoint with the default quality layers against
  ``--layers 1`` (the default path's layer measure, issue 56).
Writes the "checkpoint", "cluster" and "layers-phase" sections of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import hashlib
import json
import os
import pickle
import re
import resource
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
import psutil

from common import write_section
from tsog_stream import open_stream
from tsog_stream.codec.precision import DEFAULT_QUALITY
from tsog_stream.io.ply import write_ply
from tsog_stream.io.sequence import FrameSequence, open_sequence
from tsog_stream.model import Scene
from tsog_stream.segment import (
    SegmentOptions,
    SegmentReport,
    WindowJob,
    max_gaussians_per_chunk,
    segment_scene,
    segment_sequence,
)
from tsog_stream.segment.engines import local_cluster
from tsog_stream.segment.layers import LayerPlan
from tsog_stream.segment.plan import Plan
from tsog_stream.synthetic import freetime_scene, static_gaussians

MiB = 1 << 20


@dataclass
class Run:
    """One segmentation: which engine, what it cost."""

    engine: str
    workers: int
    wall_s: float
    cpu_percent: float
    digest: str
    container_bytes: int
    worker_peak_mib: float
    """The largest worker's RSS, sampled every 0.2 s (0: encoded in the parent)."""
    parent_peak_mib: float = 0.0
    """The peak RSS of the process that segmented (a fresh one for each run), while it
    segmented: making its input before is not counted."""
    parent_before_mib: float = 0.0
    """That process's RSS just before it segmented, its input made (a scene: held)."""


def scene_of(n: int) -> Scene:
    """The benchmark clip: ``n`` SH3 Gaussians, 10 s, long lifespans."""
    g = static_gaussians(n, sh_bands=3, seed=1)
    return freetime_scene(g, duration_s=10.0, lifespan=(0.6, 1.0), seed=2)


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class ChildPeak:
    """The largest RSS any child process (pool worker, Dask worker or nanny) reached, sampled
    every ``every_s`` seconds in a thread. Not ``getrusage``: Linux carries a process's peak
    across exec, so a spawned worker reports the parent's size at the fork."""

    def __init__(self, every_s: float = 0.2) -> None:
        self.peak = 0
        self.every_s = every_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        me = psutil.Process()
        while not self._stop.is_set():
            for child in me.children(recursive=True):
                with contextlib.suppress(psutil.Error):
                    self.peak = max(self.peak, child.memory_info().rss)
            self._stop.wait(self.every_s)

    def __enter__(self) -> ChildPeak:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def frames_of(folder: Path, count: int, per_frame: int) -> FrameSequence:
    """``count`` SH3 PLY frames of ``per_frame`` Gaussians each (a new draw per frame)."""
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(count):
        write_ply(folder / f"frame_{k:04d}.ply", static_gaussians(per_frame, sh_bands=3, seed=k))
    return open_sequence(folder)


def _segment(source: Scene | FrameSequence, path: Path, options: SegmentOptions) -> SegmentReport:
    if isinstance(source, FrameSequence):
        return segment_sequence(source, path, options)
    return segment_scene(source, path, options)


def measure(source: Scene | FrameSequence, engine: str, workers: int, path: Path) -> Run:
    """Segment ``source`` once on ``engine`` (local pool or a fresh Dask LocalCluster)."""
    base = SegmentOptions(workers=workers, layers=1, quality=DEFAULT_QUALITY)
    if isinstance(source, FrameSequence):
        base = replace(base, window_s=1 / source.fps)
    options = base
    with contextlib.ExitStack() as stack:
        cluster = None
        if engine == "dask":
            cluster = stack.enter_context(local_cluster(workers))
            options = replace(base, cluster=cluster.scheduler_address)
        cpu, began = _cpu_s(), time.monotonic()
        with ChildPeak() as children:
            report = _segment(source, path, options)
        wall = time.monotonic() - began
        cpu_used = _cpu_s() - cpu
        peak = children.peak / MiB
        if cluster is not None:
            from distributed import Client  # noqa: PLC0415

            with Client(cluster) as client:  # type: ignore[no-untyped-call]
                cpu_used += sum(client.run(lambda: sum(os.times()[:2])).values())
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    if workers == 1 and cluster is None:
        peak = 0.0  # encoded in the parent
    return Run(engine, workers, wall, 100 * cpu_used / wall, digest, report.bytes, peak)


def job_bytes(seq: FrameSequence, container_bytes: int) -> tuple[float, float, float]:
    """Mean bytes per window: sent to a worker (the pickled window job), the window's arrays,
    and what comes back (its chunks)."""
    plan = Plan(0.0, seq.count / seq.fps, 1 / seq.fps, seq.count, {}, 0)
    max_count = max_gaussians_per_chunk(SegmentOptions().max_pixels, 3)
    one = LayerPlan.single()
    sent = [
        len(
            pickle.dumps(
                WindowJob(seq.window(k, k + 1), k, max_count, one, plan, 0, DEFAULT_QUALITY)
            )
        )
        for k in range(seq.count)
    ]
    arrays = [seq.read(k, k + 1).scene.gaussians for k in range(min(seq.count, 3))]
    raw = sum(sum(a.nbytes for a in vars(g).values()) for g in arrays) / len(arrays)
    return sum(sent) / len(sent), raw, container_bytes / seq.count


def run_all(source: str, folder: Path, name: str) -> list[Run]:
    """Every engine with 1 and 2 workers on ``source`` (a frame folder, or ``scene:N`` for
    scene_of(N)), each run in a fresh process: run one after another in one process, the
    later runs paid for the earlier ones (the 1M scene on two workers took 33 s after the
    frame runs, 25 s in a process of its own)."""
    runs = []
    for engine in ("pool", "dask"):
        for workers in (1, 2):
            out = folder / f"{name}-{engine}{workers}.tsogs"
            run = measure_in_child(source, engine, workers, out)
            runs.append(run)
            print(name, engine, workers, f"{run.wall_s:.1f} s", f"{run.cpu_percent:.0f} %")
    return runs


def measure_in_child(source: str, engine: str, workers: int, out: Path) -> Run:
    """:func:`measure` in a child process of its own (``--one``); its Run."""
    argv = [sys.executable, __file__, "--one", source, engine, str(workers), str(out)]
    done = subprocess.run(argv, check=True, capture_output=True, text=True, timeout=3600)
    return Run(**json.loads(done.stdout.strip().splitlines()[-1]))


def measure_here(source: str, engine: str, workers: int, out: Path) -> None:
    """One run in this process (the child of :func:`measure_in_child`): its Run as JSON."""
    what: Scene | FrameSequence
    if source.startswith("scene:"):
        what = scene_of(int(source.removeprefix("scene:")))
    else:
        what = open_sequence(source)
    before = _status_mib("VmRSS")
    _reset_peak()  # making a scene peaked higher than segmenting it (904 against 783 MiB)
    run = measure(what, engine, workers, out)
    run.parent_peak_mib = _peak_mib()
    run.parent_before_mib = before
    print(json.dumps(vars(run)), flush=True)


def table(runs: list[Run], gaussians: int, fixed: dict[str, float], job_mib: float) -> list[str]:
    """The runs as a Markdown table, with the scaling line under it. A worker's peak is also
    given above ``fixed`` (its engine's worker peak on a tiny input: imports, threads, the
    engine's own state) against ``job_mib``, the largest job's raw arrays."""
    rows = [
        "| engine | workers | wall | Gaussians/s | CPU | worker peak RSS | above a tiny input's |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in runs:
        peak = f"{r.worker_peak_mib:.0f} MiB" if r.worker_peak_mib else "(in the parent)"
        above = r.worker_peak_mib - fixed[r.engine]
        held = f"{above:.0f} MiB ({above / job_mib:.1f}x)" if r.worker_peak_mib else "–"
        rows.append(
            f"| {r.engine} | {r.workers} | {r.wall_s:.1f} s | "
            f"{gaussians / r.wall_s / 1e3:.0f}k | {r.cpu_percent:.0f} % | {peak} | {held} |"
        )
    by = {(r.engine, r.workers): r.wall_s for r in runs}
    work = {(r.engine, r.workers): r.wall_s * r.cpu_percent for r in runs}  # CPU-seconds x 100
    same = len({r.digest for r in runs}) == 1
    rows += [
        "",
        f"Scaling from 1 to 2 workers: pool {by['pool', 1] / by['pool', 2]:.2f}x, Dask "
        f"{by['dask', 1] / by['dask', 2]:.2f}x; the CPU time the same work took with 2 workers "
        f"against 1 (what the second worker costs beyond its core): pool "
        f"{work['pool', 2] / work['pool', 1]:.2f}x, Dask {work['dask', 2] / work['dask', 1]:.2f}x; "
        f"Dask against the pool at 2 workers: "
        f"{by['dask', 2] / by['pool', 2]:.2f}x the time. Containers byte-identical: "
        f"{'yes' if same else 'NO'}. Above a tiny input's: a worker's peak less its engine's "
        f"worker peak on {TINY_FRAMES} frames of {TINY_GAUSSIANS} Gaussians, against the "
        f"largest job's raw arrays ({job_mib:.1f} MiB; target: at most 2x).",
    ]
    return rows


TINY_FRAMES, TINY_GAUSSIANS = 2, 64
"""The tiny input whose worker peak is an engine's fixed cost."""


def fixed_costs(folder: Path) -> dict[str, float]:
    """Each engine's worker peak RSS (MiB) segmenting a tiny frame sequence on 2 workers:
    what a worker holds whatever the input (interpreter, numpy, Pillow, the engine)."""
    frames_of(folder / "tiny", TINY_FRAMES, TINY_GAUSSIANS)
    return {
        engine: measure_in_child(
            str(folder / "tiny"), engine, 2, folder / f"tiny-{engine}.tsogs"
        ).worker_peak_mib
        for engine in ("pool", "dask")
    }


def largest_job_mib(container: Path, raw_per_gaussian: float) -> float:
    """The raw arrays of the container's largest chunk (its job's Gaussians), in MiB."""
    with open_stream(container) as stream:
        most = max(c.count for c in stream.index.manifest.chunks)
    return most * raw_per_gaussian / MiB


def _peak_mib() -> float:
    """This process's peak RSS since it started or :func:`_reset_peak`: the kernel's
    high-water mark of its memory (VmHWM, which starts afresh at exec), not getrusage's, which
    a process started by exec inherits from its parent at the fork (the bench's own 3 GB after
    the 5M checkpoint made a 1M scene's run report 2.9 GB)."""
    found = _status_mib("VmHWM")
    return found if found else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _status_mib(field: str) -> float:
    """A memory figure of /proc/self/status in MiB (0 where there is none)."""
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        return 0.0
    prefix = f"{field}:"
    return next(
        (int(ln.split()[1]) / 1024 for ln in status.splitlines() if ln.startswith(prefix)), 0.0
    )


def _reset_peak() -> None:
    """Start this process's high-water mark afresh at its current RSS (Linux: clear_refs 5)."""
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")


def checkpoint_npz(path: Path, n: int) -> int:
    """A generated FreeTimeGS checkpoint of ``n`` SH3 Gaussians with long lifespans (the
    issue's 5M scene); returns the bytes of its raw arrays."""
    rng = np.random.default_rng(1)
    f32 = np.float32
    arrays = {
        "means": rng.normal(0, 3, (n, 3)).astype(f32),
        "scales": rng.normal(-4, 0.5, (n, 3)).astype(f32),
        "quats": rng.normal(0, 1, (n, 4)).astype(f32),
        "opacities": rng.normal(0, 2, (n,)).astype(f32),
        "sh0": rng.normal(0, 0.5, (n, 1, 3)).astype(f32),
        "shN": rng.normal(0, 0.1, (n, 15, 3)).astype(f32),
        "times": rng.uniform(0, 1, (n, 1)).astype(f32),
        "durations": np.log(rng.uniform(0.3, 0.5, (n, 1))).astype(f32),
        "velocities": rng.normal(0, 0.05, (n, 3)).astype(f32),
    }
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return sum(a.nbytes for a in arrays.values())


@dataclass
class Checkpoint:
    """``tsog segment`` of the checkpoint, as a user runs it with stderr to a log."""

    wall_s: float
    cpu_percent: float
    first_line_s: float
    parent_peak: int
    worker_peak: int
    tree_peak: int
    size: int
    log: str


def run_checkpoint(npz: Path, out: Path, layers: int | None = 1) -> Checkpoint:
    """Run the CLI on ``npz`` with 2 workers (``--layers``; None: the default), sampling the
    RSS of it and its workers."""
    tsog = Path(sys.executable).with_name("tsog")
    argv = [str(tsog), "segment", str(npz), "-o", str(out), "--scene-length-s", "10"]
    argv += ["--workers", "2", "--force"]
    argv += ["--layers", str(layers)] if layers is not None else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    began = time.monotonic()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    first: list[float] = []
    lines: list[str] = []

    def read_log() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            if not first:
                first.append(time.monotonic() - began)
            lines.append(line.rstrip())

    reader = threading.Thread(target=read_log, daemon=True)
    reader.start()
    parent, worker, tree = 0, 0, 0
    me = psutil.Process(proc.pid)
    while proc.poll() is None:
        with contextlib.suppress(psutil.Error):
            own = me.memory_info().rss
            kids = [c.memory_info().rss for c in me.children(recursive=True)]
            parent, worker = max(parent, own), max([worker, *kids])
            tree = max(tree, own + sum(kids))
        time.sleep(0.2)
    wall = time.monotonic() - began
    reader.join(timeout=5)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    if proc.returncode != 0:
        raise SystemExit(f"tsog segment failed ({proc.returncode}): {lines[-3:]}")
    log = "\n".join(line for line in lines if line.startswith("["))
    return Checkpoint(
        wall, 100 * cpu / wall, first[0], parent, worker, tree, out.stat().st_size, log
    )


PROGRESS_LINE = re.compile(r"\[\s*([0-9.]+)s\] chunk (\d+)/(\d+), ETA\s+([0-9?]+)s?")
"""A progress line of `tsog segment` in a log: elapsed, chunks written, in all, ETA."""


def eta_rows(log: str) -> list[str]:
    """Markdown rows: each ETA the log announced against the encoding time left in fact
    (until its last chunk's line), at most every 10 s of the run."""
    said = [m.groups() for m in map(PROGRESS_LINE.search, log.splitlines()) if m]
    ends = [float(t) for t, done, total, _ in said if done == total]
    if not ends:
        return []
    rows, shown = [], -10.0
    for t, done, total, eta in said:
        at = float(t)
        if eta == "?" or at - shown < 10.0 or done == total:
            continue
        shown = at
        rows.append(f"| {at:.1f} s | {done}/{total} | {eta} s | {ends[0] - at:.0f} s |")
    return ["| at | chunks | ETA said | left in fact |", "| --- | --- | --- | --- |", *rows]


def checkpoint_section(n: int, raw: int, run: Checkpoint) -> list[str]:
    """The checkpoint's figures against the issue's targets, and its progress log."""
    gib = float(1 << 30)
    return [
        f"**The {n / 1e6:g}M-Gaussian checkpoint** (a generated SH3 FreeTimeGS `.npz`, long "
        f"lifespans, raw arrays {raw / gib:.2f} GiB) through `tsog segment --workers 2 --layers "
        "1`, stderr to a pipe; RSS sampled every 0.2 s. Targets (issue 20): <= 130 s, >= 180 % "
        "CPU, peak RSS <= 2x the raw arrays, first progress line within 5 s.",
        "",
        "| wall | CPU | first line | parent peak RSS | largest worker | parent + workers | "
        "container |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| {run.wall_s:.1f} s | {run.cpu_percent:.0f} % | {run.first_line_s:.1f} s | "
        f"{run.parent_peak / gib:.2f} GiB ({run.parent_peak / raw:.2f}x) | "
        f"{run.worker_peak / gib:.2f} GiB | {run.tree_peak / gib:.2f} GiB | "
        f"{run.size / 1e6:.1f} MB |",
        "",
        "The ETA as it was announced (every 10 s at most) against the encoding time left:",
        "",
        *eta_rows(run.log),
        "",
        "```",
        run.log,
        "```",
        "",
    ]


LAYER_ROUNDS = 2
"""Turns of (default, ``--layers 1``) runs in the layer-measure benchmark."""


def layers_phase(n: int) -> list[str]:
    """Issue 56's target for the default path: ``tsog segment`` of an ``n``-Gaussian checkpoint
    with the default quality layers against ``--layers 1``, in turns; the section's lines."""
    gib = float(1 << 30)
    runs: dict[str, list[Checkpoint]] = {"default": [], "--layers 1": []}
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "checkpoint.npz"
        raw = checkpoint_npz(npz, n)
        for _ in range(LAYER_ROUNDS):
            runs["default"].append(run_checkpoint(npz, Path(tmp) / "default.tsogs", None))
            runs["--layers 1"].append(run_checkpoint(npz, Path(tmp) / "one.tsogs", 1))
    one = min(r.wall_s for r in runs["--layers 1"])
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "## The default path's layer measure (issue 56)",
        "",
        f"Run {when} (`benchmarks/bench_cluster.py --layers-phase {n}`), 2 cores: a generated "
        f"{n / 1e6:g}M-Gaussian SH3 FreeTimeGS `.npz` (raw arrays {raw / gib:.2f} GiB) through "
        "`tsog segment --workers 2`, with the default quality layers and with `--layers 1`, "
        f"{LAYER_ROUNDS} turns. Targets: default within 1.15x the time of `--layers 1`, CPU >= "
        "170 %, peak RSS <= 2.5x the raw arrays.",
        "",
        "| run | wall | x `--layers 1` (best) | CPU | parent peak | parent + workers | container |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, done in runs.items():
        for r in done:
            lines.append(
                f"| {name} | {r.wall_s:.1f} s | {r.wall_s / one:.2f}x | {r.cpu_percent:.0f} % | "
                f"{r.parent_peak / gib:.2f} GiB ({r.parent_peak / raw:.2f}x) | "
                f"{r.tree_peak / gib:.2f} GiB ({r.tree_peak / raw:.2f}x) | {r.size / 1e6:.1f} MB |"
            )
    return [*lines, "", "The default run's progress:", "", "```", runs["default"][-1].log, "```"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gaussians", type=int, default=1_000_000)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--per-frame", type=int, default=40_000)
    parser.add_argument(
        "--checkpoint",
        type=int,
        default=5_000_000,
        help="Gaussians of the checkpoint segmented through the CLI (0: skip it)",
    )
    parser.add_argument(
        "--checkpoint-only", action="store_true", help="only the checkpoint (its own section)"
    )
    parser.add_argument(
        "--layers-phase",
        type=int,
        default=0,
        metavar="N",
        help="only the default layers against --layers 1 on an N-Gaussian checkpoint",
    )
    parser.add_argument(
        "--one", nargs=4, metavar=("SOURCE", "ENGINE", "WORKERS", "OUT"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.one:
        source, engine, workers, out = args.one
        measure_here(source, engine, int(workers), Path(out))
        return
    if args.layers_phase > 0:
        write_section(
            "layers-phase", "\n".join(layers_phase(args.layers_phase)), "bench_cluster.py"
        )
        return
    if args.checkpoint > 0:
        with tempfile.TemporaryDirectory() as tmp:
            npz = Path(tmp) / "checkpoint.npz"
            raw = checkpoint_npz(npz, args.checkpoint)
            run = run_checkpoint(npz, Path(tmp) / "checkpoint.tsogs")
        when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        head = [
            "## A 5M-Gaussian checkpoint through the CLI (issue 20)",
            "",
            f"Run {when} (`benchmarks/bench_cluster.py --checkpoint {args.checkpoint}`), 2 cores.",
            "",
        ]
        body = head + checkpoint_section(args.checkpoint, raw, run)
        write_section("checkpoint", "\n".join(body), "bench_cluster.py")
        print(f"checkpoint {run.wall_s:.1f} s {run.cpu_percent:.0f} %")
    if args.checkpoint_only:
        return
    with tempfile.TemporaryDirectory() as tmp:
        seq = frames_of(Path(tmp) / "frames", args.frames, args.per_frame)
        fixed = fixed_costs(Path(tmp))
        seq_runs = run_all(str(Path(tmp) / "frames"), Path(tmp), "frames")
        sent, window_raw, back = job_bytes(seq, seq_runs[0].container_bytes)
        parent_seq = max(r.parent_peak_mib for r in seq_runs if r.workers == 2)
        scene = scene_of(args.gaussians)
        raw = sum(a.nbytes for a in vars(scene.gaussians).values())
        del scene
        scene_runs = run_all(f"scene:{args.gaussians}", Path(tmp), "scene")
        two = [r for r in scene_runs if r.workers == 2]
        parent_scene = max(r.parent_peak_mib for r in two)
        parent_held = max(r.parent_before_mib for r in two)
        scene_job = largest_job_mib(Path(tmp) / "scene-dask2.tsogs", raw / args.gaussians)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    body = [
        "## Segmenting on the local pool and on Dask (issue 20)",
        "",
        f"Run {when} (`benchmarks/bench_cluster.py --gaussians {args.gaussians} --frames "
        f"{args.frames} --per-frame {args.per_frame}`), 2 cores. Each input segmented by each "
        "engine in the same run, one layer, at `tsog segment`'s default quality "
        f"({DEFAULT_QUALITY}), each run in a fresh process: `--workers N` (local "
        "spawned processes; 1: in the parent) and `--cluster` on a fresh Dask LocalCluster of N "
        "single-threaded worker processes (its start not counted). CPU: the parent's, its "
        "children's and the Dask "
        "workers' over the wall time. Worker peak RSS: the largest of any worker process, "
        "sampled every 0.2 s. The LocalCluster is the one `--cluster local` starts "
        "(`engines.local_cluster`: no profiler, event-loop tick and monitors at 1-5 s), its "
        "workers with glibc's malloc thresholds set back and one malloc arena (`machine.tune_malloc`).",
        "",
        f"**A scene in memory**: a generated FreeTimeGS-style clip of {args.gaussians} SH3 Gaussians "
        f"(10 s, lifespans 60-100 %; raw arrays {raw / MiB:.0f} MiB). The client sends each job "
        "its Gaussians.",
        "",
        *table(scene_runs, args.gaussians, fixed, scene_job),
        f"The parent's peak RSS while segmenting with two workers: {parent_scene:.0f} MiB, "
        f"{parent_scene - parent_held:.0f} MiB ({(parent_scene - parent_held) * MiB / raw:.1f}x "
        f"the raw arrays) above the {parent_held:.0f} MiB it held with the scene made (the "
        "parts cut for the first jobs, each pickled as well while a pool sends it, then the "
        "finished chunks waiting for their turn; making the scene, not counted, peaked "
        "higher).",
        "",
        f"**A frame sequence on disk**: {args.frames} generated SH3 PLY frames of "
        f"{args.per_frame} Gaussians (a window per frame). With 2 workers each job is a window "
        "its worker reads itself: a job sent to a worker is "
        f"{sent / 1024:.1f} KiB (the frames' paths and shapes, the plan) instead of the window's "
        f"{window_raw / MiB:.1f} MiB of arrays ({window_raw / sent:.0f}x less); what comes back "
        f"is the window's chunks, {back / 1024:.0f} KiB a window. The parent's peak RSS with "
        f"two workers: {parent_seq:.0f} MiB (it reads only the few frames it samples for the "
        "layout, the opening view and the layers).",
        "",
        *table(seq_runs, seq.gaussians, fixed, window_raw / MiB),
        "",
    ]
    write_section("cluster", "\n".join(body), "bench_cluster.py")


if __name__ == "__main__":
    main()

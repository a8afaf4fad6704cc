"""Segmenting on one machine's engines: the local process pool against a Dask LocalCluster.

    .venv/bin/python benchmarks/bench_cluster.py [--gaussians 1000000]

A generated FreeTimeGS-style SH3 clip (10 s, lifespans 60-100 % of it: the issue's kind of
scene, at a size this machine segments in a minute), segmented in one run by every engine with
1 and 2 workers: wall time, Gaussians per second, CPU use (the parent's, its children's and the
Dask workers'), the parent's peak RSS, and whether every container is byte-identical. Writes
the "cluster" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import os
import resource
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from distributed import LocalCluster

from common import write_section
from tsog_stream.model import Scene
from tsog_stream.segment.segmenter import SegmentOptions, SegmentReport, segment_scene
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
    report: SegmentReport


def scene_of(n: int) -> Scene:
    """The benchmark clip: ``n`` SH3 Gaussians, 10 s, long lifespans."""
    g = static_gaussians(n, sh_bands=3, seed=1)
    return freetime_scene(g, duration_s=10.0, lifespan=(0.6, 1.0), seed=2)


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def measure(scene: Scene, engine: str, workers: int, path: Path) -> Run:
    """Segment ``scene`` once on ``engine`` (local pool or a fresh Dask LocalCluster)."""
    options = SegmentOptions(workers=workers, layers=1)
    cluster = None
    if engine == "dask":
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        )
        options = SegmentOptions(workers=workers, layers=1, cluster=cluster.scheduler_address)
    try:
        cpu, began = _cpu_s(), time.monotonic()
        report = segment_scene(scene, path, options)
        wall = time.monotonic() - began
        cpu_used = _cpu_s() - cpu
        if cluster is not None:
            from distributed import Client  # noqa: PLC0415

            with Client(cluster) as client:  # type: ignore[no-untyped-call]
                cpu_used += sum(client.run(lambda: sum(os.times()[:2])).values())
    finally:
        if cluster is not None:
            cluster.close()
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    return Run(engine, workers, wall, 100 * cpu_used / wall, digest, report)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gaussians", type=int, default=1_000_000)
    args = parser.parse_args()
    scene = scene_of(args.gaussians)
    raw = sum(a.nbytes for a in vars(scene.gaussians).values())
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for engine in ("pool", "dask"):
            for workers in (1, 2):
                run = measure(scene, engine, workers, Path(tmp) / f"{engine}{workers}.tsogs")
                runs.append(run)
                print(
                    engine, workers, f"{run.wall_s:.1f} s", f"{run.cpu_percent:.0f} %", flush=True
                )
    identical = len({r.digest for r in runs}) == 1
    body = [
        "## Segmenting on the local pool and on Dask (issue 20)",
        "",
        f"Run {dt.datetime.now(dt.UTC).strftime('%Y-%m-%d %H:%M UTC')} "
        f"(`benchmarks/bench_cluster.py --gaussians {args.gaussians}`), 2 cores. A generated "
        f"FreeTimeGS-style clip of {len(scene)} SH3 Gaussians (10 s, lifespans 60-100 %; raw "
        f"arrays {raw / MiB:.0f} MiB), one layer, segmented by each engine in the same run: "
        "`--workers N` (local spawned processes; 1: in the parent) and `--cluster` on a fresh "
        "Dask LocalCluster of N single-threaded worker processes (its start not counted). CPU: "
        "the parent's, its children's and the Dask workers' over the wall time. "
        f"Containers byte-identical: {'yes' if identical else 'NO'}.",
        "",
        "| engine | workers | wall | Gaussians/s | CPU |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in runs:
        body.append(
            f"| {r.engine} | {r.workers} | {r.wall_s:.1f} s | "
            f"{len(scene) / r.wall_s / 1e3:.0f}k | {r.cpu_percent:.0f} % |"
        )
    by = {(r.engine, r.workers): r.wall_s for r in runs}
    body += [
        "",
        f"Scaling from 1 to 2 workers: pool {by['pool', 1] / by['pool', 2]:.2f}x, Dask "
        f"{by['dask', 1] / by['dask', 2]:.2f}x; Dask against the pool at 2 workers: "
        f"{by['dask', 2] / by['pool', 2]:.2f}x the time. The client sends each job its "
        "Gaussians (workers reading their own input is the next step); the parent's peak RSS "
        f"over all runs: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB "
        "(the scene, the jobs in flight and the finished chunks waiting for their turn). Each "
        "worker's own peak is not measured yet (`getrusage` inside a Dask worker reported the "
        "parent's figure).",
        "",
    ]
    write_section("cluster", "\n".join(body), "bench_cluster.py")


if __name__ == "__main__":
    main()

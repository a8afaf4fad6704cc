"""Load test on loopback: many players at random t against `tsog serve` and nginx, same file.

    .venv/bin/python benchmarks/bench_load.py [--clients 200] [--seconds 30] [--no-write]

Each simulated player picks a random t and fetches, with one Range GET each over a keep-alive
connection, the chunks of the ``.tsogs`` file that ``StreamIndex.chunks_for_interval(t, t+1)``
chooses, then picks another t. Both origins (ours as a separate ``tsog serve`` process, nginx
with one worker) serve the same synthetic file, one after the other in the same run, under the
same load. The load tool is ``wrk`` (Debian package) with a Lua script holding the ranges; without
wrk a Python asyncio generator runs in its own process instead. Reports requests/s, p50/p99
latency, errors, server RSS (before, peak, after) and server CPU seconds; writes
benchmarks/results/load.json and the "load" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import aiohttp

from bench_http import free_port, start_nginx, wait_up
from common import WRK_DONE, children, run_wrk, segmented_clip, status_kib, write_section
from tsog_stream.container.sources import FileSource, read_index

REPO = Path(__file__).resolve().parents[1]
TSOG = REPO / ".venv" / "bin" / "tsog"
RESULTS = REPO / "benchmarks" / "results"
TICK = os.sysconf("SC_CLK_TCK")
PLAYS = 512
"""Distinct random t values, each a list of chunk ranges (a 'play')."""

LUA = """
local plays = {%s}
local queue = {}
local pos = 1
function request()
  if pos > #queue then
    queue = plays[math.random(#plays)]
    pos = 1
  end
  local r = queue[pos]
  pos = pos + 1
  return wrk.format("GET", wrk.path, {["Range"] = r})
end
"""


def make_file(root: Path) -> Path:
    """A synthetic 8 s scene segmented into a .tsogs container of a few MB."""
    return segmented_clip(
        root / "clip.tsogs", background=60000, objects=20, per_object=3000, seed=4
    )


def plays(path: Path, count: int, seed: int = 1) -> list[list[tuple[int, int]]]:
    """For ``count`` random t: the (offset, length) of each chunk a player fetches for [t, t+1]."""
    index = asyncio.run(read_index(FileSource(path)))
    info = index.manifest.scene
    rng = random.Random(seed)
    out = []
    for _ in range(count):
        t = rng.uniform(info.start_s, info.end_s)
        out.append([(c.offset, c.length) for c in index.chunks_for_interval(t, t + 1.0)])
    return [p for p in out if p]


def lua_script(play_list: list[list[tuple[int, int]]]) -> str:
    """The wrk script: each request the next range of a play, then a new random play."""
    rows = ("{" + ",".join(f'"bytes={a}-{a + n - 1}"' for a, n in play) + "}" for play in play_list)
    return LUA % ",\n".join(rows) + WRK_DONE


def proc_stats(pids: list[int]) -> tuple[float, float]:
    """(RSS MiB, CPU seconds) summed over ``pids``, from /proc."""
    rss = cpu = 0.0
    for pid in pids:
        rss += status_kib(pid, "VmRSS") / 1024
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        cpu += (int(fields[11]) + int(fields[12])) / TICK
    return rss, cpu


class Sampler:
    """Samples the RSS of ``pids`` every 0.1 s in a thread: the peak."""

    def __init__(self, pids: list[int]) -> None:
        self.pids, self.peak = pids, 0.0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.wait(0.1):
            self.peak = max(self.peak, proc_stats(self.pids)[0])

    def __enter__(self) -> Sampler:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5)


async def _python_load(url: str, play_file: Path, clients: int, seconds: float) -> dict[str, Any]:
    """The fallback generator: ``clients`` keep-alive players, latencies of each Range GET."""
    play_list = json.loads(play_file.read_text())
    latencies: list[float] = []
    errors, nbytes = 0, 0
    deadline = time.monotonic() + seconds
    connector = aiohttp.TCPConnector(limit=clients, force_close=False)
    timeout = aiohttp.ClientTimeout(total=10)
    async with aiohttp.ClientSession(connector=connector, timeout=timeout) as session:

        async def player(seed: int) -> None:
            nonlocal errors, nbytes
            rng = random.Random(seed)
            while time.monotonic() < deadline:
                for a, n in rng.choice(play_list):
                    t0 = time.monotonic()
                    try:
                        async with session.get(
                            url, headers={"Range": f"bytes={a}-{a + n - 1}"}
                        ) as r:
                            body = await r.read()
                        ok = r.status == 206 and len(body) == n
                    except (aiohttp.ClientError, TimeoutError):
                        ok = False
                    latencies.append(time.monotonic() - t0)
                    errors += not ok
                    nbytes += len(body) if ok else 0

        start = time.monotonic()
        await asyncio.gather(*(player(i) for i in range(clients)))
        elapsed = time.monotonic() - start
    latencies.sort()

    def pick(q: float) -> float:
        return 1000 * latencies[min(len(latencies) - 1, int(q * len(latencies)))]

    return {
        "requests": len(latencies),
        "rps": len(latencies) / elapsed,
        "mb_s": nbytes / elapsed / 1e6,
        "p50_ms": pick(0.5),
        "p99_ms": pick(0.99),
        "max_ms": 1000 * latencies[-1],
        "errors": errors,
        "error_kinds": {},
    }


def run_python(url: str, play_file: Path, clients: int, seconds: float) -> dict[str, Any]:
    """The Python generator in its own process (so it does not share the benchmark's GIL)."""
    cmd = [sys.executable, __file__, "--worker", url, str(play_file), str(clients), str(seconds)]
    out = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=seconds + 120)
    if out.returncode != 0:
        raise SystemExit(f"load generator failed: {out.stderr[-800:]}")
    result: dict[str, Any] = json.loads(out.stdout.splitlines()[-1])
    return result


def measure(url: str, pids: list[int], load: Any, clients: int, seconds: float) -> dict[str, Any]:
    """Warm up 2 s, then the load with RSS sampled and CPU read before and after."""
    load(url, max(10, clients // 10), 2.0)
    busy = os.getloadavg()[0]
    rss0, cpu0 = proc_stats(pids)
    with Sampler(pids) as sampler:
        result = load(url, clients, seconds)
    rss1, cpu1 = proc_stats(pids)
    peak = max(sampler.peak, rss0, rss1)
    return {
        **result,
        "rss_before_mib": round(rss0, 1),
        "rss_peak_mib": round(peak, 1),
        "rss_after_mib": round(rss1, 1),
        "rss_growth_mib": round(peak - rss0, 1),
        "cpu_s": round(cpu1 - cpu0, 2),
        "cpu_ms_per_request": round(1000 * (cpu1 - cpu0) / max(1, result["requests"]), 3),
        "loadavg_before": busy,
    }


def markdown(r: dict[str, Any], stamp: str) -> str:
    """The load section of docs/benchmarks.md."""
    o, n = r["ours"], r["nginx"]

    def ratio(key: str) -> str:
        return f"{o[key] / n[key]:.2f}" if n[key] else "-"

    rows = [
        ("requests/s", "rps", ".0f"),
        ("MB/s", "mb_s", ".0f"),
        ("p50 latency ms", "p50_ms", ".1f"),
        ("p99 latency ms", "p99_ms", ".1f"),
        ("max latency ms", "max_ms", ".1f"),
        ("errors", "errors", "d"),
        ("server RSS before MiB", "rss_before_mib", ".1f"),
        ("server RSS peak MiB", "rss_peak_mib", ".1f"),
        ("server RSS after MiB", "rss_after_mib", ".1f"),
        ("server RSS growth MiB (peak - before)", "rss_growth_mib", ".1f"),
        ("server CPU s", "cpu_s", ".1f"),
        ("server CPU ms per request", "cpu_ms_per_request", ".3f"),
    ]
    lines = [
        "## Load: many players at random t, our server beside nginx",
        "",
        f"Run {stamp} (`benchmarks/bench_load.py --clients {r['clients']} --seconds "
        f"{r['seconds']:g}`), loopback, 2 cores shared by server and load tool. "
        f"{r['clients']} keep-alive clients each fetch, one Range GET per chunk, the chunks a "
        f"player needs for [t, t+1 s] at a random t, then another t ({r['plays']} distinct t, "
        f"{r['requests_per_play']:.1f} chunks and {r['bytes_per_request'] / 1e3:.0f} kB per "
        f"request on average) from one {r['file_bytes'] / 1e6:.1f} MB `.tsogs` file. "
        f"Load tool: {r['tool']}. Ours: `tsog serve -q --workers {r['workers']} "
        f"--max-per-client {r['clients']}` (every player connects from 127.0.0.1, as behind a "
        "proxy; worker processes sharing the port, sendfile); nginx 1.22 (Debian nginx-light, "
        f"worker_processes {r['workers']}, sendfile on, access log off): each origin's default "
        "worker count on this machine. Each origin gets a 2 s warm-up, then the measured run; "
        "RSS is sampled from /proc/PID/status every 0.1 s and CPU read from /proc/PID/stat, "
        "summed over the parent and its workers. "
        f"The machine's 1-minute load average just before each measured run (other work on "
        f"the host included): {o['loadavg_before']:.2f} (ours), {n['loadavg_before']:.2f} "
        "(nginx).",
        "",
        "Why wrk: on 2 cores the load tool competes with the server for CPU; wrk (C, epoll, "
        "2 threads) spends far less CPU per request than a Python generator would, and the "
        "same tool and script load both origins. Its Lua `request()` keeps one play queue per "
        "thread, so a play's chunks go out on consecutive requests of that thread's "
        "connections rather than on one connection: the request mix is a player's, the "
        "per-connection order is not. wrk counts errors (connect, read, write, timeout, "
        "status >= 400) but does not check bytes: `tests/test_server_load.py` does.",
        "",
        "| figure | tsog serve | nginx | ours / nginx |",
        "|---|---:|---:|---:|",
    ]
    for label, key, fmt in rows:
        lines.append(f"| {label} | {o[key]:{fmt}} | {n[key]:{fmt}} | {ratio(key)} |")
    lines += [
        "",
        f"Average CPU use over the run: ours {o['cpu_s'] / r['seconds']:.2f} cores, nginx "
        f"{n['cpu_s'] / r['seconds']:.2f}: ours spends its CPU in Python per request (aiohttp's "
        "parser, routing, middleware and response; docs/http.md, 'The per-request path': raw "
        "throughput is what nginx or a CDN in front is for), "
        "nginx is far from CPU-bound and limited by the load tool sharing the 2 cores (wrk "
        "receives and copies every body).",
        f"Goals: 0 errors (ours: {o['errors']}), RSS growth under 50 MB "
        f"(ours: {o['rss_growth_mib']:.1f} MiB). "
        "`tests/test_server_load.py` runs a short version (50 clients, byte-checked bodies).",
    ]
    return "\n".join(lines) + "\n"


def origin_run(
    name: str, cmd_pids: tuple[str, list[int]], load: Any, args: argparse.Namespace
) -> dict[str, Any]:
    """Measure one origin (already running) and print a short line."""
    url, pids = cmd_pids
    asyncio.run(wait_up(url))
    result = measure(url, pids, load, args.clients, args.seconds)
    print(
        f"{name}: {result['rps']:.0f} req/s p50 {result['p50_ms']:.1f} ms "
        f"p99 {result['p99_ms']:.1f} ms errors {result['errors']} "
        f"rss +{result['rss_growth_mib']} MiB cpu {result['cpu_s']} s",
        flush=True,
    )
    return result


def main() -> int:
    """Make the file, then load our server and nginx in turn; write the results."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--clients", type=int, default=200, help="concurrent players")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured run per origin")
    parser.add_argument("--python", action="store_true", help="use the Python load generator")
    parser.add_argument(
        "--workers",
        type=int,
        default=len(os.sched_getaffinity(0)),
        help="processes of each origin (tsog serve --workers, nginx worker_processes; "
        "default: the core count, both origins' default)",
    )
    parser.add_argument("--no-write", action="store_true", help="do not update the docs")
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        url, play_file, clients, seconds = args.worker
        result = asyncio.run(_python_load(url, Path(play_file), int(clients), float(seconds)))
        print(json.dumps(result))
        return 0
    if not 1 <= args.clients <= 2000 or not 0 < args.seconds <= 600:
        parser.error("--clients must be 1-2000 and --seconds in (0, 600]")
    use_wrk = shutil.which("wrk") is not None and not args.python
    with tempfile.TemporaryDirectory(prefix="tsog-load-") as tmp:
        work = Path(tmp)
        root = work / "www"
        root.mkdir()
        path = make_file(root)
        play_list = plays(path, PLAYS)
        script, play_file = work / "plays.lua", work / "plays.json"
        script.write_text(lua_script(play_list))
        play_file.write_text(json.dumps(play_list))
        if use_wrk:
            tool = "wrk 4.1 (Debian), 2 threads, Lua script picking the Range headers"

            def load(url: str, clients: int, seconds: float) -> dict[str, Any]:
                return run_wrk(url, script, clients, seconds)
        else:
            tool = "Python asyncio/aiohttp generator in its own process"

            def load(url: str, clients: int, seconds: float) -> dict[str, Any]:
                return run_python(url, play_file, clients, seconds)

        p1, p2 = free_port(), free_port()
        results: dict[str, Any] = {}
        # every simulated player connects from 127.0.0.1: raise the per-address limit to the
        # client count, as for a server behind a proxy (docs/reliability.md)
        serve = [str(TSOG), "serve", str(root), "--port", str(p1), "-q"]
        serve += ["--workers", str(args.workers), "--max-per-client", str(args.clients)]
        ours = subprocess.Popen(serve)
        try:
            url = f"http://127.0.0.1:{p1}/files/clip.tsogs"
            asyncio.run(wait_up(url))
            pids = [ours.pid, *children(ours.pid)]
            results["ours"] = origin_run("ours", (url, pids), load, args)
        finally:
            ours.terminate()
            ours.wait(timeout=15)
        nginx = start_nginx(root, p2, work, workers=args.workers)
        try:
            url = f"http://127.0.0.1:{p2}/clip.tsogs"
            asyncio.run(wait_up(url))
            pids = [nginx.pid, *children(nginx.pid)]
            results["nginx"] = origin_run("nginx", (url, pids), load, args)
        finally:
            nginx.terminate()
            nginx.wait(timeout=15)
        sizes = [n for play in play_list for _, n in play]
        results.update(
            workers=args.workers,
            clients=args.clients,
            seconds=args.seconds,
            tool=tool,
            plays=len(play_list),
            requests_per_play=len(sizes) / len(play_list),
            bytes_per_request=sum(sizes) / len(sizes),
            file_bytes=path.stat().st_size,
        )
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    print(json.dumps(results, indent=2))
    if not args.no_write:
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "load.json").write_text(json.dumps({"date": stamp, **results}, indent=2))
        write_section("load", markdown(results, stamp), "bench_load.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

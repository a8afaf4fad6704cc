"""HTTP benchmark on loopback: our server versus nginx serving the same .tsogs file.

    .venv/bin/python benchmarks/bench_http.py [--seconds 3]

Measures, in one run: time to first frame at random t through our client (requests, bytes,
ms) against both origins; range throughput and latency for 64 KiB and 1 MiB ranges at 1, 16
and 64 concurrent connections with wrk (a fixed time per cell), both origins with the same
number of worker processes (default: the core count); client overhead versus
raw aiohttp GETs of the same byte ranges; and the server's RSS before and after the load.
Writes benchmarks/results/http.json and the "http" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np

from common import WRK_DONE, children, run_wrk, segmented_clip, status_kib, write_section
from tsog_stream.client.http_source import HttpSource
from tsog_stream.client.stream import StreamClient
from tsog_stream.container.ranges import ByteRange

REPO = Path(__file__).resolve().parents[1]
TSOG = REPO / ".venv" / "bin" / "tsog"
NGINX = "/usr/sbin/nginx"
RESULTS = REPO / "benchmarks" / "results"


def free_port() -> int:
    """An unused loopback port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_mib(pid: int) -> float:
    """Resident memory of a process, from /proc."""
    return round(status_kib(pid, "VmRSS") / 1024, 1)


def start_nginx(root: Path, port: int, work: Path, workers: int = 1) -> subprocess.Popen[bytes]:
    """nginx in the foreground on 127.0.0.1:port serving ``root`` with ``workers`` worker
    processes (stopped by the caller)."""
    conf = work / "nginx.conf"
    (work / "logs").mkdir(exist_ok=True)
    conf.write_text(
        f"""daemon off; worker_processes {workers}; pid {work}/nginx.pid; error_log {work}/logs/error.log;
events {{ worker_connections 1024; }}
http {{ access_log off; sendfile on; default_type application/octet-stream;
  client_body_temp_path {work}/tmp; proxy_temp_path {work}/tmp; fastcgi_temp_path {work}/tmp;
  uwsgi_temp_path {work}/tmp; scgi_temp_path {work}/tmp;
  server {{ listen 127.0.0.1:{port}; root {root}; location / {{ }} }} }}
"""
    )
    (work / "tmp").mkdir(exist_ok=True)
    user = ["-g", "user root;"] if os.geteuid() == 0 else []
    return subprocess.Popen([NGINX, "-p", str(work), "-c", str(conf), *user])


async def wait_up(url: str) -> None:
    """Poll until the origin answers (at most 10 s)."""
    deadline = time.monotonic() + 10
    async with aiohttp.ClientSession() as session:
        while time.monotonic() < deadline:
            try:
                async with session.head(url) as r:
                    if r.status < 500:
                        return
            except aiohttp.ClientError:
                await asyncio.sleep(0.1)
    raise SystemExit(f"{url} did not come up")


async def first_frames(url: str, times: list[float]) -> dict[str, float]:
    """Open fresh and read the frame at each t; mean ms, requests and bytes."""
    ms, reqs, nbytes = [], [], []
    for t in times:
        start = time.monotonic()
        async with await StreamClient.open(url) as client:
            await client.frame_at(t)
            ms.append(1000 * (time.monotonic() - start))
            reqs.append(client.source.stats.requests)
            nbytes.append(client.source.stats.bytes)
    return {
        "ms": float(np.mean(ms)),
        "requests": float(np.mean(reqs)),
        "bytes": float(np.mean(nbytes)),
    }


CELLS = [(span, conns) for span in (64 * 1024, 1024 * 1024) for conns in (1, 16, 64)]
"""Load cells: range size x concurrent connections."""
RANDOM_RANGES = """
math.randomseed(%d)
function request()
  local a = math.random(0, %d)
  return wrk.format("GET", wrk.path, {["Range"] = "bytes=" .. a .. "-" .. (a + %d)})
end
"""


def load(
    url: str, size: int, span: int, conns: int, *, seconds: float, work: Path
) -> dict[str, Any]:
    """wrk: Range GETs of ``span`` bytes at random offsets from ``conns`` keep-alive
    connections for ``seconds``: MB/s, requests/s, p50 ms and errors."""
    script = work / f"ranges-{span}-{conns}.lua"
    script.write_text(RANDOM_RANGES % (conns, max(0, size - span), span - 1) + WRK_DONE)
    return run_wrk(url, script, conns, seconds, threads=min(2, conns))


async def python_load(
    url: str, size: int, span: int, conns: int, seconds: float
) -> dict[str, float]:
    """The same cell with an aiohttp client in this process (the load tool of runs before
    2026-11-25, whose figures the issues quote): MB/s and p50 ms. The client is the bottleneck
    here, so this understates a fast origin; it is kept to compare with those figures."""
    latencies: list[float] = []
    done = 0
    deadline = time.monotonic() + seconds
    rng = np.random.default_rng(conns)
    connector = aiohttp.TCPConnector(limit=conns)
    async with aiohttp.ClientSession(connector=connector) as session:

        async def worker() -> None:
            nonlocal done
            while time.monotonic() < deadline:
                a = int(rng.integers(0, max(1, size - span)))
                t0 = time.monotonic()
                headers = {"Range": f"bytes={a}-{a + span - 1}", "Accept-Encoding": "identity"}
                async with session.get(url, headers=headers) as r:
                    body = await r.read()
                latencies.append(time.monotonic() - t0)
                done += len(body)

        start = time.monotonic()
        await asyncio.gather(*(worker() for _ in range(conns)))
        elapsed = time.monotonic() - start
    return {"mb_s": done / elapsed / 1e6, "p50_ms": 1000 * float(np.median(latencies))}


async def client_overhead(url: str, ranges: list[tuple[int, int]]) -> dict[str, float]:
    """Our HttpSource reads versus raw aiohttp GETs of the same ranges (total ms each)."""
    async with aiohttp.ClientSession() as session:
        t0 = time.monotonic()
        for a, b in ranges:
            async with session.get(url, headers={"Range": f"bytes={a}-{b - 1}"}) as r:
                await r.read()
        raw = time.monotonic() - t0
    source = HttpSource(url)
    try:
        await source.size()
        t0 = time.monotonic()
        for a, b in ranges:
            await source.read(ByteRange(a, b))
        ours = time.monotonic() - t0
    finally:
        await source.aclose()
    return {"raw_ms": 1000 * raw, "client_ms": 1000 * ours, "ratio": ours / raw if raw else 0.0}


async def measure(
    path: Path, ours: str, nginx: str, server_pids: list[int], *, seconds: float, work: Path
) -> dict[str, Any]:
    """Every figure for both origins."""
    size = path.stat().st_size
    times = [float(t) for t in np.random.default_rng(3).uniform(0, 8, 5)]
    rss_before = sum(rss_mib(p) for p in server_pids)
    out: dict[str, Any] = {"file_bytes": size, "rss_before_mib": rss_before}
    for name, url in (("ours", ours), ("nginx", nginx)):
        out[f"first_frame_{name}"] = await first_frames(url, times)
        for span, conns in CELLS:
            cell = load(url, size, span, conns, seconds=seconds, work=work)
            out[f"load_{name}_{span}_{conns}"] = cell
            py = await python_load(url, size, span, conns, seconds)
            out[f"pyload_{name}_{span}_{conns}"] = py
    rng = np.random.default_rng(5)
    starts = rng.integers(0, size - 65536, 200)
    out["client_overhead"] = await client_overhead(ours, [(int(a), int(a) + 65536) for a in starts])
    out["rss_after_mib"] = round(sum(rss_mib(p) for p in server_pids), 1)
    return out


def _pairs(r: dict[str, Any], kind: str) -> Iterator[tuple[str, dict[str, Any], dict[str, Any]]]:
    """Per load cell: its table row up to the ratio column, ours and nginx's figures."""
    for span, conns in CELLS:
        o, n = r[f"{kind}_ours_{span}_{conns}"], r[f"{kind}_nginx_{span}_{conns}"]
        row = (
            f"| {span // 1024} KiB | {conns} | {o['mb_s']:.0f} | {n['mb_s']:.0f} | "
            f"{o['mb_s'] / n['mb_s']:.2f}"
        )
        yield row, o, n


def markdown(r: dict[str, Any], stamp: str) -> str:
    """The http section of docs/benchmarks.md."""
    fo, fn = r["first_frame_ours"], r["first_frame_nginx"]
    lines = [
        "## HTTP: our server and client versus nginx, on loopback",
        "",
        f"Run {stamp} (`benchmarks/bench_http.py`), one {r['file_bytes'] / 1e6:.1f} MB `.tsogs` "
        f"file served by `tsog serve --workers {r['workers']}` and by nginx 1.22 (Debian, "
        f"sendfile on, worker_processes {r['workers']}) in the same run, on 2 cores shared with "
        "the load tool: wrk 4.1 (Debian, up to 2 threads, a Lua script picking random ranges; "
        "every cell a fixed time, 0 errors unless said).",
        "",
        "Time to first frame at random t (fresh client each time, mean of 5):",
        "",
        "| origin | ms | requests | bytes |",
        "|---|---:|---:|---:|",
        f"| tsog serve | {fo['ms']:.1f} | {fo['requests']:.1f} | {fo['bytes']:,.0f} |",
        f"| nginx | {fn['ms']:.1f} | {fn['requests']:.1f} | {fn['bytes']:,.0f} |",
        "",
        "Range GETs (throughput MB/s and median latency ms; ratio = ours / nginx throughput):",
        "",
        "| range | connections | ours MB/s | nginx MB/s | ratio | ours p50 ms | nginx p50 ms | errors |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for cell, o, n in _pairs(r, "load"):
        lines.append(
            f"{cell} | {o['p50_ms']:.2f} | {n['p50_ms']:.2f} | {o['errors'] + n['errors']} |"
        )
    lines += [
        "",
        "The same cells with the Python aiohttp client in the benchmark's process (the load tool "
        "of earlier runs, which the issues quote; the client is the bottleneck, so it flatters a "
        "slow origin):",
        "",
        "| range | connections | ours MB/s | nginx MB/s | ratio |",
        "|---:|---:|---:|---:|---:|",
    ]
    lines += [f"{cell} |" for cell, _, _ in _pairs(r, "pyload")]
    c = r["client_overhead"]
    lines += [
        "",
        f"Client overhead: 200 sequential 64 KiB reads through `HttpSource` took {c['client_ms']:.0f} ms "
        f"versus {c['raw_ms']:.0f} ms of raw aiohttp GETs ({c['ratio']:.2f}x; the client also validates "
        "status, Content-Range and length, and pins the ETag with If-Match).",
        f"Server RSS: {r['rss_before_mib']} MiB before the load, {r['rss_after_mib']} MiB after.",
    ]
    return "\n".join(lines) + "\n"


def main() -> int:
    """Make a scene, start both origins, measure, stop them, write the results."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=3.0, help="duration of each load cell")
    parser.add_argument(
        "--workers",
        type=int,
        default=len(os.sched_getaffinity(0)),
        help="processes of each origin (default: the core count, both origins' default)",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="tsog-http-") as tmp:
        root = Path(tmp) / "www"
        root.mkdir()
        path = segmented_clip(
            root / "clip.tsogs", background=150000, objects=30, per_object=5000, seed=2
        )
        p1, p2 = free_port(), free_port()
        serve = [str(TSOG), "serve", str(root), "--port", str(p1), "-q"]
        ours = subprocess.Popen([*serve, "--workers", str(args.workers)])
        nginx = start_nginx(root, p2, Path(tmp), workers=args.workers)
        try:
            url1 = f"http://127.0.0.1:{p1}/files/clip.tsogs"
            url2 = f"http://127.0.0.1:{p2}/clip.tsogs"
            asyncio.run(wait_up(url1))
            asyncio.run(wait_up(url2))
            pids = [ours.pid, *children(ours.pid)]
            result = asyncio.run(
                measure(path, url1, url2, pids, seconds=args.seconds, work=Path(tmp))
            )
            result["workers"] = args.workers
        finally:
            for proc in (ours, nginx):
                proc.terminate()
                proc.wait(timeout=15)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "http.json").write_text(json.dumps({"date": stamp, **result}, indent=2))
    write_section("http", markdown(result, stamp), "bench_http.py")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

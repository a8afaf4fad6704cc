"""Helpers shared by tests: quantisation bounds and aligned comparisons."""

from __future__ import annotations

import asyncio
import http.client
import importlib
import logging
import os
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from aiohttp import web

from tsog_stream import Gaussians, Scene, TimelineType
from tsog_stream.codec.positions import log_transform
from tsog_stream.constants import U16_MAX
from tsog_stream.io.ply import write_ply
from tsog_stream.model import evaluate_all, reference_times
from tsog_stream.segment.meter import report_progress
from tsog_stream.server.app import start_server
from tsog_stream.temporal import lifespans, visibility_half_width


def means_log_step(mins: list[float], maxs: list[float]) -> npt.NDArray[np.float64]:
    """One 16-bit step of the log-space position code, per axis."""
    return (np.asarray(maxs, np.float64) - np.asarray(mins, np.float64)) / U16_MAX


def log_space_error(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """|f(a) - f(b)| per coordinate, f the symmetric log transform of SOG positions."""
    return np.abs(log_transform(a) - log_transform(b))


def _edges(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    assert scene.timeline is not None
    return lifespans(scene.timeline)


def check_decoded_at(src: Scene, decoded: Scene, meta: dict[str, Any], t: float) -> None:
    """Decoded positions at t are within the base step plus every order's coefficient step."""
    ref, mask = evaluate_all(src, t)
    got, got_mask = evaluate_all(decoded, t)
    assert src.timeline is not None
    dt = np.abs(t - reference_times(src.timeline))
    tl_meta = meta["timeline"]
    t_step = (np.asarray(tl_meta["maxs"]) - np.asarray(tl_meta["mins"])) / 65535
    spu = 1 / tl_meta["fps"] if tl_meta.get("fps") else 1.0
    bound = np.zeros(len(src))
    motion = meta.get("temporal", {}).get("means", {"mins": [], "maxs": []})
    coeff = np.abs(src.temporal["means"]).max(axis=(0, 2)) if motion["mins"] else []
    for k, (mins, maxs) in enumerate(zip(motion["mins"], motion["maxs"], strict=True)):
        half = (np.asarray(maxs) - np.asarray(mins)).max() / 65535 / 2
        # coefficient error, plus the reference-time error moving along the path
        bound += half * dt ** (k + 1) + (k + 1) * coeff[k] * (dt + 1) ** k * t_step[0] * spu / 2
    base = (1 + np.abs(ref.means).max(axis=1)) * means_log_step(
        meta["means"]["mins"], meta["means"]["maxs"]
    ).max()
    err = np.abs(ref.means - got.means).max(axis=1)
    both = mask & got_mask
    assert np.all(err[both] <= (bound + base + 1e-6)[both]), f"t={t}"
    # Visibility may differ only where t is within one quantisation error of a lifespan edge.
    start, end = _edges(src)
    half_width = visibility_half_width() if src.timeline.type is TimelineType.CENTER_SCALE else 1.0
    edge_error = (t_step[0] + half_width * t_step[1]) * spu / 2 + 1e-9
    near_edge = np.minimum(np.abs(t - start), np.abs(t - end)) <= edge_error
    assert not np.any((mask != got_mask) & ~near_edge), f"visibility changed away from edges, t={t}"


class ThreadedServer:
    """An aiohttp app served from a background thread with its own event loop (tests only)."""

    def __init__(self, app: web.Application) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        future = asyncio.run_coroutine_threadsafe(start_server(app), self.loop)
        self.runner, self.port = future.result(10)

    def stop(self) -> None:
        """Shut down the server and its loop."""
        asyncio.run_coroutine_threadsafe(self.runner.cleanup(), self.loop).result(30)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


NGINX = Path("/usr/sbin/nginx")


def write_ply_frames(folder: Path, frames: Iterable[Gaussians]) -> list[Path]:
    """Each frame as a numbered float PLY (frame_0000.ply, ...) in the new ``folder``: a frame
    sequence input; the paths in frame order."""
    folder.mkdir()
    paths = []
    for k, gaussians in enumerate(frames):
        paths.append(folder / f"frame_{k:04d}.ply")
        write_ply(paths[-1], gaussians)
    return paths


def free_port() -> int:
    """An unused loopback port."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_listening(port: int, proc: subprocess.Popen[bytes]) -> None:
    """Wait (at most 10 s) until nginx accepts connections on ``port``."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"nginx exited with {proc.returncode}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError("nginx did not start listening")


@contextmanager
def nginx_origin(
    root: Path,
    prefix: Path,
    max_ranges: int | None = None,
    *,
    http_extra: str = "",
    server_extra: str = "",
) -> Iterator[str]:
    """A plain static nginx (Debian's, installed by scripts/setup) serving ``root`` on
    127.0.0.1, optionally with ``max_ranges`` and extra ``http``/``server`` directives; yields
    its base URL and always stops it."""
    if not os.access(NGINX, os.X_OK):
        pytest.fail("nginx is not installed: run scripts/setup")
    port = free_port()
    prefix.mkdir(parents=True, exist_ok=True)
    (prefix / "logs").mkdir(exist_ok=True)
    user = "user root;" if os.geteuid() == 0 else ""
    mr = f"max_ranges {max_ranges};" if max_ranges is not None else ""
    temps = "\n".join(
        f"{k}_temp_path {prefix}/tmp_{k};" for k in ("client_body", "proxy", "fastcgi", "uwsgi")
    )
    conf = prefix / "nginx.conf"
    conf.write_text(
        f"""{user}
worker_processes 1;
daemon off;
pid {prefix}/nginx.pid;
error_log {prefix}/logs/error.log warn;
events {{ worker_connections 256; }}
http {{
    default_type application/octet-stream;
    access_log {prefix}/logs/access.log;
    {temps}
    scgi_temp_path {prefix}/tmp_scgi;
    {http_extra}
    sendfile on;
    server_tokens off;
    server {{
        listen 127.0.0.1:{port};
        root {root};
        etag on;
        {mr}
        {server_extra}
        location / {{ autoindex off; }}
    }}
}}
"""
    )
    proc = subprocess.Popen(
        [NGINX, "-p", str(prefix), "-c", str(conf)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_listening(port, proc)
        yield f"http://127.0.0.1:{port}/"
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGQUIT)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.terminate()
                proc.wait(5)


class Resp:
    """Status, headers and body of one response."""

    def __init__(self, r: http.client.HTTPResponse) -> None:
        self.status = r.status
        self.headers = r.headers
        self.body = r.read()


def fetch(
    port: int,
    path: str,
    method: str = "GET",
    headers: dict[str, Any] | None = None,
    source: str | None = None,
) -> Resp:
    """One request to 127.0.0.1 on a fresh connection, target and headers sent as given (from
    the loopback address ``source`` when given: another client, as the server sees it)."""
    origin = (source, 0) if source is not None else None
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30, source_address=origin)
    try:
        conn.putrequest(method, path, skip_accept_encoding=True)
        for k, v in (headers or {}).items():
            conn.putheader(k, v)
        conn.endheaders()
        return Resp(conn.getresponse())
    finally:
        conn.close()


def proc_stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state, ppid, pgrp, session, ...;
    utime and stime are 11 and 12), or None when the process is gone (Linux)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def resident_mib(pid: int) -> float:
    """Resident memory of process ``pid`` now (VmRSS), in MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def live_processes(where: Callable[[list[str]], bool]) -> set[int]:
    """Pids of live (non-zombie) processes whose /proc stat fields satisfy ``where``."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = proc_stat(int(entry.name))
            if fields is not None and fields[0] != "Z" and where(fields):
                found.add(int(entry.name))
    return found


def wait_until(check: Callable[[], object], timeout: float, what: str) -> None:
    """Poll ``check()`` every 10 ms until true; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.01)


_PINNED: list[npt.NDArray[np.float64]] = []
"""Arrays a worker keeps from one job to the next (see :func:`heap_holes_left`)."""


def heap_holes_left(mib: int) -> float:
    """Run on a worker: ``mib`` arrays of 1 MiB (under the mmap threshold: from the heap)
    freed below one that is kept, so glibc keeps their pages as holes it does not return by
    itself; the worker's resident MiB after."""
    blocks = [np.ones(1 << 17) for _ in range(mib)]
    _PINNED.append(np.ones(1 << 17))  # the heap's top stays in use: nothing is trimmed
    del blocks
    return resident_mib(os.getpid())


def resident_here() -> float:
    """Run on a worker: its resident MiB as a job starts."""
    return resident_mib(os.getpid())


def reporting_job(steps: int) -> int:
    """Run on a worker (pool or Dask): a job that says how far it got, ``steps`` times; its
    process id."""
    for step in range(1, steps + 1):
        report_progress(step / steps)
    return os.getpid()


@contextmanager
def loopback_s3(bucket: str) -> Iterator[Any]:
    """A moto S3 server on loopback holding an empty ``bucket``, the environment pointing
    s3fs at it for the duration; yields an ``s3fs.S3FileSystem`` (moto and s3fs are dev and
    [s3] extras that scripts/setup installs)."""
    moto_server = importlib.import_module("moto.server")
    s3fs = importlib.import_module("s3fs")
    logging.getLogger("werkzeug").setLevel(logging.ERROR)
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    env = {
        "AWS_ACCESS_KEY_ID": "loopback",
        "AWS_SECRET_ACCESS_KEY": "loopback",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL": f"http://{host}:{port}",
    }
    try:
        with pytest.MonkeyPatch.context() as mp:
            for key, value in env.items():
                mp.setenv(key, value)
            s3fs.S3FileSystem.clear_instance_cache()
            fs = s3fs.S3FileSystem()
            fs.call_s3("create_bucket", Bucket=bucket)
            try:
                yield fs
            finally:
                s3fs.S3FileSystem.clear_instance_cache()
    finally:
        server.stop()

"""``tsog serve --workers N``: N processes serving one port, so one core's event loop is not the
limit. Each worker binds the port with SO_REUSEPORT and the kernel spreads new connections over
them; the parent holds the port (bound, never listening), starts the workers, restarts one that
dies, and stops them all on SIGINT or SIGTERM. Every worker has its own limits and caches
(docs/http.md, "Worker processes").
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import os
import select
import signal
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final

from ..errors import InputError
from ..machine import usable_cores
from .app import cannot_listen, make_app, start_server
from .private import Privacy
from .respond import Limits

READY_TIMEOUT_S: Final = 30.0
"""How long the parent waits for every worker to listen before it gives up."""
RESTARTS_PER_MINUTE: Final = 10
"""A worker that keeps dying is not restarted more often than this (the parent then stops)."""
POLL_S: Final = 0.1
"""How often the parent looks for ended workers and stop signals."""
STOP_GRACE_S: Final = 10.0
"""How long stopping workers may take before they are killed."""

log = logging.getLogger("tsog.serve")


def default_workers() -> int:
    """One worker per core this process may run on (machine.usable_cores)."""
    return usable_cores()


@dataclass(frozen=True)
class Site:
    """What every worker serves, and where."""

    root: Path | str
    """A folder or file, or a storage URL."""
    host: str
    port: int
    limits: Limits
    privacy: Privacy


def reserve_port(host: str, port: int) -> socket.socket:
    """A socket bound to host:port with SO_REUSEPORT and not listening: it keeps the port (a
    free one for port 0) for the workers without taking any connection itself. The port is
    first bound without SO_REUSEPORT, so a port another server (even another ``tsog serve
    --workers``) holds is refused instead of silently shared."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with _bound(family, host, port, reuse=False) as probe:
        port = probe.getsockname()[1]
    return _bound(family, host, port, reuse=True)


def _bound(family: socket.AddressFamily, host: str, port: int, *, reuse: bool) -> socket.socket:
    """A TCP socket bound to host:port; a busy port or a bad address is one InputError line."""
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # TIME_WAIT does not block
    if reuse:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise cannot_listen(exc, host, port) from exc
    return sock


async def _serve_worker(site: Site, ready: int) -> None:
    """One worker: listen on the shared port, say so on ``ready``, serve until signalled."""
    app = make_app(site.root, limits=site.limits, privacy=site.privacy)
    runner, _ = await start_server(app, site.host, site.port, reuse_port=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    os.write(ready, b"1")
    os.close(ready)
    try:
        await stop.wait()
    finally:
        _ignore_stop_signals(loop)
        await runner.cleanup()


def _ignore_stop_signals(loop: asyncio.AbstractEventLoop) -> None:
    """Once stopping, ignore SIGINT and SIGTERM (a group's Ctrl-C and then the parent's SIGTERM
    both reach a worker), their loop handlers removed before the loop closes its wakeup pipe
    (a signal in between printed "Exception ignored when trying to write to the signal wakeup
    fd")."""
    stops = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)  # none lands between the two calls
    try:
        for signum in stops:
            loop.remove_signal_handler(signum)  # back to the default action, then ignored
            signal.signal(signum, signal.SIG_IGN)
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, stops)


PR_SET_PDEATHSIG: Final = 1


def _end_with_parent(parent: int) -> None:
    """Have the kernel SIGKILL this worker when the parent dies without stopping it (killed
    itself: the server crashed, as one process would), so no orphan keeps serving the port
    (Linux prctl); exit now if the parent is already gone."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(0)


def _start_worker(site: Site, ready: int) -> int:
    """Fork a worker process; returns its pid (the child never returns)."""
    parent = os.getpid()
    pid = os.fork()
    if pid:
        return pid
    code = 0
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_DFL)
        _end_with_parent(parent)
        asyncio.run(_serve_worker(site, ready))
    except InputError as exc:
        os.write(2, f"tsog: error: {exc}\n".encode(errors="replace"))
        code = 1
    except BaseException:  # a worker reports and exits, never returns into the CLI
        log.exception("worker %d stopped", os.getpid())
        code = 1
    finally:
        os._exit(code)


def _wait_ready(ready: int, count: int) -> None:
    """Block until ``count`` workers said they listen (or one failed: the pipe closes)."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    seen = 0
    while seen < count:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([ready], [], [], left)[0]:
            raise InputError(f"{count - seen} of {count} workers did not start", where="--workers")
        data = os.read(ready, count - seen)
        if not data:
            raise InputError("a worker failed to start (see above)", where="--workers")
        seen += len(data)


@contextlib.contextmanager
def _stopping_signals() -> Iterator[list[bool]]:
    """SIGINT and SIGTERM set a flag instead of raising, so the parent stops its workers."""
    stopping = [False]

    def stop(signum: int, frame: object) -> None:
        stopping[0] = True

    before = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stopping
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


def run_workers(site: Site, workers: int) -> None:
    """Serve ``site`` with ``workers`` processes until SIGINT or SIGTERM (blocking)."""
    holder = reserve_port(site.host, site.port)
    site = replace(site, port=holder.getsockname()[1])
    read_end, write_end = os.pipe()
    pids: set[int] = set()
    with holder, _stopping_signals() as stopping:
        try:
            pids = {_start_worker(site, write_end) for _ in range(workers)}
            os.close(write_end)
            _wait_ready(read_end, workers)
            print(
                f"serving {site.root} on http://{site.host}:{site.port}/ (web player: /play/), "
                f"{workers} worker processes",
                flush=True,
            )
            _supervise(site, pids, stopping)
        finally:
            os.close(read_end)
            _stop(pids)


def _supervise(site: Site, pids: set[int], stopping: list[bool]) -> None:
    """Until a stop signal, restart a worker that dies (at most RESTARTS_PER_MINUTE)."""
    restarts: list[float] = []
    while not stopping[0]:
        pid, status = _reap()
        if not pid:
            time.sleep(POLL_S)
            continue
        pids.discard(pid)
        now = time.monotonic()
        restarts = [t for t in restarts if now - t < 60] + [now]
        if len(restarts) > RESTARTS_PER_MINUTE:
            raise InputError("workers keep dying; stopping", where="--workers")
        log.warning("worker %d ended (status %d); starting another", pid, status)
        ready, done = os.pipe()
        pids.add(_start_worker(site, done))
        os.close(done)
        with contextlib.suppress(InputError):
            _wait_ready(ready, 1)
        os.close(ready)


def _reap() -> tuple[int, int]:
    """A worker that ended (pid, wait status), or (0, 0) when none has."""
    try:
        return os.waitpid(-1, os.WNOHANG)
    except ChildProcessError:
        return 0, 0


def _stop(pids: set[int]) -> None:
    """SIGTERM every worker, wait STOP_GRACE_S for them, then SIGKILL what is left."""
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_GRACE_S
    while pids and time.monotonic() < deadline:
        for pid in list(pids):
            with contextlib.suppress(ChildProcessError):
                if os.waitpid(pid, os.WNOHANG)[0] == 0:
                    continue
            pids.discard(pid)
        time.sleep(0.05)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)

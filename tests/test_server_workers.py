"""`tsog serve --workers N`: N real processes share one port; a worker that dies is replaced,
a killed parent takes its workers with it, Ctrl-C stops them all."""

from __future__ import annotations

import contextlib
import http.client
import os
import re
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import live_processes, proc_stat, wait_until
from serve_process import TSOG

BODY = bytes(range(256)) * 1024


def children(pid: int) -> set[int]:
    """Live child processes of ``pid``."""
    return live_processes(lambda fields: int(fields[1]) == pid)


def alive(pid: int) -> bool:
    fields = proc_stat(pid)
    return fields is not None and fields[0] != "Z"


def get_range(port: int, start: int, end: int) -> tuple[int, bytes]:
    """One ranged GET on a fresh connection (so the kernel may pick any worker)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", "/files/blob.bin", headers={"Range": f"bytes={start}-{end}"})
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], int]]:
    """``tsog serve --workers 2`` on a free port; always stopped."""
    (tmp_path / "blob.bin").write_bytes(BODY)
    cmd = [str(TSOG), "serve", str(tmp_path), "--port", "0", "--workers", "2", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()
        match = re.search(r"http://127\.0\.0\.1:(\d+)/.*2 worker processes", line)
        assert match, line + (proc.stderr.read().decode() if proc.stderr else "")
        yield proc, int(match.group(1))
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
        proc.stdout.close() if proc.stdout else None
        proc.stderr.close() if proc.stderr else None


def test_workers_share_the_port_and_every_answer_is_exact(
    served: tuple[subprocess.Popen[bytes], int],
) -> None:
    proc, port = served
    workers = children(proc.pid)
    assert len(workers) == 2
    cpu_before = {w: _cpu_ticks(w) for w in workers}
    for k in range(200):
        start = (k * 7919) % (len(BODY) - 5000)
        status, body = get_range(port, start, start + 4999)
        assert status == 206 and body == BODY[start : start + 5000]
    busy = [w for w in workers if _cpu_ticks(w) > cpu_before[w]]
    assert len(busy) == 2, "one worker answered everything"


def _cpu_ticks(pid: int) -> int:
    fields = proc_stat(pid)
    assert fields is not None, f"worker {pid} is gone"
    return int(fields[11]) + int(fields[12])


def test_a_dead_worker_is_replaced(served: tuple[subprocess.Popen[bytes], int]) -> None:
    proc, port = served
    first = children(proc.pid)
    victim = min(first)
    os.kill(victim, signal.SIGKILL)
    wait_until(lambda: len(children(proc.pid) - {victim}) == 2, 10, "a new worker")
    for k in range(20):
        status, body = get_range(port, k, k + 99)
        assert status == 206 and body == BODY[k : k + 100]


def test_killing_the_parent_ends_its_workers(served: tuple[subprocess.Popen[bytes], int]) -> None:
    proc, port = served
    workers = children(proc.pid)
    proc.kill()
    proc.wait(5)
    wait_until(lambda: not any(alive(w) for w in workers), 10, "the orphaned workers to end")
    with pytest.raises(OSError):
        get_range(port, 0, 9)


def test_ctrl_c_stops_every_worker_cleanly(served: tuple[subprocess.Popen[bytes], int]) -> None:
    proc, _ = served
    workers = children(proc.pid)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(15) == 0
    wait_until(lambda: not any(alive(w) for w in workers), 10, "the workers to stop")
    assert proc.stderr is not None and b"Traceback" not in proc.stderr.read()


def test_signals_while_stopping_end_every_process_quietly(
    served: tuple[subprocess.Popen[bytes], int],
) -> None:
    """A terminal's Ctrl-C reaches the whole group and the parent then sends each worker
    SIGTERM: signals that reach a worker while it stops are ignored, nothing is printed, the
    parent exits 0."""
    proc, _ = served
    workers = children(proc.pid)
    for pid in [*workers, proc.pid]:
        os.kill(pid, signal.SIGINT)
    for _ in range(50):
        for pid in workers:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
    assert proc.wait(15) == 0
    assert proc.stderr is not None
    err = proc.stderr.read()
    assert b"Traceback" not in err and b"Exception ignored" not in err, err


def test_a_port_held_by_another_server_is_refused_not_shared(
    served: tuple[subprocess.Popen[bytes], int], tmp_path: Path
) -> None:
    """SO_REUSEPORT would let a second `tsog serve --workers` share the port and split its
    traffic; it is refused as a port in use."""
    _, port = served
    cmd = [str(TSOG), "serve", str(tmp_path), "--port", str(port), "--workers", "2", "-q"]
    done = subprocess.run(cmd, capture_output=True, timeout=30, check=False)
    assert done.returncode == 1
    assert f"port {port} is in use; try --port 0" in done.stderr.decode()
    assert b"Traceback" not in done.stderr

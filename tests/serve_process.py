"""`tsog serve` as a real child process for tests, with its RSS, CPU and open fds from /proc."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from helpers import free_port, proc_stat, resident_mib

TSOG = Path(sys.executable).with_name("tsog")
TICK = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True, slots=True)
class Served:
    """A running ``tsog serve``: its port and pid."""

    port: int
    pid: int
    log: Path
    """The server's stderr; with ``-q`` only warnings and errors (tracebacks) land there."""

    def stderr(self) -> str:
        """What the server wrote to stderr so far."""
        return self.log.read_text(errors="replace")

    def rss_mib(self) -> float:
        """Resident memory now (VmRSS)."""
        return resident_mib(self.pid)

    def cpu_s(self) -> float:
        """User plus system CPU seconds so far."""
        fields = proc_stat(self.pid)
        assert fields is not None, "tsog serve is gone"
        return (int(fields[11]) + int(fields[12])) / TICK

    def open_fds(self) -> int:
        """Open file descriptors (sockets included)."""
        return len(os.listdir(f"/proc/{self.pid}/fd"))


@contextmanager
def tsog_serve(root: Path, *options: str, nofile: int | None = None) -> Iterator[Served]:
    """Run ``tsog serve ROOT -q OPTIONS`` on a free loopback port (with at most ``nofile`` open
    files if given); always stops it."""
    port = free_port()
    workers = [] if "--workers" in options else ["--workers", "1"]  # measured: one process
    cmd = [str(TSOG), "serve", str(root), "--port", str(port), "-q", *workers, *options]
    with tempfile.TemporaryDirectory(prefix="tsog-serve-") as tmp:
        log = Path(tmp) / "stderr.txt"
        with open(log, "wb") as err:
            limit = [] if nofile is None else ["prlimit", f"--nofile={nofile}"]  # execs cmd
            proc = subprocess.Popen([*limit, *cmd], stdout=subprocess.DEVNULL, stderr=err)
        try:
            _wait_listening(proc, port, log)
            yield Served(port, proc.pid, log)
            assert proc.poll() is None, "tsog serve died"
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)


def _wait_listening(proc: subprocess.Popen[bytes], port: int, log: Path) -> None:
    """Wait (at most 20 s) until the server accepts connections."""
    deadline = time.monotonic() + 20
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"tsog serve did not start: {log.read_text(errors='replace')[-500:]}")

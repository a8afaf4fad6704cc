"""Run ``tsog`` command lines in forked children and report each one's exit, stderr and peak RSS.

Used by tests/test_cli_hostile.py: ``python tests/cli_probe.py < runs.json > results.json``.
The parent imports every module a command may load, then forks one child per run (a few at a
time), so a
child's peak resident memory beyond that of an idle child is what the command itself used (RSS, not
Python allocations: numpy, Pillow and zstd allocate outside tracemalloc's view). A child
still running after its time limit is killed and reported as such.

Input: a JSON list of ``{"argv": [...], "cwd": "...", "timeout_s": float}``. Output: a JSON
list of ``{"code": int | null, "stderr": str, "rss_growth": int, "seconds": float,
"timed_out": bool}``.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import resource
import signal
import sys
import tempfile
import time
import traceback
from typing import Any

PRELOADED = (
    "tsog_stream.cli.main",
    "tsog_stream.cli.stream_commands",
    "tsog_stream.cli.render_commands",
    "tsog_stream.server.app",
    "tsog_stream.client",
    "tsog_stream.render.evaluate",
    "tsog_stream.segment.segmenter",
    "tsog_stream.io.fourdgs",
)


def _child(argv: list[str], cwd: str, stderr_path: str) -> None:
    """Run one command line with stdout discarded and stderr to a file; never returns."""
    code = 70
    try:
        os.chdir(cwd)
        err = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        null = os.open(os.devnull, os.O_RDWR)
        os.dup2(null, 0)
        os.dup2(null, 1)
        os.dup2(err, 2)
        os.setpgid(0, 0)
        try:
            code = importlib.import_module("tsog_stream.cli.main").main(argv)
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:  # a traceback escaped main: show it to the test
            traceback.print_exc()
            code = 99
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


def _idle_child_rss() -> int:
    """Peak RSS of a child that does nothing: what a fork costs before any work (file-backed
    pages the parent holds are not counted in a child until it touches them)."""
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    return os.wait4(pid, 0)[2].ru_maxrss * 1024


PARALLEL = 4
"""Children run at once: most wait (a server alive until its deadline, a refusal's exit), so
four share two cores without a deadline passing for want of CPU (the suite's time: 71 s of it
went to running them one by one)."""


class _Job:
    """One forked run: its deadline, its stderr file, and once ended what it did."""

    def __init__(self, run: dict[str, Any], stderr_path: str) -> None:
        self.stderr_path = stderr_path
        self.started = time.monotonic()
        self.pid = os.fork()
        if self.pid == 0:
            _child(run["argv"], run["cwd"], stderr_path)
        self.deadline = self.started + float(run.get("timeout_s", 60))
        self.timed_out = False

    def poll(self, base: int) -> dict[str, Any] | None:
        """What the child did once it ended (None while it runs); past its deadline it is
        sent SIGTERM, 5 s later SIGKILL."""
        done, status, usage = os.wait4(self.pid, os.WNOHANG)
        if not done:
            if time.monotonic() > self.deadline and not self.timed_out:
                self.timed_out = True
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.pid, signal.SIGTERM)
                self.deadline += 5
            elif self.timed_out and time.monotonic() > self.deadline:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.pid, signal.SIGKILL)
            return None
        with open(self.stderr_path, errors="replace") as f:
            stderr = f.read()
        return {
            "code": os.waitstatus_to_exitcode(status),
            "stderr": stderr[-4000:],
            "rss_growth": usage.ru_maxrss * 1024 - base,
            "seconds": time.monotonic() - self.started,
            "timed_out": self.timed_out,
        }


def _run_all(runs: list[dict[str, Any]], scratch: str, base: int) -> list[dict[str, Any]]:
    """Every run, at most PARALLEL at once, results in the runs' order."""
    results: list[dict[str, Any] | None] = [None] * len(runs)
    waiting = list(enumerate(runs))
    active: dict[int, _Job] = {}
    while waiting or active:
        while waiting and len(active) < PARALLEL:
            i, run = waiting.pop(0)
            active[i] = _Job(run, os.path.join(scratch, f"stderr-{i}.txt"))
        for i, job in list(active.items()):
            outcome = job.poll(base)
            if outcome is not None:
                results[i] = outcome
                del active[i]
        time.sleep(0.01)
    return [r for r in results if r is not None]


def main() -> None:
    """Read the runs from stdin, write their results to stdout."""
    runs = json.load(sys.stdin)
    for name in PRELOADED:
        importlib.import_module(name)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    base = _idle_child_rss()
    with tempfile.TemporaryDirectory(prefix="stderr-") as scratch:
        json.dump(_run_all(runs, scratch, base), sys.stdout)


if __name__ == "__main__":
    main()

"""Run ``tsog`` command lines in forked children and report each one's exit, stderr and peak RSS.

Used by tests/test_cli_hostile.py: ``python tests/cli_probe.py < runs.json > results.json``.
The parent imports every module a command may load, then forks one child per run, so a
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


def _run(run: dict[str, Any], scratch: str, base: int) -> dict[str, Any]:
    """Fork, wait with a deadline, and collect what the child did."""
    stderr_path = os.path.join(scratch, "stderr.txt")
    started = time.monotonic()
    pid = os.fork()
    if pid == 0:
        _child(run["argv"], run["cwd"], stderr_path)
    deadline = started + float(run.get("timeout_s", 60))
    timed_out = False
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline and not timed_out:
            timed_out = True
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGTERM)
            deadline += 5
        elif timed_out and time.monotonic() > deadline:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
        time.sleep(0.01)
    with open(stderr_path, errors="replace") as f:
        stderr = f.read()
    return {
        "code": os.waitstatus_to_exitcode(status),
        "stderr": stderr[-4000:],
        "rss_growth": usage.ru_maxrss * 1024 - base,
        "seconds": time.monotonic() - started,
        "timed_out": timed_out,
    }


def main() -> None:
    """Read the runs from stdin, write their results to stdout."""
    runs = json.load(sys.stdin)
    for name in PRELOADED:
        importlib.import_module(name)
    scratch = os.environ.get("TMPDIR", "/tmp")
    scratch = os.path.join(scratch, f"cli-probe-{os.getpid()}")
    os.makedirs(scratch, exist_ok=True)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    base = _idle_child_rss()
    json.dump([_run(run, scratch, base) for run in runs], sys.stdout)


if __name__ == "__main__":
    main()

"""Shared by the benchmark scripts: measured child processes and docs/benchmarks.md sections."""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tsog_stream.model import Gaussians, TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "benchmarks.md"
IN_TREE = REPO / "tests" / "data" / "real"
SPLAT_TRANSFORM = REPO / "node_modules" / ".bin" / "splat-transform"
"""The reference SOG codec (npm ``@playcanvas/splat-transform``, installed by scripts/setup)."""
SAMPLE_DATA_ENV = "TSOG_SAMPLE_DATA"
ALTI = "3dgs/gsplat_pr176_alti_splatfacto.npz"
"""gsplat's splatfacto output of the alti scene: 22589 trained Gaussians with three SH bands."""


def sample(rel: str, *, in_tree: bool = True) -> Path:
    """A real sample by its path in the sample layout (``4d/splatv/x.splatv``): from
    ``$TSOG_SAMPLE_DATA``, else ``../shared/data``, else (``in_tree``: the repository carries
    it whole) ``tests/data/real``. Exits with a message saying how to provide it otherwise."""
    chosen = os.environ.get(SAMPLE_DATA_ENV)
    roots = ([Path(chosen)] if chosen else []) + [REPO.parent / "shared" / "data"]
    roots += [IN_TREE] if in_tree else []
    for root in roots:
        if (root / rel).exists():
            return root / rel
    raise SystemExit(
        f"benchmark sample {rel} not found: set {SAMPLE_DATA_ENV}=/path/to/data (the layout of "
        "../shared/data, see its PROVENANCE.md) or put shared/data beside the checkout"
    )


def alti_gaussians() -> Gaussians:
    """The alti capture's Gaussians (an npz no reader takes: gsplat's arrays by name)."""
    data = np.load(sample(ALTI, in_tree=False))
    return Gaussians.from_arrays(
        data["means3d"],
        data["scales"],
        data["quats"],
        data["opacities"].reshape(-1),
        data["colors"],
        shN=data["features_rest"],
    )


def write_section(name: str, body: str, script: str) -> None:
    """Replace (or append) the section ``name``, keeping every other section as it is."""
    begin, end = f"<!-- {name}:begin", f"<!-- {name}:end -->"
    section = f"{begin} (written by benchmarks/{script}) -->\n{body}{end}\n"
    text = DOC.read_text() if DOC.exists() else "# Benchmarks\n\n"
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + section + rest.split(end, 1)[1].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + section
    DOC.write_text(text)


def run_measured(cmd: list[str], timeout: float = 3600) -> dict[str, Any]:
    """Run ``cmd``: wall seconds, peak RSS (MiB: the largest VmHWM of the process and of every
    process below it, sampled every 20 ms) and whether it finished in time; stderr goes to a
    temp file, so a chatty child never blocks on a pipe.

    Not ``ru_maxrss`` from ``wait4``: Linux carries the forked parent's high-water mark through
    ``exec``, so every child of a large benchmark process reported the benchmark's own size."""
    start = time.monotonic()
    peaks: dict[int, int] = {}
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        deadline = start + timeout
        while True:
            _sample_hwm(proc.pid, peaks)
            pid, status, _ = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                proc.kill()
                os.wait4(proc.pid, 0)
                return {"finished": False, "seconds": round(timeout, 1)}
            time.sleep(0.02)
        ok = os.waitstatus_to_exitcode(status) == 0
        out: dict[str, Any] = {
            "finished": ok,
            "seconds": round(time.monotonic() - start, 2),
            "peak_mib": round(max(peaks.values(), default=0) / 1024, 1),
        }
        if not ok:
            err.seek(0)
            out["error"] = err.read().decode(errors="replace")[-500:]
    return out


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (worker processes), from /proc."""
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(x) for x in (task / "children").read_text().split()]
    return out


def status_kib(pid: int, field: str) -> int:
    """A kB field of /proc/PID/status (VmRSS, VmHWM), 0 when absent."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1])
    return 0


def _sample_hwm(pid: int, peaks: dict[int, int]) -> None:
    """Record the VmHWM (kB) of ``pid`` and every live process below it into ``peaks``."""
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            peaks[p] = max(peaks.get(p, 0), status_kib(p, "VmHWM"))
            todo += children(p)
        except OSError:
            continue  # gone between two looks


def segmented_clip(
    path: Path, *, background: int, objects: int, per_object: int, seed: int
) -> Path:
    """A synthetic 8 s type-2 scene (SH0) segmented into a .tsogs at ``path`` (1 s windows)."""
    spec = SceneSpec(
        timeline_type=TimelineType.CENTER_SCALE,
        background=background,
        objects=objects,
        per_object=per_object,
        duration=8.0,
        sh_bands=0,
        seed=seed,
    )
    segment_scene(generate_scene(spec), path, SegmentOptions(window_s=1.0, workers=2))
    return path


WRK_DONE = """
function done(summary, latency, requests)
  io.write(string.format(
    '{"requests": %d, "duration_us": %d, "bytes": %d, "p50_us": %d, "p99_us": %d, '
    .. '"max_us": %d, "connect": %d, "read": %d, "write": %d, "status": %d, "timeout": %d}\\n',
    summary.requests, summary.duration, summary.bytes, latency:percentile(50),
    latency:percentile(99), latency.max, summary.errors.connect, summary.errors.read,
    summary.errors.write, summary.errors.status, summary.errors.timeout))
end
"""
"""The end of every wrk script: its summary as one JSON line (read by run_wrk)."""


def run_wrk(
    url: str, script: Path, clients: int, seconds: float, threads: int = 2
) -> dict[str, Any]:
    """wrk -tTHREADS -cCLIENTS -dSECONDS with ``script`` (ending in WRK_DONE): requests/s,
    MB/s, latency percentiles and errors by kind."""
    cmd = ["wrk", f"-t{threads}", f"-c{clients}", f"-d{seconds:g}s", "--timeout", "10s", "-s"]
    out = subprocess.run(
        [*cmd, str(script), url], check=False, capture_output=True, text=True, timeout=seconds + 60
    )
    line = [x for x in out.stdout.splitlines() if x.startswith('{"requests"')]
    if out.returncode != 0 or not line:
        raise SystemExit(f"wrk failed: {out.stdout[-500:]} {out.stderr[-500:]}")
    raw = json.loads(line[0])
    kinds = ("connect", "read", "write", "status", "timeout")
    return {
        "requests": raw["requests"],
        "rps": raw["requests"] / (raw["duration_us"] / 1e6),
        "mb_s": raw["bytes"] / (raw["duration_us"] / 1e6) / 1e6,
        "p50_ms": raw["p50_us"] / 1000,
        "p99_ms": raw["p99_us"] / 1000,
        "max_ms": raw["max_us"] / 1000,
        "errors": sum(raw[k] for k in kinds),
        "error_kinds": {k: raw[k] for k in kinds},
    }

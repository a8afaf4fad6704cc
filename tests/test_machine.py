"""What a process may use: cores (affinity, a container's CPU quota) and memory (MemAvailable,
a container's limit), read from the kernel's files (here, files written like them)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tsog_stream import machine


def test_memory_available_reads_the_kernel_and_a_container_limit(tmp_path: Path) -> None:
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:  32000000 kB\nMemFree:  100 kB\nMemAvailable:  2048 kB\n")
    assert machine.meminfo_available(str(meminfo)) == 2048 * 1024
    meminfo.write_text("MemTotal:  32000000 kB\n")  # a kernel before 3.14 has none
    assert machine.meminfo_available(str(meminfo)) is None
    assert machine.meminfo_available(str(tmp_path / "none")) is None
    limit, used = tmp_path / "memory.max", tmp_path / "memory.current"
    used.write_text("1000\n")
    for text, room in [
        ("5000\n", 4000),
        ("500\n", 0),
        ("max\n", None),
        (f"{2**63 - 4096}\n", None),
    ]:
        limit.write_text(text)  # v2 "max" and v1's near-2^63 both mean no limit
        assert machine.room_under(str(limit), str(used)) == room
    limit.write_text("garbage\n")
    assert machine.room_under(str(limit), str(used)) is None
    assert machine.room_under(str(tmp_path / "no"), str(used)) is None
    found = machine.available_memory()
    assert found is None or found > 0  # this machine's: read, not assumed


def test_a_cpu_quota_counts_whole_cores_rounded_up(tmp_path: Path) -> None:
    v2 = tmp_path / "cpu.max"
    for text, cores in [("200000 100000\n", 2), ("150000 100000\n", 2), ("50000 100000\n", 1)]:
        v2.write_text(text)
        assert machine.cpu_quota(str(v2), None) == cores
    v2.write_text("max 100000\n")
    assert machine.cpu_quota(str(v2), None) is None
    quota, period = tmp_path / "cpu.cfs_quota_us", tmp_path / "cpu.cfs_period_us"
    period.write_text("100000\n")
    quota.write_text("400000\n")
    assert machine.cpu_quota(str(quota), str(period)) == 4
    quota.write_text("-1\n")  # v1: no quota
    assert machine.cpu_quota(str(quota), str(period)) is None
    period.write_text("0\n")
    quota.write_text("400000\n")
    assert machine.cpu_quota(str(quota), str(period)) is None
    assert machine.cpu_quota(str(tmp_path / "none"), None) is None


PINNED = """
import os, sys
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from tsog_stream.machine import usable_cores
from tsog_stream.segment.engines import default_workers
print(usable_cores(), default_workers())
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this OS")
def test_a_process_pinned_to_one_core_counts_one_core_and_starts_one_worker() -> None:
    """Thread pools and ``tsog segment``'s default workers follow the cores a process may use
    (taskset, a cpuset), not the machine's: the machine's count oversubscribed a pinned one."""
    done = subprocess.run(
        [sys.executable, "-c", PINNED], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.split() == ["1", "1"]
    assert 1 <= machine.usable_cores() <= len(os.sched_getaffinity(0))

"""What this machine lets a process use: cores and memory, as the kernel and a container's
limits (cgroup v2, then v1) say. Thread pools and default worker counts are sized by these, not
by the machine's totals, which a pinned or limited process would oversubscribe."""

from __future__ import annotations

import contextlib
import math
import os
from typing import Final

CPU_QUOTAS: Final = (
    ("/sys/fs/cgroup/cpu.max", None),
    ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu/cpu.cfs_period_us"),
)
"""A container's CPU quota: v2's "quota period" in one file ("max" for none), v1's quota (-1
for none) and period in two."""
MEMORY_LIMITS: Final = (
    ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
    ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
)
"""A container's memory limit and use (v2, then v1), where the machine's free memory would
overstate what this process may take."""
MEMINFO: Final = "/proc/meminfo"
UNLIMITED: Final = 1 << 60
"""Limits at or above this mean none (cgroup v1 writes "unlimited" as about 2^63)."""


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity (what ``taskset``, a cpuset or a
    batch scheduler left it), fewer under a container's CPU quota (``docker --cpus 2``: two,
    rounded up), the machine's core count where the system cannot say (as on macOS)."""
    affinity = getattr(os, "sched_getaffinity", None)
    cores = len(affinity(0)) if affinity is not None else os.cpu_count() or 1
    quotas = [q for paths in CPU_QUOTAS if (q := cpu_quota(*paths)) is not None]
    return max(1, min([cores, *quotas]))


def cpu_quota(quota_path: str, period_path: str | None) -> int | None:
    """Whole cores a cgroup's CPU quota allows, rounded up (None: no quota, or unreadable)."""
    with contextlib.suppress(OSError, ValueError, ZeroDivisionError):
        fields = _read(quota_path).split()
        if period_path is not None:
            fields = [fields[0], _read(period_path)]
        if fields[0] == "max" or int(fields[0]) <= 0:
            return None
        return max(1, math.ceil(int(fields[0]) / int(fields[1])))
    return None


def available_memory() -> int | None:
    """Bytes this process may still take: the kernel's estimate of memory available without
    swapping (Linux's MemAvailable), lowered by a container's limit; None where neither can
    be read."""
    found = [meminfo_available(MEMINFO), *(room_under(*paths) for paths in MEMORY_LIMITS)]
    known = [value for value in found if value is not None]
    return min(known) if known else None


def meminfo_available(path: str) -> int | None:
    """MemAvailable of a /proc/meminfo in bytes (None without it)."""
    with contextlib.suppress(OSError, ValueError):
        for line in _read(path).splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return None


def room_under(limit_path: str, used_path: str) -> int | None:
    """A cgroup's memory limit minus its use (None when unlimited or unreadable)."""
    with contextlib.suppress(OSError, ValueError):
        limit = _read(limit_path)
        if limit == "max" or int(limit) >= UNLIMITED:
            return None
        return max(0, int(limit) - int(_read(used_path)))
    return None


def _read(path: str) -> str:
    """A small system file's text, stripped (at most 64 KiB: these are a line or a page)."""
    with open(path, encoding="ascii") as file:
        return file.read(1 << 16).strip()

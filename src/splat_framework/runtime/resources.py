"""What the machine has right now: cores, memory, other processes' load.

A leaf module (standard library only), shared by the trainer's memory plan,
the sweep's worker count and the rasterizer's thread policy. Linux sources
(``/proc``, cgroups) first, portable ``os.sysconf`` fallbacks; every probe
returns None where it cannot tell.
"""

from __future__ import annotations

import os
from pathlib import Path


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def cgroup_memory_limit() -> int | None:
    """The cgroup (v2 or v1) memory limit of this process in bytes, or None when unlimited or unknown."""
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(path).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 2**60:
            return int(text)
    return None


def physical_memory_bytes() -> int | None:
    """Total RAM this process may use (physical pages, capped by a cgroup limit), or None."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None
    limit = cgroup_memory_limit()
    return min(total, limit) if limit else total


def available_memory_bytes() -> int | None:
    """RAM available to new allocations (psutil if installed, MemAvailable, else SC_AVPHYS_PAGES), or None."""
    try:
        import psutil  # optional

        return int(psutil.virtual_memory().available)
    except Exception:
        pass
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def others_running() -> int | None:
    """Runnable threads of other processes right now (None if unknown).

    /proc/loadavg's 4th field counts all runnable threads, including this
    process's; those are subtracted using /proc/self/task/*/stat."""
    try:
        with open("/proc/loadavg") as f:
            running = int(f.read().split()[3].split("/")[0])
        own = 0
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/stat") as f:
                    st = f.read()
            except OSError:
                continue
            if st[st.rindex(")") + 2] == "R":
                own += 1
        return max(running - own, 0)
    except (OSError, ValueError, IndexError):
        return None

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


class CpuMeter:
    """How many cores other processes kept busy between two readings, averaged over the interval.

    Linux ``/proc/stat`` (busy and total time of the CPUs this process may run on, steal time
    counted as busy) minus this process's own CPU time (``os.times``): unlike the runnable threads
    at one instant (:func:`others_running`), a reading is not thrown by a thread that happened to be
    asleep or awake at the moment it was taken."""

    def __init__(self) -> None:
        self.last: tuple[float, float, float] | None = None  # (busy s, wall s, own s)

    def read(self) -> float | None:
        """Cores busy elsewhere since the previous call (None on the first call or where unknown)."""
        sample = _cpu_sample()
        last, self.last = self.last, sample
        if sample is None or last is None:
            return None
        wall = sample[1] - last[1]
        if wall <= 0:
            return None
        return max(0.0, ((sample[0] - last[0]) - (sample[2] - last[2])) / wall)


def _cpu_sample() -> tuple[float, float, float] | None:
    """(busy seconds summed over this process's CPUs, wall seconds, this process's CPU seconds)."""
    try:
        cpus = os.sched_getaffinity(0)
        tick = os.sysconf("SC_CLK_TCK")
        busy = total = 0
        with open("/proc/stat") as f:
            for line in f:
                name, *fields = line.split()
                if not name.startswith("cpu") or name == "cpu" or int(name[3:]) not in cpus:
                    continue
                user, nice, system, idle, iowait, irq, softirq, steal = (int(v) for v in fields[:8])
                busy += user + nice + system + irq + softirq + steal
                total += user + nice + system + idle + iowait + irq + softirq + steal
    except (OSError, ValueError, AttributeError):
        return None
    if not total:
        return None
    own = os.times()
    return busy / tick, total / tick / len(cpus), own.user + own.system

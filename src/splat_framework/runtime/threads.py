"""One CPU thread policy for the whole process: how many threads, and how they wait.

On a CPU shared with other busy processes, a parallel region with more threads
than free cores waits for its descheduled thread at every barrier, and the
rasterizer, the losses and the optimizer run hundreds of small regions per step.
The policy decides for every phase at once (data loading, matching, the
warm-up, training, evaluation, rendering), because every phase runs through
the same OpenMP pool (torch, the compiled kernels) and OpenCV's pool:

``SPLAT_THREADS``
    "auto" (default): follow the cores that are free. A run starts with the
    cores free at that instant (the runnable threads of other processes);
    then :func:`follow_load`, called from every phase's progress (training
    steps, matched pairs, warm-up iterations) and every CPU render, reads at
    most once a second how many cores other processes kept busy since the
    last reading (Linux ``/proc/stat`` minus this process's own CPU time) and
    sets torch's and OpenCV's thread count to the free cores (rounded to the
    nearest whole core, then down to a power of two), at least 1, at most the
    count the run started with. A change needs two readings in a row that
    agree, so a burst elsewhere does not flip the count, and each count
    has its own compiled kernel graph (saved once per machine,
    :mod:`splat_framework.render.precompiled`): at most log2(cores)+1 of them.
    An integer pins that many threads for the whole process.
    "off" never touches the thread count.

Matching is the one exception: its result depends on the thread count and is cached for every later
run, so it runs on the machine's cores whatever the load or the pin (:func:`machine_threads`).

OpenMP's wait policy is left at its default (spin a few milliseconds, then
sleep): measured, ``OMP_WAIT_POLICY=PASSIVE`` made a training step 24 % slower
on idle cores and gained nothing once the count follows the load; it only
helps a count pinned above the free cores (``docs/decisions.md``).
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager

from ..environment import threads_setting
from .resources import CpuMeter, available_cores, others_running

#: Seconds between two readings of the machine's load.
READ_EVERY_S = 1.0


def mode() -> int | str:
    """``SPLAT_THREADS``: a whole number >= 1, "auto" (when unset) or "off"; one line (DataError) else."""
    return threads_setting(os.environ.get("SPLAT_THREADS"))


def free_cores(most: int, others: float | None) -> int | None:
    """Threads to run when other processes keep ``others`` cores busy: a power of two in [1, most]."""
    if others is None:
        return None
    n = max(1, min(most, round(available_cores() - others)))
    return 1 << (n.bit_length() - 1) if n < most else n


class ThreadPolicy:
    """The process's thread count: pinned by ``SPLAT_THREADS=N`` or following the free cores."""

    def __init__(self) -> None:
        self.most: int | None = None  # the ceiling: torch's count when a run started (OMP_NUM_THREADS, a sweep's)
        self.applied: int | None = None  # the count this policy set last
        self.pending: int | None = None  # a new count seen once, applied when seen again
        self.next_read = 0.0
        self.changes = 0
        self.used: set[int] = set()  # every count the process ran with since the policy started
        self.meter = CpuMeter()
        self.held = 0  # > 0 inside machine_threads(): the load is not followed

    def start(self) -> int | None:
        """Apply a pinned count, or remember the ceiling for "auto"; returns the pinned count (else None)."""
        import torch

        value = mode()
        if isinstance(value, int):
            self._set(value)
            self.used = {value}
            return value
        current = torch.get_num_threads()
        if self.most is None or current != self.applied:  # set by someone else since: the new ceiling
            self.most = current
        if value == "auto":  # the free cores now, before any kernel is loaded for a thread count
            start = free_cores(self.most, others_running())
            if start is not None:
                self._set(start)
            self.meter.read()
            self.next_read, self.pending = time.monotonic() + READ_EVERY_S, None
        self.used = {torch.get_num_threads()}
        return None

    def follow(self, now: float | None = None) -> int | None:
        """Under "auto", re-read the load (at most every READ_EVERY_S) and apply the count; returns a new count.

        Under any mode but "off", OpenCV's pool is also brought to torch's count (a phase may load
        OpenCV after the count was set)."""
        value = mode()
        if value == "off" or self.held:
            return None
        now = time.monotonic() if now is None else now
        if now < self.next_read:
            return None
        self.next_read = now + READ_EVERY_S
        torch = sys.modules.get("torch")
        if torch is None:  # a torch-free command (or phase): nothing to follow, nothing to import
            return None
        _match_opencv(torch.get_num_threads())
        if value != "auto":
            return None
        if self.most is None:
            self.most = torch.get_num_threads()
        want = free_cores(self.most, self.meter.read())
        if want is None or want == torch.get_num_threads():
            self.pending = None
            return None
        if self.pending != want:  # seen once: wait for a second reading
            self.pending = want
            return None
        self.pending = None
        self._set(want)
        return want

    def _set(self, n: int) -> None:
        import torch

        _match_opencv(n)
        if n == torch.get_num_threads():
            return
        torch.set_num_threads(n)
        self.applied = n
        self.changes += 1
        self.used.add(n)

    def record(self) -> dict:
        """What a run's metrics.json keeps of its threads: the setting, every count used (under "auto"
        they follow the load), the gradient slots of the native compositing, which, not the
        thread count, fix the order of its sums (one per core the process may use), and the count
        the matches are computed on (:func:`machine_thread_count`): the last bits of the learned
        matches, so the prior and the scores, depend on it (docs/results.md)."""
        setting = mode()
        return {"setting": str(setting), "counts": sorted(self.used), "gradient_slots": available_cores(),
                "matching": machine_thread_count()}


def _match_opencv(n: int) -> None:
    """OpenCV's own pool to ``n`` threads, when a phase has loaded OpenCV."""
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and cv2.getNumThreads() != n:
        cv2.setNumThreads(n)


POLICY = ThreadPolicy()


def machine_thread_count() -> int:
    """The thread count of :func:`machine_threads`: the cores this process may run on, or torch's
    count as it is under ``SPLAT_THREADS=off``."""
    if mode() == "off":
        import torch

        return torch.get_num_threads()
    return available_cores()


@contextmanager
def machine_threads():
    """Run the block on :func:`machine_thread_count` threads (torch's and OpenCV's), whatever the load
    or a pinned ``SPLAT_THREADS``, the load not followed inside; the count before is restored after.

    For work whose result depends on the thread count and is cached for every later run, the matches:
    torch's matrix products split their sums by thread, so the same photos gave other matches on 1
    thread than on 2 (fern: 36,433 against 36,438 raw matches of a pair, then other ones among the
    12,000 kept; test PSNR 22.77 against 22.65), and which of them a run trained on depended on the
    load when the first run computed them. On one machine they are now the same bits alone, beside
    other work, pinned or not (the match cache's key holds the count). Yields the count."""
    import torch

    n, before = machine_thread_count(), torch.get_num_threads()
    if mode() == "off":  # "off" never touches the thread count
        yield n
        return
    POLICY.held += 1
    try:
        torch.set_num_threads(n)
        _match_opencv(n)
        yield n
    finally:
        POLICY.held -= 1
        torch.set_num_threads(before)
        _match_opencv(before)


def apply_process_threads() -> int | None:
    """Start the process's thread policy; returns the pinned count under ``SPLAT_THREADS=N`` (else None)."""
    return POLICY.start()


def threads_record() -> dict:
    """The threads of this process's run, for metrics.json (see :meth:`ThreadPolicy.record`)."""
    return POLICY.record()


def follow_load() -> int | None:
    """Follow the machine's load (cheap: reads ``/proc`` at most once a second); returns a new count or None."""
    return POLICY.follow()

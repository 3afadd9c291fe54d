"""Named timing sections for profiling whole training steps (off unless a benchmark turns them on).

The trainer and the rasterizer mark their phases with ``section("name")``.
While profiling is off (the default) a section is a no-op context manager; while
it is on (:func:`profiling`), each section adds its wall time to a total keyed by
its path of nested names ("step/forward/projection") and appears in
``torch.profiler`` traces under the same name. On CUDA the device is
synchronised at both ends of a section, so its time is the device's; that
changes the timing of asynchronous work, which is why it is only done while
profiling.

Usage (``benchmarks/train_step.py``)::

    with profiling(device) as times:
        for _ in range(10):
            trainer.train_step(step)
    times  # {"step": 1.93, "step/forward": 0.71, "step/forward/projection": 0.05, ...} seconds
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator

import torch

__all__ = ["exclusive", "profiling", "section", "synchronize"]

_state: dict = {"on": False, "stack": [], "totals": None, "counts": None, "device": None}


def synchronize(device: torch.device | None) -> None:
    """Wait for the device's queued kernels, so that a wall-clock time covers the work (no-op on CPU)."""
    if device is not None and device.type == "cuda":
        torch.cuda.synchronize(device)


def _sync() -> None:
    synchronize(_state["device"])


@contextmanager
def section(name: str) -> Iterator[None]:
    """Time the enclosed block as ``name`` (nested under the enclosing sections) while profiling is on."""
    if not _state["on"]:
        yield
        return
    stack = _state["stack"]
    stack.append(name)
    key = "/".join(stack)
    _sync()
    t0 = time.perf_counter()
    try:
        with torch.profiler.record_function(name):
            yield
    finally:
        _sync()
        _state["totals"][key] += time.perf_counter() - t0
        _state["counts"][key] += 1
        stack.pop()


@contextmanager
def profiling(device: torch.device | str | None = None) -> Iterator[dict[str, float]]:
    """Turn sections on; yields the dict of total seconds per section path (filled while it runs)."""
    if _state["on"]:
        raise RuntimeError("profiling is already on")
    totals: dict[str, float] = defaultdict(float)
    _state.update(on=True, stack=[], totals=totals, counts=defaultdict(int),
                  device=None if device is None else torch.device(device))
    try:
        yield totals
    finally:
        _state.update(on=False, stack=[], totals=None, counts=None, device=None)


def exclusive(totals: dict[str, float]) -> dict[str, float]:
    """Seconds spent in each section outside its child sections (the children's keys extend the parent's)."""
    out = dict(totals)
    for key, t in totals.items():
        parent = key.rpartition("/")[0]
        if parent in out:
            out[parent] -= t
    return out

"""CPU thread policy for the rasterizer.

On a CPU shared with other busy processes, OpenMP's spin-waiting makes every
parallel region wait for a descheduled sibling thread. The rasterizer runs
hundreds of medium-sized ops per call, so with 2 threads on 2 oversubscribed
cores it gets ~2.5x slower than with 1 thread (measured: 50k Gaussians at
504x378, fwd+bwd ~1.0 s with 2 threads vs 0.42 s with 1 thread at load ~5;
0.25 s vs 0.40 s on an idle machine).

``SPLAT_THREADS`` sets the number of torch threads used inside the rasterizer
on CPU:
    "auto" (default): min(torch's setting, CPUs - threads of other processes
        that are runnable right now), at least 1, rounded down to a power of
        two when below torch's setting (each thread count is a separate
        torch.compile specialisation of the kernels) (Linux /proc; elsewhere
        torch's setting);
    an integer: exactly that many, and for the whole training process too
        (:func:`apply_process_threads`: the warm-up, losses and optimizer run
        outside the rasterizer and spin-wait the same way);
    "off": never touch torch's setting.
The previous setting is restored when the rasterizer returns.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

import torch

from ..runtime.resources import others_running


def apply_process_threads() -> int | None:
    """Set torch's thread count for the process when ``SPLAT_THREADS`` is an integer; returns it (else None).

    Measured: two fern trainings sharing 2 cores with ``SPLAT_THREADS=1`` limiting only the
    rasterizer took 1043 s each (z warm-up 69 s); with one thread everywhere, 336 s (warm-up 4.8 s).
    """
    n = _mode()
    if not isinstance(n, int) or n < 1:
        return None
    torch.set_num_threads(n)
    return n


def _mode() -> int | str:
    """``SPLAT_THREADS``: an int, or the lower-cased word ("auto" when unset)."""
    mode = os.environ.get("SPLAT_THREADS", "auto").strip().lower()
    try:
        return int(mode)
    except ValueError:
        return mode


def choose_threads(device: torch.device) -> int | None:
    """Thread count to use inside the rasterizer, or None to leave torch's."""
    if device.type != "cpu":
        return None
    mode = _mode()
    if mode in ("off", "none", ""):
        return None
    cur = torch.get_num_threads()
    if isinstance(mode, int):
        return mode if mode > 0 and mode != cur else None
    if mode != "auto":
        return None
    if cur <= 1:
        return None
    others = others_running()
    if others is None:
        return None
    n = max(1, min(cur, (os.cpu_count() or cur) - others))
    if n < cur:  # a power of two: each count is a separate torch.compile specialisation
        n = 1 << (n.bit_length() - 1)
    return n if n != cur else None


@contextmanager
def thread_policy(device: torch.device):
    n = choose_threads(device)
    if n is None:
        yield
        return
    prev = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(prev)

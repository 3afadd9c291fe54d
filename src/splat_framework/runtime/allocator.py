"""How the C library's ``malloc`` keeps freed memory during a run: large blocks reused, not
returned to the system after every step.

A training step allocates and frees tensors of several MiB (images, per-tile buffers, the
compiled loss's and projection's intermediates). glibc serves each block above its mmap
threshold (dynamic, at most 32 MiB) with a fresh mapping and unmaps it on free, and trims the
heap's top whenever more than twice that threshold is free: each step then faults its big
tensors' pages in again, zero-filled by the kernel. :func:`keep_freed_memory` sets the mmap
threshold to glibc's largest (32 MiB) and the trim threshold to 1 GiB, so such blocks come from
the heap and are reused. Measured on the 2-core CPU (fern ``scgaussian`` snapshots, two processes
side by side on one thread each, so both see the same machine): a step 5-10 % shorter (at
iteration 1000: 201 against 211 ms and 182 against 201 ms; at 0: 272 against 296 ms), page
faults 630k -> 225k, system time halved. Whole default fern runs, alternated with runs that
leave ``malloc`` alone: 128 and 119 s against 153 and 138 s, the same metrics, peak memory
780-820 MB against 740-750 MB.

glibc only (Linux); elsewhere, or where the user has set ``MALLOC_*`` variables or
``GLIBC_TUNABLES``, nothing is changed.
"""

from __future__ import annotations

import ctypes
import os

#: ``mallopt`` parameters (glibc's malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: glibc's largest mmap threshold on 64-bit systems
MMAP_THRESHOLD = 32 * 2**20
TRIM_THRESHOLD = 2**30


def _user_tuned() -> bool:
    return any(k.startswith("MALLOC_") for k in os.environ) or "malloc" in os.environ.get("GLIBC_TUNABLES", "")


def keep_freed_memory(libc=None) -> bool:
    """Apply the thresholds above to this process (``libc``: the C library, for tests); True
    when they were set. Never raises."""
    if _user_tuned():
        return False
    try:
        libc = libc if libc is not None else ctypes.CDLL(None)
        if not hasattr(libc, "gnu_get_libc_version"):  # not glibc (musl, macOS): other allocators
            return False
        # the mmap threshold first: a trim threshold alone would also freeze the mmap threshold at
        # its 128 KiB start (measured: steps twice as long)
        return libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1 and libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
    except (OSError, AttributeError, TypeError):
        return False


__all__ = ["keep_freed_memory"]

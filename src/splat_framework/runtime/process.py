"""What a training process sets once, before its data loads: its CPU thread policy
(:mod:`.threads`) and its allocator's thresholds (:mod:`.allocator`)."""

from __future__ import annotations

from .allocator import keep_freed_memory
from .threads import apply_process_threads


def prepare_training_process() -> None:
    """The thread policy started (``SPLAT_THREADS``) and freed memory kept for reuse (glibc)."""
    apply_process_threads()
    keep_freed_memory()

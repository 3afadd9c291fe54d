"""Ctrl-C and SIGTERM during training: the first finishes the step and writes a checkpoint, a
second stops at once.

The first signal asks the loop to stop after the current step (``Trainer.request_stop``) and
says so in one line; the loop then writes the step's checkpoint and raises ``TrainingInterrupted``.
A second signal before that raises KeyboardInterrupt at once (a step can take long: the first
one compiles kernels), which the loop turns into a ``TrainingInterrupted`` whose message says what
was saved (:func:`abandoned_message`); while the checkpoint is being written, the write finishes
first. Both exit with code 130 in the CLIs. A stop during the final evaluation (outside the loop)
says the training is saved and how to score it (:func:`evaluation_stopped_message`).
"""

from __future__ import annotations

import signal
from contextlib import contextmanager
from pathlib import Path

from ..console import say
from .checkpoint import list_checkpoints


@contextmanager
def stop_signals(trainer):
    """Turn SIGINT/SIGTERM into a stop request the loop checks between steps (``trainer``: a
    ``Trainer``; its ``stop_reason``, ``request_stop`` and ``saving`` flag are used)."""

    def handler(signum, frame):
        name = signal.Signals(signum).name
        if trainer.stop_reason is None:
            trainer.request_stop(name)
            say(f"{name}: stopping after this step and writing a checkpoint "
                "(a second Ctrl-C or SIGTERM stops at once, without it)", "yellow")
        elif not trainer.saving:  # a checkpoint being written is never cut short
            raise KeyboardInterrupt

    sigs = (signal.SIGINT, signal.SIGTERM)
    old = {}
    try:
        for s in sigs:
            old[s] = signal.signal(s, handler)
    except ValueError:  # not in the main thread: no handlers
        pass
    try:
        yield
    finally:
        for s, h in old.items():
            try:
                signal.signal(s, h)
            except ValueError:
                pass


def abandoned_message(reason: str | None, step: int, total: int, checkpoint_dir: Path, hint: str) -> str:
    """The one-line message of a run stopped during step ``step`` without its checkpoint: what is on
    disk, then ``hint``, how to continue (``Trainer.continue_hint``)."""
    what = f"{reason} again" if reason else "interrupted"
    saved = list_checkpoints(checkpoint_dir)
    if saved:
        kept = f"the newest checkpoint is {saved[-1]}; {hint}"
    else:
        kept = f"nothing was saved (no checkpoint yet: resuming starts the run over); {hint}"
    return f"{what} during step {step + 1}/{total}: stopped at once, this step's checkpoint was not written; {kept}"


def evaluation_stopped_message(checkpoint_dir: Path, hint: str) -> str:
    """The one-line message of a run stopped (Ctrl-C, SIGTERM) during its final evaluation: the training
    is saved, what was not written, then ``hint``, how to continue (its ``--resume`` scores it again)."""
    saved = list_checkpoints(checkpoint_dir)
    done = f"training is done and saved in {saved[-1]}" if saved else "training is done"
    return f"interrupted during the evaluation: {done}; metrics.json was not written (renders/ may hold some views); {hint}"

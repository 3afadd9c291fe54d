"""Hidden work folders next to an output (``.<out name>.work-XXXXXXXX``), owned by one process.

A command that builds its output in a work folder beside it and moves it into place at
the end (splat-process, splat-scene) leaves that folder behind when it is killed
(``kill -9``, a power cut: no ``finally`` runs). Each work folder is therefore locked by
its process with the run-folder lock (:mod:`splat_framework.files.run_lock`: an exclusive
``flock`` on ``.splat.lock`` inside it, which the kernel drops when the process dies);
the next run for the same output removes every work folder of that output whose lock
nobody holds. A folder that is locked (a run in progress), has no lock file (not ours,
or not yet locked), or is a symlink is left alone. :func:`building` wraps the whole
cycle; :func:`scratch` is the same for intermediate files only. Torch-free.
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from . import run_lock


def _prefix(out: Path) -> str:
    return f".{Path(out).name}.work-"


def make_work_folder(out: Path) -> Path:
    """Create a fresh hidden work folder beside ``out`` (its parent must exist), locked by this process
    until :func:`run_lock.release` or its exit."""
    work = Path(tempfile.mkdtemp(prefix=_prefix(out), dir=Path(out).parent))
    run_lock.acquire(work)
    return work


def remove_stale_work_folders(out: Path) -> list[Path]:
    """Remove the work folders of ``out`` that hold a lock file nobody holds (their process died); return them.

    Only real folders (never a symlink) named ``.<out name>.work-*`` in ``out``'s parent are
    candidates; ``shutil.rmtree`` unlinks symlinks inside, never follows them."""
    parent, prefix = Path(out).parent, _prefix(out)
    removed = []
    try:
        entries = [e for e in os.scandir(parent) if e.name.startswith(prefix)]
    except OSError:
        return removed
    for entry in entries:
        work = Path(entry.path)
        try:
            ours = stat.S_ISDIR(os.lstat(work).st_mode) and stat.S_ISREG(os.lstat(work / run_lock.LOCK_NAME).st_mode)
        except OSError:
            continue
        if ours and run_lock.holder(work) is None and not run_lock.holds(work):
            shutil.rmtree(work, ignore_errors=True)
            removed.append(work)
    return removed


def remove_work_folder(work: Path) -> None:
    """Release this process's lock on ``work`` and remove it (the end of a run, successful or not)."""
    run_lock.release(work)
    shutil.rmtree(work, ignore_errors=True)


@contextmanager
def scratch(out: Path) -> Iterator[Path]:
    """A fresh work folder beside ``out`` for a run's intermediate files (yielded), removed at the
    end, success or not; after a crash (``kill -9``) the next :func:`scratch` or :func:`building` of
    the same output removes it (a temporary folder in /tmp would stay there)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_work_folders(out)
    work = make_work_folder(out)
    try:
        yield work
    finally:
        remove_work_folder(work)


@contextmanager
def building(out: Path, install: Callable[[Path, Path], object]) -> Iterator[Path]:
    """Build the folder ``out`` in a fresh work folder beside it (yielded), then ``install(work, out)``.

    ``install`` moves the finished folder into place (e.g. :func:`splat_framework.files.output_paths.install_output`,
    which renames it when ``out`` does not exist); the work folder then has the mode a new
    folder gets and no lock file. On any failure or interruption (Ctrl-C) the work folder is
    removed and ``out`` is untouched; after a crash (``kill -9``) the next :func:`building` of
    the same output removes it."""
    with scratch(out) as work:
        yield work
        run_lock.release(work)  # deletes the lock file: it is not part of the output
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(work, 0o777 & ~umask)  # a folder as mkdir makes it, not mkdtemp's private 0700
        install(work, out)

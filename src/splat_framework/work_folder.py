"""Hidden work folders next to an output (``.<out name>.work-XXXXXXXX``), owned by one process.

A command that builds its output in a work folder beside it and renames it into place
at the end (splat-process) leaves that folder behind when it is killed (``kill -9``, a
power cut: no ``finally`` runs). Each work folder therefore holds an owner file with
its process id and host; the next run for the same output removes every work folder of
that output whose owner, on this host, is no longer running. A folder whose owner is
alive (a run in progress), on another host, or that has no readable owner file, or is
a symlink, is left alone. :func:`building` wraps the whole cycle for a command that
writes a folder (splat-scene). Torch-free.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

OWNER_FILE = "splat-owner.json"
"""The file in a work folder naming its owner: ``{"pid": int, "host": str}``."""


def _prefix(out: Path) -> str:
    return f".{Path(out).name}.work-"


def make_work_folder(out: Path) -> Path:
    """Create a fresh hidden work folder beside ``out`` (its parent must exist), owned by this process."""
    work = Path(tempfile.mkdtemp(prefix=_prefix(out), dir=Path(out).parent))
    (work / OWNER_FILE).write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))
    return work


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True


def _owner_gone(work: Path) -> bool:
    """True when ``work``'s owner file names a process of this host that no longer runs."""
    try:
        owner = json.loads((work / OWNER_FILE).read_text())
        pid, host = int(owner["pid"]), str(owner["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return host == socket.gethostname() and pid > 0 and pid != os.getpid() and not _alive(pid)


def remove_stale_work_folders(out: Path) -> list[Path]:
    """Remove the work folders of ``out`` whose owner process is gone; return them.

    Only real folders (never a symlink) named ``.<out name>.work-*`` in ``out``'s parent with an
    owner file are candidates; ``shutil.rmtree`` unlinks symlinks inside, never follows them."""
    parent, prefix = Path(out).parent, _prefix(out)
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        if not entry.name.startswith(prefix):
            continue
        work = Path(entry.path)
        try:
            if not stat.S_ISDIR(os.lstat(work).st_mode) or not _owner_gone(work):
                continue
        except OSError:
            continue
        shutil.rmtree(work, ignore_errors=True)
        removed.append(work)
    return removed


@contextmanager
def building(out: Path, install: Callable[[Path, Path], object]) -> Iterator[Path]:
    """Build the folder ``out`` in a fresh work folder beside it (yielded), then ``install(work, out)``.

    ``install`` moves the finished folder into place (e.g. :func:`splat_framework.output_paths.install_output`,
    which renames it when ``out`` does not exist); the work folder then has the mode a new
    folder gets and no owner file. On any failure or interruption (Ctrl-C) the work folder is
    removed and ``out`` is untouched; after a crash (``kill -9``) the next :func:`building` of
    the same output removes it."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_work_folders(out)
    work = make_work_folder(out)
    try:
        yield work
        (work / OWNER_FILE).unlink()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(work, 0o777 & ~umask)  # a folder as mkdir makes it, not mkdtemp's private 0700
        install(work, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)

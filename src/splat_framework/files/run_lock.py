"""One process owns a run folder: an exclusive lock on ``RUN/.splat.lock``.

Every command that writes into a run folder takes the lock before anything else
and holds it until it is done:

- ``splat-train`` (a new run, ``--overwrite`` and ``--resume``): taken by
  ``run_folder.prepare_run_dir`` as the folder is created, before the data is
  loaded, and the folder's emptiness is checked again under it (two runs started
  0.3 s apart on the same ``--output``: the second is refused);
- ``splat-eval`` (rewrites ``metrics.json`` and ``renders/``), ``splat-render``
  and ``splat-export`` when their output lies inside the run folder (the
  defaults ``RUN/renders``, ``RUN/spiral.mp4``, ``RUN/point_cloud.ply``).

A second process gets :class:`RunFolderBusy` (a DataError: one line, exit 2)
naming the holder: its pid, host, command line and start time, which the holder
writes into the lock file (after its first byte, :data:`RECORD_AT`).

Pure readers take no lock: ``splat-view``, and ``splat-render``/``splat-export``
writing outside the run folder. Every file a run writes (checkpoints,
config.json, metrics.json) is replaced atomically and checksummed, so a reader
never sees half a file; and a shared lock would let a viewer left open for hours
block ``--resume``, or a render of a running run's newest checkpoint refuse.

The lock is the operating system's, taken on the open descriptor through
``filelock.lock_descriptor`` (``flock`` on Linux and macOS, ``LockFileEx`` on byte 0
on Windows); nothing here needs ``fcntl``, ``os.pread`` or Unix-only open flags.
Stale locks cannot block: the system drops the lock when its process dies
(kill -9, power cut on a local disk), so a lock file left behind is just a file.
The holder deletes the file when it releases the lock (where the system lets it:
Windows keeps an open file, and the next owner locks it again); an acquirer checks
that the file it locked is still the one at the path (same file id), else retries,
so no two processes can both believe they own the folder. The lock belongs to the
process: acquiring a folder it already holds returns the same lock (several
``Trainer`` objects of one test on one folder).

Tested where: Linux runs every test; the paths of a platform without ``fcntl``,
``os.pread`` and the Unix open flags, and one that cannot delete an open file
(Windows), are simulated in ``tests/framework/test_run_ownership.py``.
"""

from __future__ import annotations

import errno
import os
import socket
import stat
import sys
import time
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import Iterator

from ..errors import DataError

LOCK_NAME = ".splat.lock"
"""The lock file inside a run folder (ignored when a folder's emptiness is judged)."""

RECORD_AT = 1
"""Offset of the holder's record in the lock file: Windows locks byte 0, and its locks also bar
other processes from reading the bytes they cover."""

_HOLDER_WAIT_S = 0.5
"""How long a refused process waits for the holder to finish writing its identity."""

_held: dict[Path, "RunLock"] = {}
"""Locks this process holds, by resolved run folder."""


class RunFolderBusy(DataError):
    """Another process holds the run folder's lock (exit 2, one line naming it)."""


def command_line() -> str:
    """This process's command as a user typed it: ``splat-train 3dgs --data ...`` (a module run with
    ``python -m splat_framework.cli.train`` is named after its console script)."""
    argv = list(sys.argv) or ["python"]
    first = Path(argv[0])
    if first.parent.name == "cli" and first.parent.parent.name == "splat_framework":
        argv[0] = f"splat-{first.stem}"
    else:
        argv[0] = first.name or "python"
    line = " ".join(argv)
    return line if len(line) <= 300 else line[:297] + "..."


class RunLock:
    """An exclusive lock on one run folder, held through an open file descriptor."""

    def __init__(self, folder: Path, fd: int) -> None:
        self.folder = folder
        self.path = folder / LOCK_NAME
        self.pid = os.getpid()
        self._fd: int | None = fd

    @property
    def held(self) -> bool:
        """Whether this process still holds the lock on the file at :attr:`path` (not a forked
        child's inherited copy, nor a file someone deleted or replaced)."""
        return self._fd is not None and self.pid == os.getpid() and _same_file(self._fd, self.path)

    def release(self) -> None:
        """Delete the lock file (while still holding it) and drop the lock; idempotent."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        if _held.get(self.folder) is self:
            del _held[self.folder]
        if self.pid != os.getpid():
            return  # a forked child: the descriptor and the lock are the parent's
        try:
            if _same_file(fd, self.path):
                self.path.unlink()
        except OSError:
            pass
        finally:
            os.close(fd)  # closing the descriptor drops the flock


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)


def _read_holder(fd: int) -> str:
    """The identity the holder wrote into the lock file ("" while it has not yet)."""
    deadline = time.monotonic() + _HOLDER_WAIT_S
    while True:
        os.lseek(fd, RECORD_AT, os.SEEK_SET)
        text = os.read(fd, 4096).decode("utf-8", "replace").strip()
        if text or time.monotonic() > deadline:
            return " ".join(text.split())
        time.sleep(0.02)


def _open_flags() -> int:
    """Flags of every open of the lock file: a symlink or a FIFO planted at its name is never
    followed nor waited on, where the platform has the flags (Windows has neither, nor FIFOs;
    a symlink there is refused by :func:`_open` before opening)."""
    return getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)


def _open(path: Path, flags: int) -> int:
    """A descriptor of the lock file at ``path``; OSError (ELOOP) for a symlink in its place."""
    if not getattr(os, "O_NOFOLLOW", 0) and path.is_symlink():
        raise OSError(errno.ELOOP, "a symlink is in its place")
    return os.open(path, flags | _open_flags(), 0o600)


def _try_lock(fd: int) -> bool:
    """Take the exclusive lock of ``fd``'s file without waiting; False when another process has it."""
    from filelock import lock_descriptor

    return lock_descriptor(fd, blocking=False)


def acquire(folder: Path) -> RunLock:
    """Take the exclusive lock of the existing folder ``folder`` for this process.

    Raises :class:`RunFolderBusy` naming the holder when another process has it, and
    DataError when the lock file cannot be made (a symlink in its place, a read-only folder).
    """
    folder = Path(folder)
    key = folder.resolve()
    mine = _held.pop(key, None)
    if mine is not None:
        if mine.held:
            _held[key] = mine
            return mine
        if mine.pid == os.getpid() and mine._fd is not None:  # its file was deleted or replaced
            os.close(mine._fd)
        # a forked child's copy: the parent's descriptor, left open for the parent
    path = key / LOCK_NAME
    while True:
        try:
            fd = _open(path, os.O_RDWR | os.O_CREAT)
        except OSError as e:
            why = "a symlink is in its place" if e.errno == errno.ELOOP else (e.strerror or str(e))
            raise DataError(f"{path}: cannot create the run folder's lock file ({why})") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise DataError(f"{path}: not a regular file, so it cannot be the run folder's lock file")
        if not _try_lock(fd):
            who = _read_holder(fd) or "identity not written yet"
            os.close(fd)
            raise busy(folder, who)
        if _same_file(fd, path):
            break
        os.close(fd)  # the holder we waited on deleted that file as it released: lock the new one
    stamp = datetime.now().isoformat(timespec="seconds")
    record = f"pid {os.getpid()} on {socket.gethostname()}, started {stamp}: {command_line()}\n"
    lock = _held[key] = RunLock(key, fd)
    try:
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, b"\n" + record.encode("utf-8", "replace"))  # the record at RECORD_AT
    except OSError:  # a full disk: report it (one line in the CLIs), holding nothing
        lock.release()
        raise
    return lock


def holder(folder: Path) -> str | None:
    """The identity of the other process holding ``folder``'s lock, None when none does (or this one).
    Creates nothing (a free lock is taken for an instant, and dropped with the descriptor)."""
    if holds(folder):
        return None
    try:
        fd = _open(Path(folder) / LOCK_NAME, os.O_RDONLY)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode) or _try_lock(fd):
            return None
        return _read_holder(fd) or "identity not written yet"
    finally:
        os.close(fd)


def busy(folder: Path, who: str) -> RunFolderBusy:
    """The one-line refusal of a folder that process ``who`` holds."""
    return RunFolderBusy(f"{folder}: run folder is in use by another process ({who}); wait for it to finish or stop it")


def holds(folder: Path) -> bool:
    """Whether this process holds ``folder``'s lock."""
    lock = _held.get(Path(folder).resolve())
    return lock is not None and lock.held


def release(folder: Path) -> None:
    """Release this process's lock on ``folder``, if it holds one."""
    lock = _held.get(Path(folder).resolve())
    if lock is not None:
        lock.release()


@contextmanager
def owned(folder: Path, writes: bool = True) -> Iterator[RunLock | None]:
    """Hold ``folder``'s lock for the ``with`` block when the command ``writes`` into it (None otherwise).

    A lock this process already held before the block stays held after it."""
    if not writes or not Path(folder).is_dir():  # nothing to own: the command reports the missing run itself
        yield None
        return
    before = holds(folder)
    lock = acquire(folder)
    try:
        yield lock
    finally:
        if not before:
            lock.release()


def writes_inside(folder: Path, target: Path) -> bool:
    """Whether ``target`` (a file or folder a command will write) lies inside run folder ``folder``."""
    try:
        Path(target).resolve().relative_to(Path(folder).resolve())
    except ValueError:
        return False
    return True

"""Run a ``splat-*`` command in a subprocess and check what a user would see and what it touched.

A CLI test says which command, its arguments, the exit code it expects and which
folders it watches; :func:`run_cli` then asserts, for a failure:

- the exit code;
- at most ``max_lines`` lines on stderr besides progress lines (one, by default: the promise of
  the README's bad-input table), none of them a Python traceback; a command's progress (its
  ``starting`` phase while PyTorch loads, a built-in scene's generation) shows after 2 s, so on a
  loaded machine it can precede an error;
- optionally, that the message contains each of ``match``;

and, for any outcome, that nothing changed under the watched folders except the
paths listed in ``allowed`` (a snapshot of every entry, symlinks not followed, before
and after: type, size, mode, content hash of regular files, symlink target).

For example::

    from splat_framework.testing import run_cli
    run_cli("export", run, "--out", target, code=2, match="exists", watch=[tmp_path])

:func:`stop_training` runs ``splat-train`` and stops it with SIGTERM once it has written a checkpoint.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
import signal
import stat
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from ..console import PROGRESS_LINE

COMMANDS = ("train", "eval", "render", "view", "export", "process", "scene", "match", "sweep")
"""The ``splat-*`` commands: ``splat_framework.cli.<name>``."""


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder`` (itself included), symlinks not followed: relative path -> fingerprint."""
    folder = Path(folder)
    out: dict[str, tuple] = {}
    if not os.path.lexists(folder):
        return out
    todo = [folder]
    while todo:
        p = todo.pop()
        st = os.lstat(p)
        rel = os.path.relpath(p, folder)
        if stat.S_ISLNK(st.st_mode):
            out[rel] = ("link", os.readlink(p))
        elif stat.S_ISDIR(st.st_mode):
            out[rel] = ("dir", stat.S_IMODE(st.st_mode))
            todo.extend(Path(p) / name for name in os.listdir(p))
        elif stat.S_ISREG(st.st_mode):
            with open(p, "rb") as f:
                digest = hashlib.sha256(f.read()).hexdigest()
            out[rel] = ("file", st.st_size, stat.S_IMODE(st.st_mode), digest)
        else:  # FIFO, device, socket: never opened
            out[rel] = ("special", stat.S_IFMT(st.st_mode))
    return out


def message_lines(stderr: str) -> list[str]:
    """A command's stderr without blank lines and progress lines (:data:`splat_framework.console.PROGRESS_LINE`)."""
    return [line for line in stderr.splitlines() if line.strip() and not PROGRESS_LINE.match(line)]


def changed_paths(before: dict[str, tuple], after: dict[str, tuple]) -> set[str]:
    """Relative paths added, removed or changed between two snapshots."""
    return {p for p in before.keys() | after.keys() if before.get(p) != after.get(p)}


def _is_allowed(path: Path, allowed: list[Path]) -> bool:
    return any(path == a or a in path.parents for a in allowed)


@dataclass
class CliResult:
    """What a command did: exit code, its output, and the watched paths that changed."""

    code: int
    stdout: str
    stderr: str
    changed: set[Path]

    @property
    def message(self) -> str:
        """stderr without blank lines and progress lines (the one-line error, when the command failed)."""
        return "\n".join(message_lines(self.stderr))


def cli_env(**extra: str) -> dict[str, str]:
    """The test process's environment (SPLAT_CACHE, SPLAT_COMPILE, ...) with ``extra`` on top."""
    env = dict(os.environ)
    env.update({k: str(v) for k, v in extra.items()})
    return env


def run_cli(
    command: str,
    *args,
    code: int | None = 2,
    match: str | tuple[str, ...] = (),
    watch: list[Path] | tuple = (),
    allowed: list[Path] | tuple = (),
    max_lines: int | None = 1,
    env: dict[str, str] | None = None,
    cwd: Path | None = None,
    timeout: float = 300,
    stdin: str | None = None,
) -> CliResult:
    """Run ``splat-<command> *args`` in a subprocess and assert how it ended.

    ``code``: the expected exit code (None: any). For a non-zero code, stderr must
    hold at most ``max_lines`` non-blank lines (None: any number), no traceback, and
    every string of ``match`` (case-insensitive). ``watch``: folders whose content must
    not change, except at or below the paths in ``allowed`` (absolute paths).
    """
    assert command in COMMANDS, command
    watch = [Path(w) for w in watch]
    allowed = [Path(a) for a in allowed]
    before = {w: snapshot(w) for w in watch}
    proc = subprocess.run(
        [sys.executable, "-m", f"splat_framework.cli.{command}", *map(str, args)],
        capture_output=True, text=True, env=env or cli_env(), cwd=cwd, timeout=timeout,
        input=stdin if stdin is not None else "",
    )
    changed: set[Path] = set()
    for w in watch:
        changed |= {w / rel for rel in changed_paths(before[w], snapshot(w))}
    result = CliResult(proc.returncode, proc.stdout, proc.stderr, changed)
    shown = f"splat-{command} {' '.join(map(str, args))}\nexit {proc.returncode}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"
    if code is not None:
        assert proc.returncode == code, f"expected exit {code}\n{shown}"
    if proc.returncode != 0:
        assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, f"a traceback\n{shown}"
        if max_lines is not None:
            lines = result.message.splitlines()
            assert len(lines) <= max_lines, f"{len(lines)} lines on stderr (at most {max_lines})\n{shown}"
        for needle in (match,) if isinstance(match, str) else match:
            assert needle.lower() in result.message.lower(), f"{needle!r} not in the message\n{shown}"
    unexpected = {p for p in changed if not _is_allowed(p, allowed)}
    assert not unexpected, f"changed outside the expected output: {sorted(map(str, unexpected))}\n{shown}"
    return result


def stop_training(*args, checkpoints: str, after_step: int = 0, env: dict[str, str] | None = None,
                  cwd: Path | None = None, timeout: float = 300) -> CliResult:
    """Run ``splat-train *args`` in a subprocess and send it SIGTERM once a checkpoint of a step past
    ``after_step`` matches the glob ``checkpoints`` (an absolute pattern); assert that it then
    stopped (exit 130) without a traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "splat_framework.cli.train", *map(str, args)], env=env or cli_env(),
                            cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + timeout
    try:
        while not any(int(re.search(r"step-(\d+)\.ckpt$", p).group(1)) > after_step for p in glob.glob(checkpoints)):
            assert proc.poll() is None, f"splat-train ended before a checkpoint past step {after_step}\n{proc.communicate()}"
            assert time.time() < deadline, "no checkpoint in time"
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:  # a failed wait: the run is not left behind
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130 and "Traceback" not in stderr, f"exit {proc.returncode}\n{stderr[-3000:]}"
    return CliResult(proc.returncode, stdout, stderr, set())

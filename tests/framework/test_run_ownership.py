"""A run folder is owned by one process, and a resume never rewrites a run's provenance (issue 40, items 3-4).

Subprocess-level: what a user sees is the exit code and the one line naming the holder, or the refused
edit; the run folder must come out of a refusal unchanged.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from cli_harness import cli_env, run_cli
from splat_framework.config import read_config_json
from splat_framework.engine.checkpoint import checkpoint_step, list_checkpoints, load_checkpoint, save_checkpoint
from splat_framework.engine.run_folder import prepare_run_dir
from splat_framework.errors import DataError
from splat_framework.files import run_lock
from splat_framework.files.output_paths import RUN_FOLDER
from splat_framework.files.run_lock import LOCK_NAME
from splat_framework.registry import get_method
from splat_framework.runtime.io import CHECKSUM_KEY, atomic_write_json, read_json

TINY = ("3dgs", "--data", "synthetic/forward-tiny", "--no-progress", "--no-save-renders",
        "--model.init.num-points", "300")


def train_args(out: Path, steps: int, *extra) -> list[str]:
    return [*TINY, "--steps", str(steps), "--output", str(out), *map(str, extra)]


def wait_for_lock(folder: Path, proc: subprocess.Popen, timeout: float = 120) -> str:
    """The lock file's text once ``proc`` has written its identity there."""
    deadline = time.time() + timeout
    path = folder / LOCK_NAME
    while True:
        text = path.read_text() if path.is_file() else ""
        if f"pid {proc.pid} " in text:
            return text
        assert proc.poll() is None, proc.communicate()
        assert time.time() < deadline, "the lock was never taken"
        time.sleep(0.02)


def hold_lock(folder: Path) -> subprocess.Popen:
    """A process that takes ``folder``'s lock and sleeps (torch-free: it starts in a fraction of a second)."""
    code = ("import sys, time; from splat_framework.files.run_lock import acquire; "
            "acquire(sys.argv[1]); print('locked', flush=True); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder)], env=cli_env(), stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


@pytest.fixture(scope="module")
def seed0_run(tmp_path_factory):
    """A finished 10-step run, seed 0 (each test copies it)."""
    out = tmp_path_factory.mktemp("ownership") / "run"
    env = cli_env(SPLAT_COMPILE="0", SPLAT_CACHE=tmp_path_factory.getbasetemp() / "splatcache")
    run_cli("train", *train_args(out, 10), code=0, env=env)
    return out


# -------------------------------------------------------------- one owner
@pytest.mark.bad_input("two `splat-train --output SAME` started together; `--resume`, `--overwrite`, `splat-eval`, `splat-render` or `splat-export` into a run another process is writing", "the second exits 2, one line naming the holder (pid, host, command); the first finishes intact")
def test_a_second_training_on_the_same_output_is_refused_while_the_first_finishes(tmp_path):
    """Two splat-train on one --output: before, both exited 0 and only the second run survived. Now the
    second (fresh or --resume) and a splat-eval of the folder exit 2 naming the first, whose run then
    finishes intact. The first is paused (SIGSTOP) while the others try, so that it is still running
    whatever the machine's load."""
    out = tmp_path / "run"
    first = subprocess.Popen([sys.executable, "-m", "splat_framework.cli.train", *train_args(out, 30, "--seed", 3)],
                             env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "splat-train 3dgs" in wait_for_lock(out, first)
        first.send_signal(signal.SIGSTOP)
        who = (f"pid {first.pid} ", "splat-train 3dgs", "in use")
        tries = [("train", *train_args(out, 20)), ("train", *train_args(out, 20, "--resume")), ("eval", out)]
        with ThreadPoolExecutor(len(tries)) as pool:
            for refused in [pool.submit(run_cli, *t, code=2, match=who) for t in tries]:
                refused.result()
        first.send_signal(signal.SIGCONT)
        _, err = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err
    assert read_json(out / "metrics.json", require_checksum=True)["steps"] == 30
    assert read_config_json(out / "config.json")[1]["seed"] == 3
    assert load_checkpoint(list_checkpoints(out / "checkpoints")[-1])["step"] == 30
    assert not (out / LOCK_NAME).exists(), "the lock file is removed when the run ends"


@pytest.mark.bad_input("two `splat-train --output SAME` started together; `--resume`, `--overwrite`, `splat-eval`, `splat-render` or `splat-export` into a run another process is writing", "the second exits 2, one line naming the holder (pid, host, command); the first finishes intact")
@pytest.mark.bad_input("a run-folder lock left by a killed process; a symlink or FIFO planted as the lock file", "the stale lock blocks nothing; a planted file is refused in one line, never followed or waited on")
def test_writers_into_a_held_run_are_refused_readers_are_not_and_a_dead_holder_blocks_nothing(seed0_run, tmp_path):
    """train --overwrite, eval, render and export into the run folder exit 2 naming the holder and change
    nothing (--overwrite deleted the holder's checkpoints before); an export to a PLY elsewhere only
    reads the run and proceeds; once the holder is killed (kill -9, its lock file left behind) the
    same export into the folder runs."""
    run = tmp_path / "run"
    shutil.copytree(seed0_run, run)
    holder = hold_lock(run)
    try:
        who = (f"pid {holder.pid} ", "in use")
        for args in (("train", *train_args(run, 10, "--overwrite")), ("eval", run), ("render", run), ("export", run)):
            run_cli(*args, code=2, match=who, watch=[tmp_path])
        elsewhere = tmp_path / "copy.ply"
        run_cli("export", run, "--out", elsewhere, code=0, watch=[tmp_path], allowed=[elsewhere])
    finally:
        holder.kill()
        holder.wait()
    assert f"pid {holder.pid} " in (run / LOCK_NAME).read_text(), "a stale lock file names its dead holder"
    run_cli("export", run, code=0, watch=[tmp_path], allowed=[run / "point_cloud.ply", run / LOCK_NAME])
    assert not (run / LOCK_NAME).exists()


@pytest.mark.bad_input("a run-folder lock left by a killed process; a symlink or FIFO planted as the lock file", "the stale lock blocks nothing; a planted file is refused in one line, never followed or waited on")
def test_a_stale_lock_file_leaves_a_folder_empty_for_a_new_run(tmp_path):
    """A folder holding only the lock file of a run killed before it wrote anything is still empty: a
    new run starts there without --overwrite, and owns it."""
    out = tmp_path / "run"
    out.mkdir()
    holder = hold_lock(out)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert [p.name for p in out.iterdir()] == [LOCK_NAME]
    cfg = get_method("3dgs").default_config().model_copy(update={"output": out})
    try:
        assert prepare_run_dir(cfg) == out
        assert f"pid {os.getpid()} " in (out / LOCK_NAME).read_text()
    finally:
        run_lock.release(out)
    assert not out.joinpath(LOCK_NAME).exists()


def test_the_lock_needs_no_fcntl_nor_unix_only_calls(tmp_path, monkeypatch):
    """On a Python without ``fcntl``, ``os.pread``/``pwrite`` and the ``O_NOFOLLOW``/``O_NONBLOCK`` flags, whose
    system cannot delete an open file (Windows, simulated: filelock keeps its own lock primitive), the lock
    still excludes another process both ways and names its holder, a planted symlink is refused, and the
    lock file a release leaves behind blocks nothing."""
    import filelock

    assert filelock.lock_descriptor  # loaded before fcntl goes: the library's primitive, as LockFileEx on Windows
    monkeypatch.setitem(sys.modules, "fcntl", None)  # `import fcntl` raises ImportError
    for name in ("pread", "pwrite", "O_NOFOLLOW", "O_NONBLOCK"):
        monkeypatch.delattr(os, name, raising=False)
    real_unlink = Path.unlink

    def unlink(path, *args, **kwargs):
        if path.name == LOCK_NAME:
            raise PermissionError(13, "the file is open")  # what Windows answers for an open file
        return real_unlink(path, *args, **kwargs)

    monkeypatch.setattr(Path, "unlink", unlink)
    try_lock = ("import sys; from splat_framework.files import run_lock\n"
                "print(run_lock.holder(sys.argv[1]))\n"
                "try: run_lock.acquire(sys.argv[1])\n"
                "except run_lock.RunFolderBusy as e: print(e)")
    run = tmp_path / "run"
    run.mkdir()
    lock = run_lock.acquire(run)
    other = subprocess.run([sys.executable, "-c", try_lock, str(run)], env=cli_env(), capture_output=True, text=True)
    holder_line, refusal = other.stdout.splitlines()
    assert holder_line.startswith(f"pid {os.getpid()} on ") and f"({holder_line})" in refusal and "in use" in refusal
    lock.release()
    assert (run / LOCK_NAME).is_file() and not run_lock.holds(run)  # left behind, unlocked
    child = hold_lock(run)
    try:
        with pytest.raises(run_lock.RunFolderBusy, match=f"pid {child.pid} "):
            run_lock.acquire(run)
        assert run_lock.holder(run).startswith(f"pid {child.pid} ")
    finally:
        child.kill()
        child.wait()
    assert run_lock.acquire(run).held and run_lock.holder(run) is None
    run_lock.release(run)
    planted = tmp_path / "planted"
    planted.mkdir()
    os.symlink(tmp_path / "elsewhere.txt", planted / LOCK_NAME)
    with pytest.raises(DataError, match="a symlink is in its place"):
        run_lock.acquire(planted)
    assert not (tmp_path / "elsewhere.txt").exists()


# -------------------------------------------------------------- provenance
def edited_copy(seed0_run: Path, tmp_path: Path, edit: str) -> Path:
    """A copy of the seed-0 run whose config.json is deleted, stripped of its checksum, or has its seed
    changed to 5 (``"delete"``, ``"unsigned"``, ``"seed"``: seed 5 and checksum stripped)."""
    run = tmp_path / "run"
    shutil.copytree(seed0_run, run)
    path = run / "config.json"
    if edit == "delete":
        path.unlink()
        return run
    payload = json.loads(path.read_text())
    if edit == "seed":
        payload["config"]["seed"] = 5
    atomic_write_json(path, payload, checksum=False)
    return run


@pytest.mark.parametrize("edit, match", [
    ("delete", ("config.json: missing", "--trust-edited-config")),
    ("seed", ("config.json: no checksum", "--trust-edited-config")),
])
@pytest.mark.bad_input("`--resume` with `config.json` deleted, unsigned or edited (its seed, say)", "exit 2 unless `--trust-edited-config`; then the checkpoints' own signed record of the experiment must match; `config.json` is never re-signed as another experiment")
def test_resume_refuses_a_missing_or_unsigned_config(seed0_run, tmp_path, edit, match):
    """Before: --resume --seed 5 on a seed-0 run whose config.json was deleted (or stripped of its
    checksum and its seed edited) trained and signed config.json as seed 5."""
    run = edited_copy(seed0_run, tmp_path, edit)
    run_cli("train", *train_args(run, 10, "--resume", "--seed", 5), code=2, match=match, watch=[tmp_path])


@pytest.mark.bad_input("`--resume` with `config.json` deleted, unsigned or edited (its seed, say)", "exit 2 unless `--trust-edited-config`; then the checkpoints' own signed record of the experiment must match; `config.json` is never re-signed as another experiment")
def test_trusted_resume_is_checked_against_the_checkpoints_own_record(seed0_run, tmp_path):
    """--trust-edited-config does not let an edited config.json change the experiment (nor re-sign it):
    the newest checkpoint records seed 0 under its own checksum, and nothing is rewritten."""
    run = edited_copy(seed0_run, tmp_path, "seed")
    run_cli("train", *train_args(run, 10, "--resume", "--seed", 5, "--trust-edited-config"), code=2,
            match=("step-0000010.ckpt", "cannot change the experiment", "--seed (0 -> 5)"), watch=[tmp_path])


@pytest.mark.bad_input("`--resume` with `config.json` deleted, unsigned or edited (its seed, say)", "exit 2 unless `--trust-edited-config`; then the checkpoints' own signed record of the experiment must match; `config.json` is never re-signed as another experiment")
def test_a_checkpoint_without_a_record_needs_a_verified_config(seed0_run, tmp_path):
    """Checkpoints written before they recorded their experiment resume on the word of a signed
    config.json only: with config.json missing, even --trust-edited-config is refused."""
    run = edited_copy(seed0_run, tmp_path, "delete")
    newest = list_checkpoints(run / "checkpoints")[-1]  # the one a resume reads
    payload = load_checkpoint(newest)
    del payload["experiment"]
    save_checkpoint(run / "checkpoints", checkpoint_step(newest), payload)
    run_cli("train", *train_args(run, 10, "--resume", "--trust-edited-config"), code=2,
            match=("step-0000010.ckpt", "records no experiment"), watch=[tmp_path])


@pytest.mark.bad_input("`--resume` with `config.json` deleted, unsigned or edited (its seed, say)", "exit 2 unless `--trust-edited-config`; then the checkpoints' own signed record of the experiment must match; `config.json` is never re-signed as another experiment")
def test_trusted_resume_of_the_same_experiment_writes_the_true_config(seed0_run, tmp_path):
    """With config.json deleted, --trust-edited-config resumes the same experiment (seed 0, as the
    checkpoints record) and writes this run's config, signed."""
    run = edited_copy(seed0_run, tmp_path, "delete")
    run_cli("train", *train_args(run, 10, "--resume", "--trust-edited-config"), code=0)
    method, saved, _ = read_config_json(run / "config.json")
    assert method == "3dgs" and saved["seed"] == 0 and saved["trust_edited_config"] is True


@pytest.mark.bad_input("`--resume` with `config.json` deleted, unsigned or edited (its seed, say)", "exit 2 unless `--trust-edited-config`; then the checkpoints' own signed record of the experiment must match; `config.json` is never re-signed as another experiment")
def test_an_edited_config_names_the_flag_that_accepts_it(seed0_run, tmp_path):
    """A config.json whose checksum no longer matches (seed edited, checksum kept) is refused by every
    reader of a run (splat-eval, splat-train --resume) with the flag that accepts it."""
    path = tmp_path / "config.json"
    payload = read_json(seed0_run / "config.json", require_checksum=True)
    payload["config"]["seed"] = 5
    path.write_text(json.dumps(payload))
    assert CHECKSUM_KEY in payload
    with pytest.raises(DataError, match="checksum mismatch.*--trust-edited-config"):
        read_config_json(path)
    assert read_config_json(path, trust_edits=True)[1]["seed"] == 5


@pytest.mark.bad_input("a run-folder lock left by a killed process; a symlink or FIFO planted as the lock file", "the stale lock blocks nothing; a planted file is refused in one line, never followed or waited on")
def test_the_lock_file_is_never_a_planted_symlink_or_fifo(tmp_path):
    """A symlink or a FIFO at the lock file's name is refused in one line (never followed: the symlink's
    target is untouched; never waited on); a plain lock is released with its file."""
    target = tmp_path / "someone_elses.txt"
    target.write_text("keep")
    for plant in ("symlink", "fifo"):
        run = tmp_path / plant
        run.mkdir()
        if plant == "symlink":
            os.symlink(target, run / LOCK_NAME)
        else:
            os.mkfifo(run / LOCK_NAME)
        with pytest.raises(DataError, match=LOCK_NAME):
            run_lock.acquire(run)
        assert run_lock.holder(run) is None
    assert target.read_text() == "keep"
    plain = tmp_path / "plain"
    plain.mkdir()
    with run_lock.owned(plain) as lock:
        assert run_lock.holds(plain) and lock is run_lock.acquire(plain)  # the process's own lock, again
        assert RUN_FOLDER.is_empty(plain)  # the lock file does not count
    assert not run_lock.holds(plain) and list(plain.iterdir()) == []

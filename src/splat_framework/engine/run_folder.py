"""Run folders: where a run writes, and the rule that no existing run is overwritten silently."""

from __future__ import annotations

import shlex
from datetime import datetime
from pathlib import Path
from typing import Sequence

from ..config import TrainConfig, read_config_json
from ..console import say
from ..data import DataError
from ..files import run_lock
from ..files.output_paths import RUN_FOLDER, check_output, check_path, clear_output, data_inputs
from .checkpoint import checkpoint_step, list_checkpoints, remove_stale_temporaries


def default_runs_folder(config: TrainConfig) -> Path:
    """outputs/SCENE/METHOD, where the runs of ``config``'s method on its data go by default; SCENE
    the last name of the resolved --data path (so that ``--data some/dir/..`` cannot put a run
    outside ``outputs/``)."""
    scene = Path(config.data).resolve().name
    if scene in ("", ".", "..") or not scene.isprintable():
        scene = "scene"
    return Path("outputs") / scene / config.method


def default_run_dir(config: TrainConfig) -> Path:
    """A new folder for a run without ``--output``: :func:`default_runs_folder`/TIMESTAMP."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = default_runs_folder(config) / stamp
    run_dir, k = base, 1
    while run_dir.exists():  # two runs started in the same second
        run_dir = base.with_name(f"{stamp}-{k}")
        k += 1
    return run_dir


def resume_unfinished(config: TrainConfig) -> TrainConfig:
    """``config`` (``--resume`` without ``--output``) continuing the one unfinished run of its method
    on its data under ``outputs/`` (:func:`unfinished_runs`), named in one line; a DataError (one
    line, exit 2) when there is none, or more than one (listed: ``--output`` picks one)."""
    runs = unfinished_runs(config)
    which = f"of {config.method} on {config.data}"
    if not runs:
        raise DataError(f"--resume: no unfinished run {which} was found under {default_runs_folder(config)} "
                        "(pass --output RUN_FOLDER to continue a run elsewhere)")
    if len(runs) > 1:
        raise DataError(f"--resume: {len(runs)} unfinished runs {which}: {', '.join(map(str, runs))}; "
                        "pass --output with the one to continue")
    say(f"resuming {runs[0]} ({_progress(runs[0])})", "cyan")
    return config.model_copy(update={"output": runs[0]})


def unfinished_runs(config: TrainConfig) -> list[Path]:
    """The runs of ``config``'s method on its data in :func:`default_runs_folder` that did not finish,
    newest first: a ``config.json`` (read even when edited: the resume check says what is wrong with
    it) of the same method and ``--data`` (resolved from here), and no ``metrics.json``, which a
    run writes last; a run stopped, killed, or failed before its final evaluation."""
    folder = default_runs_folder(config)
    found = []
    for run_dir in sorted(folder.iterdir(), reverse=True) if folder.is_dir() else ():
        saved = _saved_config(run_dir)
        if saved is not None and not (run_dir / "metrics.json").exists() and saved.get("method") == config.method \
                and _same_data(saved.get("data"), config.data):
            found.append(run_dir)
    return found


def _saved_config(run_dir: Path) -> dict | None:
    """The config a run folder's ``config.json`` records (checksum not required); None without one."""
    path = run_dir / "config.json"
    if not path.is_file():
        return None
    try:
        return read_config_json(path, trust_edits=True)[1]
    except (DataError, OSError, ValueError):
        return None


def _same_data(saved, given: str) -> bool:
    """Whether a saved ``--data`` spec names the same path as ``given`` (both resolved from here)."""
    return isinstance(saved, str) and Path(saved).expanduser().resolve() == Path(given).expanduser().resolve()


def _progress(run_dir: Path) -> str:
    """``step 412 of 1000``: where an unfinished run stands (its newest checkpoint, by name)."""
    saved = _saved_config(run_dir) or {}
    checkpoints = list_checkpoints(run_dir / "checkpoints")
    step = checkpoint_step(checkpoints[-1]) if checkpoints else 0
    return f"step {step} of {saved.get('steps') or saved.get('default_steps')}" + (
        "" if checkpoints else ", no checkpoint yet")


NOT_WITH_RESUME = ("--resume", "--no-resume", "--overwrite", "--no-overwrite")
"""splat-train flags that :func:`continue_command` leaves out of the command it gives."""


def continue_command(argv: Sequence[str], run_dir: Path) -> str:
    """The exact ``splat-train`` command (shell-quoted) that continues ``run_dir``: ``argv``, the
    arguments that started it, with ``--resume`` (never ``--overwrite``), and ``--output run_dir``
    unless they name the output already."""
    args = [a for a in argv if a not in NOT_WITH_RESUME]
    if not any(a == "--output" or a.startswith("--output=") for a in args):
        args += ["--output", str(run_dir)]
    return shlex.join(["splat-train", *args, "--resume"])


def prepare_run_dir(config: TrainConfig) -> Path:
    """The run folder, created and locked by this process; never silently overwrite an existing run.

    Raises DataError (one line, exit code 2 in the CLIs) when ``--output``
    exists and is not empty and neither ``--resume`` nor ``--overwrite`` is
    given, when it is not a run folder (see :mod:`splat_framework.files.output_paths`),
    or when it is, holds, or lies inside the ``--data`` folder; and
    :class:`~splat_framework.files.run_lock.RunFolderBusy` when another process holds the
    folder (see :func:`claim_run_dir`). With ``--overwrite`` what the previous run
    wrote (config, checkpoints, metrics, renders) is removed under the lock,
    symlinks unlinked and never followed, so that nothing of it can be mistaken for
    this one's; files of the user's in the folder are kept.
    """
    if config.resume and config.overwrite:
        raise DataError("--resume and --overwrite exclude each other (continue the run, or start it again)")
    inputs = data_inputs(config.data)
    replace = False
    if config.output is None:
        if config.resume:
            raise DataError("--resume needs --output RUN_FOLDER (the run to continue)")
        while True:
            run_dir = default_run_dir(config)
            check_path(run_dir, RUN_FOLDER, inputs=inputs, flag="--output")
            try:
                run_dir.mkdir(parents=True)
                break
            except FileExistsError:  # another run took this name since default_run_dir looked
                continue
    else:
        run_dir = Path(config.output)
        who = run_lock.holder(run_dir) if run_dir.is_dir() else None  # a run in progress: name it
        if who is not None:
            raise run_lock.busy(run_dir, who)
        if config.resume:  # what is there is checked by the trainer (config.json, checkpoints)
            check_path(run_dir, RUN_FOLDER, inputs=inputs, flag="--output")
        else:
            replace = check_output(run_dir, RUN_FOLDER, overwrite=config.overwrite, inputs=inputs, flag="--output")
        run_dir.mkdir(parents=True, exist_ok=True)
    claim_run_dir(run_dir, fresh=not (config.resume or replace))
    if replace:
        clear_output(run_dir, RUN_FOLDER)
    for folder in (run_dir, run_dir / "checkpoints", run_dir / "renders"):  # partial files of a killed run
        remove_stale_temporaries(folder)
    return run_dir


def claim_run_dir(run_dir: Path, fresh: bool) -> None:
    """Take the run folder's lock for this process (:mod:`splat_framework.files.run_lock`), before any data
    is loaded; a ``fresh`` run checks again under the lock that the folder is still empty, so of two
    runs started together on one ``--output`` the second is refused even if both saw it empty."""
    before = run_lock.holds(run_dir)
    lock = run_lock.acquire(run_dir)
    if fresh and not RUN_FOLDER.is_empty(run_dir):
        if not before:
            lock.release()
        raise _not_empty(run_dir)


def _not_empty(run_dir: Path) -> DataError:
    """The refusal of a non-empty folder: it names the process writing it, if one is."""
    who = run_lock.holder(run_dir)
    if who is not None:
        return run_lock.busy(run_dir, who)
    return DataError(
        f"{run_dir}: run folder exists and is not empty (use --resume to continue it or --overwrite to replace it)"
    )


def remove_if_unused(run_dir: Path, default_location: bool) -> bool:
    """After a failed or interrupted start of a new run (its lock released): remove ``run_dir`` if it
    is still empty, and, for a folder under ``outputs/`` (``default_location``), the method, scene
    and ``outputs`` folders above it that are left empty; whether ``run_dir`` was removed."""
    if not run_dir.is_dir() or any(run_dir.iterdir()):
        return False
    run_dir.rmdir()
    if default_location:
        for parent in list(run_dir.parents)[:3]:  # outputs/SCENE/METHOD, outputs/SCENE, outputs
            try:
                parent.rmdir()
            except OSError:  # not empty (other runs), or gone: leave it
                break
    return True


def starts_fresh(output: Path | None) -> bool:
    """Whether a run writing to ``output`` (None: a new timestamped folder) starts in a folder that
    holds nothing of a run yet: one that a failed start then removes again."""
    return output is None or not Path(output).exists() or (Path(output).is_dir() and RUN_FOLDER.is_empty(Path(output)))


def release_run_dir(run_dir: Path) -> None:
    """Give up this process's lock on ``run_dir`` (:mod:`splat_framework.files.run_lock`)."""
    run_lock.release(run_dir)

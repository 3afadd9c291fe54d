"""Run folders: where a run writes, and the rule that no existing run is overwritten silently."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

from ..files import run_lock
from .checkpoint import remove_stale_temporaries
from ..config import TrainConfig
from ..data import DataError
from ..files.output_paths import RUN_FOLDER, check_output, check_path, clear_output, data_inputs


def default_run_dir(config: TrainConfig) -> Path:
    """outputs/SCENE/METHOD/TIMESTAMP, SCENE the last name of the resolved --data path (so that
    ``--data some/dir/..`` cannot put the run outside ``outputs/``)."""
    scene = Path(config.data).resolve().name
    if scene in ("", ".", "..") or not scene.isprintable():
        scene = "scene"
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path("outputs") / scene / config.method / stamp
    run_dir, k = base, 1
    while run_dir.exists():  # two runs started in the same second
        run_dir = base.with_name(f"{stamp}-{k}")
        k += 1
    return run_dir


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

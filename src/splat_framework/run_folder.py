"""Run folders: where a run writes, and the rule that no existing run is overwritten silently."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

from . import run_lock
from .checkpoint import list_checkpoints, remove_stale_temporaries
from .config import TrainConfig
from .data import DataError
from .run_lock import is_empty_run_dir


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
    """The run folder, owned by this process; never silently overwrite an existing run.

    Raises DataError (one line, exit code 2 in the CLIs) when ``--output``
    exists and is not empty and neither ``--resume`` nor ``--overwrite`` is
    given, and :class:`~splat_framework.run_lock.RunFolderBusy` when another
    process holds the folder (see :func:`claim_run_dir`). With ``--overwrite`` the
    old checkpoints and metrics are removed (under the lock) so that nothing of the
    previous run can be mistaken for this one's.
    """
    if config.resume and config.overwrite:
        raise DataError("--resume and --overwrite exclude each other (continue the run, or start it again)")
    if config.output is None:
        if config.resume:
            raise DataError("--resume needs --output RUN_FOLDER (the run to continue)")
        while True:
            run_dir = default_run_dir(config)
            try:
                run_dir.mkdir(parents=True)
                break
            except FileExistsError:  # another run took this name since default_run_dir looked
                continue
    else:
        run_dir = Path(config.output)
        if run_dir.exists() and not run_dir.is_dir():
            raise DataError(f"{run_dir}: --output exists and is not a folder")
        if run_dir.exists() and not is_empty_run_dir(run_dir) and not (config.resume or config.overwrite):
            raise _not_empty(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
    claim_run_dir(run_dir, fresh=not (config.resume or config.overwrite))
    if config.overwrite:
        for old in list_checkpoints(run_dir / "checkpoints"):
            old.unlink(missing_ok=True)
        (run_dir / "metrics.json").unlink(missing_ok=True)
    for folder in (run_dir, run_dir / "checkpoints", run_dir / "renders"):  # partial files of a killed run
        remove_stale_temporaries(folder)
    return run_dir


def claim_run_dir(run_dir: Path, fresh: bool) -> None:
    """Take the run folder's lock for this process (:mod:`splat_framework.run_lock`), before any data
    is loaded; a ``fresh`` run checks again under the lock that the folder is still empty, so of two
    runs started together on one ``--output`` the second is refused even if both saw it empty."""
    before = run_lock.holds(run_dir)
    lock = run_lock.acquire(run_dir)
    if fresh and not is_empty_run_dir(run_dir):
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

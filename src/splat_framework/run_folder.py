"""Run folders: where a run writes, and the rule that no existing run is overwritten silently."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

from .checkpoint import list_checkpoints, remove_stale_temporaries
from .config import TrainConfig
from .data import DataError


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
    """The run folder; never silently overwrite an existing run.

    Raises DataError (one line, exit code 2 in the CLIs) when ``--output``
    exists and is not empty and neither ``--resume`` nor ``--overwrite`` is
    given. With ``--overwrite`` the old checkpoints and metrics are removed so
    that nothing of the previous run can be mistaken for this one's.
    """
    if config.resume and config.overwrite:
        raise DataError("--resume and --overwrite exclude each other (continue the run, or start it again)")
    if config.output is None:
        if config.resume:
            raise DataError("--resume needs --output RUN_FOLDER (the run to continue)")
        run_dir = default_run_dir(config)
    else:
        run_dir = Path(config.output)
        if run_dir.exists() and not run_dir.is_dir():
            raise DataError(f"{run_dir}: --output exists and is not a folder")
        if run_dir.exists() and any(run_dir.iterdir()) and not (config.resume or config.overwrite):
            raise DataError(
                f"{run_dir}: run folder exists and is not empty (use --resume to continue it or --overwrite to replace it)"
            )
        if config.overwrite and run_dir.is_dir():
            for old in list_checkpoints(run_dir / "checkpoints"):
                old.unlink(missing_ok=True)
            (run_dir / "metrics.json").unlink(missing_ok=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    for folder in (run_dir, run_dir / "checkpoints", run_dir / "renders"):  # partial files of a killed run
        remove_stale_temporaries(folder)
    return run_dir

"""Run folders: where a run writes, and the rule that no existing run is overwritten silently."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

from .checkpoint import remove_stale_temporaries
from .config import TrainConfig
from .data import DataError
from .output_paths import RUN_FOLDER, check_output, check_path, clear_output


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
    given, when it is not a run folder (see :mod:`splat_framework.output_paths`),
    or when it is, holds, or lies inside the ``--data`` folder. With ``--overwrite``
    what the previous run wrote (config, checkpoints, metrics, renders) is removed,
    symlinks unlinked and never followed, so that nothing of it can be mistaken for
    this one's; files of the user's in the folder are kept.
    """
    if config.resume and config.overwrite:
        raise DataError("--resume and --overwrite exclude each other (continue the run, or start it again)")
    inputs = [Path(config.data)] if Path(config.data).exists() else []
    if config.output is None:
        if config.resume:
            raise DataError("--resume needs --output RUN_FOLDER (the run to continue)")
        run_dir = default_run_dir(config)
        check_path(run_dir, RUN_FOLDER, inputs=inputs, flag="--output")
    else:
        run_dir = Path(config.output)
        if config.resume:  # what is there is checked by the trainer (config.json, checkpoints)
            check_path(run_dir, RUN_FOLDER, inputs=inputs, flag="--output")
        elif check_output(run_dir, RUN_FOLDER, overwrite=config.overwrite, inputs=inputs, flag="--output"):
            clear_output(run_dir, RUN_FOLDER)
    run_dir.mkdir(parents=True, exist_ok=True)
    for folder in (run_dir, run_dir / "checkpoints", run_dir / "renders"):  # partial files of a killed run
        remove_stale_temporaries(folder)
    return run_dir

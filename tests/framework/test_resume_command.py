"""``--resume`` from the command the user just ran: without ``--output`` it continues the one
unfinished run of that method on that data under ``outputs/``, and a stop prints the exact command
that continues the run."""

from __future__ import annotations

import re
import shlex
import shutil

import pytest

from cli_harness import run_cli, stop_training
from splat_framework.runtime.io import atomic_write_json, read_json

ARGS = ["3dgs", "--data", "synthetic/forward-tiny", "--steps", "60", "--no-progress", "--checkpoint-every", "1",
        "--model.init.num-points", "300", "--no-save-renders"]
"""A short run with a checkpoint after each step."""
RUNS = "outputs/forward-tiny/3dgs"
"""Where the runs of ``ARGS`` go (the default run folder's parent), relative to the folder they start in."""


def stopped_at(stderr: str, command: list[str]) -> int:
    """The step of the stop whose last line names ``command`` as the one that continues the run."""
    last = stderr.strip().splitlines()[-1]
    found = re.fullmatch(r"stopped: SIGTERM at step (\d+)/60: checkpoint written to \S+; continue with: (.+)", last)
    assert found and found.group(2) == shlex.join(command), last
    return int(found.group(1))


@pytest.mark.bad_input("`splat-train ... --resume` without `--output`, and no unfinished run (or several) of that method on that data under `outputs/`",
                       "exit 2, one line naming where it looked (or the runs: `--output` picks one); nothing is started")
def test_resume_continues_the_run_the_same_command_started(tmp_path):
    """In one folder: --resume before any run finds none; a run stopped by SIGTERM names the exact
    command that continues it; with a second unfinished run beside it --resume lists both; with a
    finished one beside it instead, the same command plus --resume continues the stopped run (one
    line naming it), and the command its stop names finishes it in the same folder."""
    outputs = tmp_path / "outputs"
    run_cli("train", *ARGS, "--resume", cwd=tmp_path, watch=[tmp_path],
            match=f"--resume: no unfinished run of 3dgs on synthetic/forward-tiny was found under {RUNS} ")
    first = stop_training(*ARGS, checkpoints=str(tmp_path / RUNS / "*" / "checkpoints" / "step-*.ckpt"), cwd=tmp_path)
    (run,) = (tmp_path / RUNS).iterdir()
    rel = f"{RUNS}/{run.name}"
    command = ["splat-train", *ARGS, "--output", rel, "--resume"]
    step = stopped_at(first.stderr, command)

    twin = run.with_name(run.name + "-1")  # a second unfinished run of the same command
    shutil.copytree(run, twin)
    run_cli("train", *ARGS, "--resume", cwd=tmp_path, watch=[outputs],
            match=(f"--resume: 2 unfinished runs of 3dgs on synthetic/forward-tiny: {RUNS}/{twin.name}, {rel}; ",
                   "pass --output"))
    atomic_write_json(twin / "metrics.json", {"steps": 60})  # now finished: no longer a candidate

    again = stop_training(*ARGS, "--resume", checkpoints=str(run / "checkpoints" / "step-*.ckpt"), after_step=step,
                          cwd=tmp_path)
    assert again.stderr.splitlines()[0] == f"resuming {rel} (step {step} of 60)", again.stderr
    assert stopped_at(again.stderr, command) > step  # the same continue command: --resume is not doubled

    done = run_cli("train", *command[1:], cwd=tmp_path, code=0, watch=[outputs], allowed=[run])
    assert "resumed from" in done.stderr
    assert read_json(run / "metrics.json", require_checksum=True)["steps"] == 60
    assert sorted(p.name for p in (tmp_path / RUNS).iterdir()) == [run.name, twin.name]


def test_the_continue_command_is_the_users_own_with_the_run_folder_and_resume(tmp_path):
    """The arguments as typed, shell-quoted; ``--output`` added unless given (either spelling);
    ``--overwrite`` (which excludes ``--resume``) left out, ``--resume`` once, last."""
    from splat_framework.engine.run_folder import continue_command

    run = tmp_path / "my runs" / "a"
    assert continue_command(["3dgs", "--data", "my data/fern", "--overwrite"], run) == \
        f"splat-train 3dgs --data 'my data/fern' --output '{run}' --resume"
    assert continue_command(["3dgs", "--resume", "--output=x y", "--seed", "3"], run) == \
        "splat-train 3dgs '--output=x y' --seed 3 --resume"

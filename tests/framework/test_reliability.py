"""Reliability: exact resume, corrupt checkpoints, signals, disk full, non-finite numerics, CLI errors."""

from __future__ import annotations

import errno
import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import splat_framework.engine.trainer as trainer_mod
from cli_harness import message_lines, stop_training
from splat_framework.cli.common import run_cli
from splat_framework.config import apply_overrides
from splat_framework.engine.checkpoint import (
    CheckpointError,
    checkpoint_path,
    list_checkpoints,
    load_checkpoint,
    load_latest,
    save_checkpoint,
)
from splat_framework.engine.run import load_trained_model
from splat_framework.engine.trainer import Trainer, TrainingDiverged, TrainingInterrupted
from splat_framework.errors import DataError
from splat_framework.model.gaussians import GaussianModel
from splat_framework.registry import get_method
from splat_framework.runtime.io import CHECKSUM_KEY, atomic_write_json, read_json
from tiers import seed_kernels

PY = sys.executable


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPLAT_CACHE", str(seed_kernels(tmp_path / "cache")))
    monkeypatch.delenv("SPLAT_IMAGE_MEMORY_BUDGET", raising=False)
    # a fixed rasterizer thread count: "auto" follows the machine's load, and a
    # different reduction order could change the last bits between two runs
    monkeypatch.setenv("SPLAT_THREADS", "1")


def fixed_config(method: str, output: Path, **over):
    """A 40-step schedule written out directly (no --steps rescaling), so an
    interrupted+resumed run and a straight run have identical schedules:
    densification at steps 10, 20, 30, opacity reset at 30, SH degree up every 10."""
    cfg = get_method(method).default_config()
    base = {
        "data": "synthetic/forward-tiny",
        "output": str(output),
        "default_steps": 40,
        "checkpoint_every": 20,
        "progress": False,
        "save_renders": False,
        "model": {"init": {"num_points": 300}, "sh_degree_interval": 10},
        "strategy": {"refine_start_iter": 5, "refine_stop_iter": 35, "refine_every": 10, "reset_every": 30},
    }
    cfg = apply_overrides(cfg, base)
    return apply_overrides(cfg, over)


def stop_at(step_to_stop: int):
    def callback(trainer, step):
        if step == step_to_stop:
            trainer.request_stop("test stop")

    return callback


def assert_same_params(a, b):
    assert set(a.params.keys()) == set(b.params.keys())
    for k in a.params:
        pa, pb = a.params[k].detach(), b.params[k].detach()
        assert pa.shape == pb.shape, k
        assert torch.allclose(pa, pb, atol=1e-6, rtol=0), (k, (pa - pb).abs().max())


def interrupted_then_resumed(cfg_fn, out: Path, stop: int):
    with pytest.raises(TrainingInterrupted, match=f"at step {stop}/"):
        Trainer(cfg_fn(out, overwrite=True), [stop_at(stop)]).train()
    ck = load_latest(out / "checkpoints")
    assert ck is not None and ck[1]["step"] == stop
    resumed = Trainer(cfg_fn(out, resume=True))
    metrics = resumed.train()
    return resumed, metrics



def forget_fields(path, *dotted):
    """Rewrite a run's config.json (with a fresh checksum) as if written before ``dotted`` fields existed."""
    payload = read_json(path)
    for name in dotted:
        *parents, leaf = name.split(".")
        section = payload["config"]
        for p in parents:
            section = section[p]
        del section[leaf]
    payload.pop(CHECKSUM_KEY, None)
    atomic_write_json(path, payload)

# ------------------------------------------------------------------ resume
@pytest.mark.bad_input("`--resume` with a different seed or any experiment setting", "exit 2 naming each setting; run options (device, progress, ...) may change")
def test_resume_reproduces_uninterrupted_run_3dgs(tmp_path):
    cfg_fn = lambda out, **kw: fixed_config("3dgs", out, **kw)  # noqa: E731
    straight = Trainer(cfg_fn(tmp_path / "a"))
    ma = straight.train()
    # stop mid densification window (15) so grad statistics, SH degree, Adam
    # moments and RNG state all have to travel through the checkpoint
    resumed, mb = interrupted_then_resumed(cfg_fn, tmp_path / "b", stop=15)
    # a resume may change run options (device, progress, ...) but never the experiment
    saved = (tmp_path / "b" / "config.json").read_bytes()
    with pytest.raises(DataError, match=r"config.json: --resume cannot change the experiment: --seed \(0 -> 5\)"):
        Trainer(cfg_fn(tmp_path / "b", resume=True, seed=5))
    assert (tmp_path / "b" / "config.json").read_bytes() == saved
    Trainer(cfg_fn(tmp_path / "b", resume=True, progress=False, eval_every=7))
    # a run written before a field existed resumes: the field takes its default
    forget_fields(tmp_path / "b" / "config.json", "schedule_views", "model.reg.backdrop_weight", "strategy.kind")
    Trainer(cfg_fn(tmp_path / "b", resume=True))
    assert straight.model.num_gaussians != 300, "densification should have run"
    assert_same_params(straight.model, resumed.model)
    assert mb["mean"]["psnr"] == pytest.approx(ma["mean"]["psnr"], abs=1e-6)
    # a finished run resumed (nothing left to train) evaluates the model as the run left it
    again = Trainer(cfg_fn(tmp_path / "b", resume=True)).train()
    assert again["mean"]["psnr"] == pytest.approx(ma["mean"]["psnr"], abs=1e-6)


def test_resume_reproduces_uninterrupted_run_scgaussian(tmp_path):
    def cfg_fn(out, **kw):
        # single stage with the match cache alive across the interruption (cache until 30)
        over = {"model": {"schedule": "single-stage", "cache_until": 30, "lambda_gp": 1.0, "warmup_steps": 0,
                          "init": {"num_points": 0}, "sparse_matches": 0, "matching": {"kind": "dense", "max_matches": 100, "dense_preset": "ultrafast"}}}
        return apply_overrides(fixed_config("scgaussian", out, **kw), over)

    straight = Trainer(cfg_fn(tmp_path / "a"))
    assert straight.model.cache is not None and straight.model.num_match_gaussians > 0
    straight.train()
    resumed, _ = interrupted_then_resumed(cfg_fn, tmp_path / "b", stop=15)
    assert_same_params(straight.model, resumed.model)
    assert resumed.model.num_match_gaussians == straight.model.num_match_gaussians
    # a run written before a field existed takes the method's default (scgaussian's
    # schedule_views is 3, the base class's 0), not the class default, so it still resumes
    forget_fields(tmp_path / "b" / "config.json", "schedule_views", "strategy.kind")
    Trainer(cfg_fn(tmp_path / "b", resume=True))
    config, rebuilt = load_trained_model(tmp_path / "b")
    assert config.schedule_views == 3 and config.strategy.kind == "ray-gaussian"
    # rebuilt by normal construction: no training views, its ray rows frozen, its matches restored
    assert rebuilt.train_cameras == [] and not rebuilt.params["ray_o"].requires_grad
    assert torch.equal(rebuilt.bundle.z.cpu(), resumed.model.bundle.z.cpu())
    assert torch.equal(resumed.model.bundle.z.cpu(), straight.model.bundle.z.cpu())


@pytest.mark.bad_input("a checkpoint that is truncated, corrupt, or checksummed but of the wrong layout", "one line, the previous checkpoint is used")
def test_corrupt_checkpoint_on_resume_falls_back_to_previous(tmp_path, capsys):
    out = tmp_path / "run"
    cfg_fn = lambda out, **kw: fixed_config("3dgs", out, checkpoint_every=5, **kw)  # noqa: E731
    with pytest.raises(TrainingInterrupted):
        Trainer(cfg_fn(out), [stop_at(10)]).train()
    newest = checkpoint_path(out / "checkpoints", 10)
    raw = newest.read_bytes()
    newest.write_bytes(raw[: len(raw) // 2])  # truncated
    capsys.readouterr()
    resumed = Trainer(cfg_fn(out, resume=True))
    resumed.restore()
    err = capsys.readouterr().err
    assert resumed.start_step == 5
    bad = [line for line in err.splitlines() if "step-0000010.ckpt" in line]
    assert len(bad) == 1 and "checksum mismatch" in bad[0] and "previous checkpoint" in bad[0]
    # all checkpoints corrupt: a clear error, not a silent fresh start
    for p in list_checkpoints(out / "checkpoints"):
        p.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="no valid checkpoint"):
        Trainer(cfg_fn(out, resume=True)).restore()


@pytest.mark.parametrize("damage", ["missing parameter", "wrong shape", "float64", "optimizer shape", "rows differ"])
@pytest.mark.bad_input("a checkpoint that is truncated, corrupt, or checksummed but of the wrong layout", "one line, the previous checkpoint is used")
def test_a_checkpoint_with_a_valid_checksum_but_wrong_contents_falls_back(tmp_path, capsys, damage):
    """A checksum proves the bytes, not the layout: a newest checkpoint with a missing parameter, a wrong
    shape or dtype is reported in one line and the previous one is used, by --resume and by splat-eval,
    splat-render and splat-export (load_trained_model)."""

    out = tmp_path / "run"
    cfg_fn = lambda out, **kw: fixed_config("3dgs", out, checkpoint_every=5, **kw)  # noqa: E731
    with pytest.raises(TrainingInterrupted):
        Trainer(cfg_fn(out), [stop_at(10)]).train()
    ck = load_checkpoint(checkpoint_path(out / "checkpoints", 10))
    params = ck["params"]
    if damage == "missing parameter":
        del params["shN"]
    elif damage == "wrong shape":
        params["means"] = params["means"][:, :2].contiguous()
    elif damage == "float64":
        params["means"] = params["means"].double()
    elif damage == "optimizer shape":
        ck["optimizers"]["means"]["state"][0]["exp_avg"] = torch.zeros(3, 3)
    else:
        params["opacities"] = params["opacities"][:-1]
    save_checkpoint(out / "checkpoints", 10, ck)  # a valid checksum over the wrong contents
    capsys.readouterr()
    resumed = Trainer(cfg_fn(out, resume=True))
    assert resumed.restore() and resumed.start_step == 5
    bad = [line for line in capsys.readouterr().err.splitlines() if "step-0000010.ckpt" in line]
    assert len(bad) == 1 and "previous checkpoint" in bad[0], bad
    with pytest.warns(UserWarning, match="step-0000010.ckpt.*previous checkpoint"):
        _, model = load_trained_model(out)
    assert model.num_gaussians == resumed.model.num_gaussians


def test_checkpoint_verification_unit(tmp_path):
    folder = tmp_path / "ck"
    save_checkpoint(folder, 1, {"step": 1, "params": {"x": torch.ones(3)}})
    p2 = save_checkpoint(folder, 2, {"step": 2, "params": {"x": torch.full((3,), 2.0)}})
    data = bytearray(p2.read_bytes())
    data[-5] ^= 0xFF  # flip a byte
    p2.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        load_checkpoint(p2)
    msgs = []
    path, ck = load_latest(folder, report=msgs.append)
    assert ck["step"] == 1 and len(msgs) == 1 and "step-0000002" in msgs[0]
    # NaN parameters are never written
    with pytest.raises(CheckpointError, match="non-finite"):
        save_checkpoint(folder, 3, {"step": 3, "params": {"x": torch.tensor([1.0, float("nan")])}})
    assert not checkpoint_path(folder, 3).exists()
    # keep the newest two; a save at an older step drops the abandoned later ones
    save_checkpoint(folder, 3, {"step": 3, "params": {"x": torch.ones(3)}})
    save_checkpoint(folder, 4, {"step": 4, "params": {"x": torch.ones(3)}})
    assert [p.name for p in list_checkpoints(folder)] == ["step-0000003.ckpt", "step-0000004.ckpt"]
    save_checkpoint(folder, 2, {"step": 2, "params": {"x": torch.ones(3)}})
    assert [p.name for p in list_checkpoints(folder)] == ["step-0000002.ckpt"]


# ------------------------------------------------------------- disk full
def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_disk_full_keeps_previous_checkpoint_and_results(tmp_path, monkeypatch):
    folder = tmp_path / "ck"
    good = save_checkpoint(folder, 1, {"step": 1, "params": {"x": torch.ones(3)}})
    atomic_write_json(tmp_path / "metrics.json", {"mean": {"psnr": 20.0}})
    monkeypatch.setattr(os, "fsync", _enospc)
    with pytest.raises(CheckpointError) as info:
        save_checkpoint(folder, 2, {"step": 2, "params": {"x": torch.zeros(3)}})
    msg = str(info.value)
    assert "\n" not in msg and "No space left on device" in msg
    assert msg.endswith("; step-0000001.ckpt (the newest checkpoint) is kept")
    with pytest.raises(CheckpointError, match="; no checkpoint was written yet$"):  # the first one: nothing kept
        save_checkpoint(tmp_path / "empty", 1, {"step": 1, "params": {"x": torch.zeros(3)}})
    with pytest.raises(OSError):
        atomic_write_json(tmp_path / "metrics.json", {"mean": {"psnr": 1.0}})
    monkeypatch.undo()
    assert [p.name for p in folder.iterdir()] == [good.name]  # no temp files left
    assert load_checkpoint(good)["step"] == 1
    assert read_json(tmp_path / "metrics.json")["mean"]["psnr"] == 20.0
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_cli_reports_os_failures_in_one_line(tmp_path, capsys):
    def full_disk():
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "metrics.json"))

    with pytest.raises(SystemExit) as info:
        run_cli(full_disk)
    assert info.value.code == 1
    err = capsys.readouterr().err
    assert err == f"error: {tmp_path / 'metrics.json'}: No space left on device\n"


def test_disk_full_during_training_is_one_line(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    trainer = Trainer(fixed_config("3dgs", out, checkpoint_every=5, default_steps=10))

    real_fsync = os.fsync

    def fsync_fails_after_first_checkpoint(fd):
        if list_checkpoints(out / "checkpoints"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync_fails_after_first_checkpoint)
    with pytest.raises(SystemExit) as info:
        run_cli(trainer.train)
    assert info.value.code == 1  # the machine's fault, not the input's
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and "No space left on device" in err[-1]
    assert "Traceback" not in "\n".join(err)
    monkeypatch.undo()
    ck = load_latest(out / "checkpoints")
    assert ck is not None and ck[1]["step"] == 5


# -------------------------------------------------------------- numerics
def nan_loss_on_calls(monkeypatch, bad_calls):
    real = GaussianModel.get_loss_dict
    calls = {"n": 0}

    def patched(self, outputs, batch, camera, step):
        losses = real(self, outputs, batch, camera, step)
        calls["n"] += 1
        if calls["n"] in bad_calls:
            losses["photometric"] = losses["photometric"] * float("nan")
        return losses

    monkeypatch.setattr(GaussianModel, "get_loss_dict", patched)
    return calls


def test_nan_loss_and_gradient_steps_are_skipped(tmp_path, monkeypatch, capsys):
    real = GaussianModel.get_loss_dict
    calls = {"n": 0}

    def patched(self, outputs, batch, camera, step):
        losses = real(self, outputs, batch, camera, step)
        calls["n"] += 1
        if calls["n"] in (3, 4):  # NaN loss
            losses["photometric"] = losses["photometric"] * float("nan")
        if calls["n"] == 7:  # finite loss, NaN gradient: d sqrt(|0 x|) at 0 = inf * 0
            losses["bad"] = torch.sqrt((self.params["means"][:1, 0] * 0).abs()).sum()
        return losses

    monkeypatch.setattr(GaussianModel, "get_loss_dict", patched)
    trainer = Trainer(fixed_config("3dgs", tmp_path / "run", default_steps=12, checkpoint_every=5))
    metrics = trainer.train()
    assert metrics["skipped_steps"] == 3 and metrics["restores"] == 0
    assert read_json(tmp_path / "run" / "metrics.json")["skipped_steps"] == 3
    for p in list_checkpoints(tmp_path / "run" / "checkpoints"):
        for t in load_checkpoint(p)["params"].values():
            assert torch.isfinite(t).all()
    err = capsys.readouterr().err
    assert "non-finite loss, step skipped" in err and "non-finite gradient of means" in err


def test_repeated_nan_restores_last_checkpoint_with_lower_lr(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(trainer_mod, "MAX_NONFINITE", 3)
    nan_loss_on_calls(monkeypatch, {8, 9, 10})  # steps 7, 8, 9 after the step-5 checkpoint
    trainer = Trainer(fixed_config("3dgs", tmp_path / "run", default_steps=12, checkpoint_every=5))
    metrics = trainer.train()
    assert metrics["restores"] == 1 and metrics["skipped_steps"] == 3
    assert trainer.lr_factor == 0.5
    err = capsys.readouterr().err
    assert "restored step-0000005.ckpt (step 5), learning rates x0.5" in err
    assert all(torch.isfinite(p).all() for p in trainer.model.params.values())


def test_a_parameter_a_step_made_non_finite_restores_the_last_checkpoint_before_any_is_written(tmp_path, monkeypatch,
                                                                                                  capsys):
    """The parameters an optimizer step wrote are checked in the next step's one host read, or before
    the checkpoint that follows the step: a NaN written at step 6 is caught at step 7, one written at
    step 9 before step 10's checkpoint; each restores step 5 with its learning rates halved."""
    real = GaussianModel.after_optimizer_step
    pending = {6, 9}

    def corrupt(self, step, losses, optimizers):
        change = real(self, step, losses, optimizers)
        if step in pending:
            pending.discard(step)
            with torch.no_grad():
                self.params["means"][0, 0] = float("nan")
        return change

    monkeypatch.setattr(GaussianModel, "after_optimizer_step", corrupt)
    trainer = Trainer(fixed_config("3dgs", tmp_path / "run", default_steps=12, checkpoint_every=5))
    metrics = trainer.train()
    assert metrics["restores"] == 2 and trainer.lr_factor == 0.5 and not pending  # the checkpoint's factor, halved
    err = capsys.readouterr().err
    assert "non-finite parameter means at step 6: restored step-0000005.ckpt (step 5), learning rates x0.5" in err
    assert "non-finite parameter means at step 9: restored step-0000005.ckpt (step 5), learning rates x0.5" in err
    for p in list_checkpoints(tmp_path / "run" / "checkpoints"):
        for t in load_checkpoint(p)["params"].values():
            assert torch.isfinite(t).all()


@pytest.mark.bad_input("a weight so large that every step's loss is non-finite (`--model.reg.depth-smoothness 1e308`)",
                       "exit 1, one line naming the flag; no metrics, no checkpoint")
def test_a_run_whose_every_step_was_skipped_fails_naming_the_flag_and_writes_no_metrics(tmp_path, capsys):
    out = tmp_path / "run"
    trainer = Trainer(fixed_config("3dgs", out, default_steps=3, model={"reg": {"depth_smoothness": 1e308}}))
    with pytest.raises(SystemExit) as info:
        run_cli(trainer.train)
    assert info.value.code == 1
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last == ("error: training diverged: every step of this run (3) had a non-finite loss or gradient and was "
                    "skipped; nothing was evaluated or saved (check --model.reg.depth-smoothness 1e+308)")
    assert not (out / "metrics.json").exists() and list_checkpoints(out / "checkpoints") == []


def test_persistent_nan_stops_with_clear_message_and_no_nan_on_disk(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(trainer_mod, "MAX_NONFINITE", 2)
    nan_loss_on_calls(monkeypatch, set(range(7, 1000)))
    out = tmp_path / "run"
    trainer = Trainer(fixed_config("3dgs", out, default_steps=20, checkpoint_every=5))
    with pytest.raises(SystemExit) as info:
        run_cli(trainer.train)
    assert info.value.code == 1
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: training diverged: non-finite loss") and "restores" in last
    assert "Traceback" not in err
    assert not (out / "metrics.json").exists()
    for p in list_checkpoints(out / "checkpoints"):
        for t in load_checkpoint(p)["params"].values():
            assert torch.isfinite(t).all()
    # without any checkpoint to fall back on, the run stops at once with a message
    nan_loss_on_calls(monkeypatch, set(range(1, 1000)))
    with pytest.raises(TrainingDiverged, match="no checkpoint to restore"):
        Trainer(fixed_config("3dgs", tmp_path / "run2", default_steps=20)).train()


# ---------------------------------------------------------------- signals
def test_sigint_in_process_saves_checkpoint(tmp_path):
    def send_sigint(trainer, step):
        if step == 3:
            os.kill(os.getpid(), signal.SIGINT)

    out = tmp_path / "run"
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(TrainingInterrupted, match="SIGINT at step 3/"):
        Trainer(fixed_config("3dgs", out, default_steps=20), [send_sigint]).train()
    assert load_latest(out / "checkpoints")[1]["step"] == 3
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored


@pytest.mark.bad_input("Ctrl-C twice, the second during a checkpoint write", "the write finishes, exit 130")
def test_a_second_sigint_during_the_checkpoint_write_waits_for_it(tmp_path, monkeypatch):
    """Two SIGINTs close together: the second arrives while the stop's checkpoint is being written;
    the write completes (nothing is lost) and the run ends as interrupted."""
    def send_sigint(trainer, step):
        if step == 3:
            os.kill(os.getpid(), signal.SIGINT)

    import splat_framework.engine.train_state as train_state

    real_save = train_state.save_checkpoint

    def save_with_a_second_signal(folder, step, payload, *a, **kw):
        if step == 3:
            os.kill(os.getpid(), signal.SIGINT)  # handled here, in the middle of the save
        return real_save(folder, step, payload, *a, **kw)

    monkeypatch.setattr(train_state, "save_checkpoint", save_with_a_second_signal)
    out = tmp_path / "run"
    with pytest.raises(TrainingInterrupted, match="SIGINT at step 3/"):
        Trainer(fixed_config("3dgs", out, default_steps=20, checkpoint_every=0), [send_sigint]).train()
    assert load_latest(out / "checkpoints")[1]["step"] == 3


@pytest.mark.bad_input("Ctrl-C during setup (matching, warm-up)", "one line saying nothing was trained; the empty run folder is removed")
def test_a_stop_during_setup_leaves_no_empty_run_folder(tmp_path, monkeypatch):
    """Ctrl-C during the setup (SCGaussian: matching and warm-up) of a new run: the empty run folder is
    removed and the message says nothing was trained; for a resumed run the folder is left as it was."""
    def interrupted(*a, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(GaussianModel, "from_data", classmethod(interrupted))
    out = tmp_path / "run"
    with pytest.raises(TrainingInterrupted, match="before any training step: nothing was trained.*removed"):
        Trainer(fixed_config("3dgs", out, default_steps=20))
    assert not out.exists()
    monkeypatch.undo()
    with pytest.raises(TrainingInterrupted, match="test stop at step 3/"):
        Trainer(fixed_config("3dgs", out, default_steps=20), [stop_at(3)]).train()
    files = sorted(p.relative_to(out) for p in out.rglob("*"))
    monkeypatch.setattr(GaussianModel, "from_data", classmethod(interrupted))
    with pytest.raises(TrainingInterrupted, match=r"is unchanged; continue with --resume$"):
        Trainer(fixed_config("3dgs", out, default_steps=20, resume=True))
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == files


def _cli(args, env, **kw):
    return subprocess.run([PY, "-m", "splat_framework.cli.train", *args], env=env, capture_output=True, text=True, **kw)


def _env(tmp_path):
    env = dict(os.environ, SPLAT_CACHE=str(seed_kernels(tmp_path / "cache")), PYTHONUNBUFFERED="1")
    env.pop("SPLAT_IMAGE_MEMORY_BUDGET", None)
    return env


def test_sigterm_writes_checkpoint_exits_130_and_resume_finishes(tmp_path):
    env = _env(tmp_path)
    out = tmp_path / "run"
    # --steps 60 rather than 2000 so that the resumed run finishes quickly; a checkpoint after
    # every step, so one exists within the first steps
    args = ["3dgs", "--data", "synthetic/forward-tiny", "--steps", "60", "--output", str(out), "--no-progress",
            "--checkpoint-every", "1", "--model.init.num-points", "300", "--no-save-renders"]
    stderr = stop_training(*args, checkpoints=str(out / "checkpoints" / "step-*.ckpt"), env=env).stderr
    lines = message_lines(stderr)  # (a loaded machine may take over 2 s to start: that phase then prints its lines)
    assert len(lines) == 2 and lines[0].startswith("SIGTERM: stopping after this step"), stderr
    assert lines[1].startswith("stopped: SIGTERM at step "), stderr
    assert lines[1].endswith("; continue with: " + shlex.join(["splat-train", *args, "--resume"])), stderr
    path, ck = load_latest(out / "checkpoints")
    assert 1 <= ck["step"] < 60 and all(torch.isfinite(t).all() for t in ck["params"].values())
    assert not (out / "metrics.json").exists()
    # the same command line without --resume refuses to overwrite the run
    again = _cli(args, env, timeout=300)
    assert again.returncode == 2 and len(message_lines(again.stderr)) == 1, again.stderr
    assert "not empty" in again.stderr and "Traceback" not in again.stderr
    done = _cli([*args, "--resume"], env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"resumed from {path}" in done.stderr
    metrics = read_json(out / "metrics.json", require_checksum=True)
    assert metrics["steps"] == 60
    assert load_latest(out / "checkpoints")[1]["step"] == 60


# -------------------------------------------------------------------- CLI
def test_invalid_config_value_is_one_line_naming_the_field(tmp_path):
    res = _cli(["3dgs", "--model.sh-degree", "9", "--output", str(tmp_path / "x")], _env(tmp_path), timeout=120)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "model.sh_degree" in lines[0] and lines[0].startswith("error: invalid config")
    assert not (tmp_path / "x").exists()  # rejected before any work


def test_existing_output_without_flags_exits_2(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "something").write_text("x")
    res = _cli(["3dgs", "--data", "synthetic/forward-tiny", "--output", str(out)], _env(tmp_path), timeout=120)
    assert res.returncode == 2
    lines = message_lines(res.stderr)
    assert len(lines) == 1 and "not a run folder" in lines[0]  # --overwrite would not replace it either
    assert sorted(p.name for p in out.iterdir()) == ["something"]


def test_refined_training_cameras_resume_exactly_and_are_the_poses_a_reloaded_run_scores(tmp_path):
    """--camera-refine.mode on: the training views' pose corrections travel through the checkpoint
    (an interrupted and resumed run ends where a straight one does), the first view fixes the frame,
    metrics.json reports how far each view moved, and a reloaded run's training cameras carry them."""
    from splat_framework.engine.run import load_run

    cfg_fn = lambda out, **kw: fixed_config("3dgs", out, camera_refine={"mode": "on"}, **kw)  # noqa: E731
    straight = Trainer(cfg_fn(tmp_path / "a"))
    ma = straight.train()
    resumed, mb = interrupted_then_resumed(cfg_fn, tmp_path / "b", stop=15)
    assert_same_params(straight.model, resumed.model)
    for key, value in straight.camera_refiner.tensors().items():
        assert torch.allclose(value, resumed.camera_refiner.tensors()[key], atol=1e-7, rtol=0), key
    moved = [v["rotation_deg"] for v in mb["camera_refine"]]
    assert moved[0] == 0.0 and all(d > 0 for d in moved[1:]), moved
    assert mb["mean"]["psnr"] == pytest.approx(ma["mean"]["psnr"], abs=1e-6)
    config, dm, _ = load_run(tmp_path / "b")
    for position, cam in enumerate(dm.train_cameras):
        trained_at = resumed.datamanager.train_cameras[position]
        assert torch.allclose(cam.world_to_cam.float(), trained_at.world_to_cam.float(), atol=1e-6)
    assert not torch.allclose(dm.train_cameras[1].world_to_cam, load_run_scene_camera(config, dm.train_indices[1]))
    # the dataset's poses: auto leaves them alone
    assert Trainer(fixed_config("3dgs", tmp_path / "c")).camera_refiner is None


def load_run_scene_camera(config, index: int):
    from splat_framework.pipeline.scene import load_config_scene

    return load_config_scene(config).cameras[index].world_to_cam


@pytest.mark.slow
@pytest.mark.bad_input("SIGTERM (or Ctrl-C) during the final evaluation of `splat-train`",
                       "exit 130, one line: the training is saved (its checkpoint named), metrics.json not written, "
                       "and the command that continues (which scores the run)")
def test_sigterm_during_the_evaluation_says_what_is_saved_and_the_command_that_continues(tmp_path):
    import shlex
    import time

    from cli_harness import cli_env
    from cli_harness import run_cli as run_command

    out = tmp_path / "run"
    args = ["3dgs", "--data", "synthetic/forward-tiny", "--steps", "4", "--model.init.num-points", "200",
            "--no-progress", "--no-save-renders", "--test-pose-steps", "60", "--output", str(out)]
    # the eager kernels: with the native ones, under a loaded CI, this run once printed its line and
    # then died of SIGINT (exit -2, not 130); not understood yet (docs/history/2026-12-07.md)
    proc = subprocess.Popen([sys.executable, "-m", "splat_framework.cli.train", *args], env=cli_env(SPLAT_COMPILE="0"),
                            text=True, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 240
    while not list((out / "checkpoints").glob("step-0000004.ckpt")):  # the last step's checkpoint: evaluation follows
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    lines = message_lines(stderr)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert lines[-1].startswith("stopped: interrupted during the evaluation: training is done and saved in "), stderr
    assert "metrics.json was not written" in lines[-1] and not (out / "metrics.json").exists()
    command = shlex.split(lines[-1].partition("continue with: ")[2])
    assert command[0] == "splat-train" and command[-1] == "--resume", lines[-1]
    run_command("train", *command[1:], code=0)
    assert read_json(out / "metrics.json")["steps"] == 4


@pytest.mark.bad_input("SIGTERM (or Ctrl-C) during `splat-eval`",
                       "exit 130, one line: metrics.json unchanged, and the command to run again")
def test_sigterm_during_splat_eval_says_metrics_are_unchanged_and_the_command(run_dir, tmp_path):
    import shlex
    import shutil
    import time

    from cli_harness import cli_env
    from splat_framework.files.run_lock import LOCK_NAME

    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    before = (run / "metrics.json").read_bytes()
    proc = subprocess.Popen([sys.executable, "-m", "splat_framework.cli.eval", str(run), "--test-pose-steps", "500"],
                            env=cli_env(), text=True, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while not (run / LOCK_NAME).exists():  # it owns the run: whatever it does next, a stop leaves metrics.json as it was
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    lines = message_lines(stderr)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert lines[-1] == (f"stopped: interrupted during the evaluation: {run / 'metrics.json'} is unchanged (renders/ "
                         f"may hold some views of this evaluation); run it again: "
                         f"{shlex.join(['splat-eval', str(run), '--test-pose-steps', '500'])}"), stderr
    assert (run / "metrics.json").read_bytes() == before

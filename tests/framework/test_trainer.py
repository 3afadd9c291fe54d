"""Trainer basics on the tiny synthetic scene: run folder contents, learning, progress and summary."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest
import torch

from splat_framework.config import SCHEMA_VERSION, RunFacts, apply_overrides, read_config_json, save_config
from splat_framework.data import DataError, load_scene
from splat_framework.data.datamanager import view_bytes
from splat_framework.engine.run_folder import default_run_dir, prepare_run_dir
from splat_framework.engine.trainer import Trainer
from splat_framework.evaluation.held_out import evaluate
from splat_framework.pipeline import Pipeline
from splat_framework.pipeline.memory_plan import parse_bytes
from splat_framework.registry import get_method
from splat_framework.runtime.io import read_json
from splat_framework.sfm import resolve_data_path


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPLAT_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("SPLAT_IMAGE_MEMORY_BUDGET", raising=False)


def tiny_config(output, **top):
    cfg = get_method("3dgs").default_config()
    over = {"data": "synthetic/forward-tiny", "output": str(output), "model": {"init": {"num_points": 500}}}
    over.update(top)
    return apply_overrides(cfg, over)


def test_run_writes_documented_outputs_and_learns(tmp_path, capsys):
    run = tmp_path / "run"
    trainer = Trainer(tiny_config(run, steps=60, progress=True))
    dm = trainer.datamanager
    before = evaluate(trainer.model, dm, trainer.background)["mean"]["psnr"]
    metrics = trainer.train()
    out, err = capsys.readouterr()

    # config.json: schema version, the resolved config, a checksum that verifies
    payload = read_json(run / "config.json", require_checksum=True)
    assert payload["schema_version"] == SCHEMA_VERSION
    method, raw, _ = read_config_json(run / "config.json")
    assert method == "3dgs" and raw["steps"] == 60
    # checkpoints: the final one
    ckpts = sorted((run / "checkpoints").glob("step-*.ckpt"))
    assert ckpts and ckpts[-1].name == "step-0000060.ckpt"
    # metrics.json: documented keys, checksummed, equal to the returned dict
    m = read_json(run / "metrics.json", require_checksum=True)
    assert set(m["mean"]) >= {"psnr", "ssim", "lpips", "avg"}
    assert len(m["per_view"]) == dm.num_eval and all("psnr" in v for v in m["per_view"])
    assert m["timing"]["total_s"] > 0 and {"kernels_s", "data_s", "init_s", "train_s", "eval_s"} <= set(m["timing"])
    assert m["timing"]["total_s"] >= m["timing"]["kernels_s"] + m["timing"]["train_s"]  # the kernels' build counts
    assert m["rasterizer"] == trainer.rasterizer  # what rendered: the summary table's row too
    assert isinstance(m["num_gaussians"], int) and m["num_gaussians"] == trainer.model.num_gaussians
    assert m["skipped_steps"] == 0
    assert m["eval_split"] == "test"
    # the strategy's returned counts, summed over the run
    assert set(m["densified"]) == {"n_clone", "n_split", "n_prune"} and all(isinstance(v, int) for v in m["densified"].values())
    assert m["mean"]["psnr"] == pytest.approx(metrics["mean"]["psnr"])
    # renders
    pngs = list((run / "renders").glob("*.png"))
    assert len(pngs) >= dm.num_eval
    # learned something: beats the untrained model clearly
    assert math.isfinite(before)
    assert metrics["mean"]["psnr"] > before + 1.0, (before, metrics["mean"]["psnr"])
    # progress bar (stderr) and summary table (stdout)
    assert "60/60" in err and "gaussians" in err and "it/s" in err
    assert "test psnr" in out and "run folder" in out
    assert "Traceback" not in err


def test_metrics_and_summary_name_the_slowest_step_against_the_median(tmp_path, capsys, monkeypatch):
    """metrics.json's step_times: the median and the slowest of the process's steps after its
    first (which builds what later steps reuse), the slowest step counted from 1 as the progress
    bar counts; the summary table has a row for it."""
    import time

    slow_index = 6  # the 7th step sleeps, and so does the first (left out of the spread)
    real_step = Trainer.train_step

    def train_step(self, step):
        if step in (0, slow_index):
            time.sleep(0.4)
        return real_step(self, step)

    monkeypatch.setattr(Trainer, "train_step", train_step)
    m = Trainer(tiny_config(tmp_path / "run", steps=12)).train()
    st = m["step_times"]
    assert st["slowest_step"] == slow_index + 1
    assert st["max_s"] >= 0.4 > st["median_s"]
    assert st["max_over_median"] == pytest.approx(st["max_s"] / st["median_s"])
    assert read_json(tmp_path / "run" / "metrics.json", require_checksum=True)["step_times"] == st
    out = capsys.readouterr().out
    assert f"s at {slow_index + 1}, " in out and "slowest step" in out


@pytest.mark.bad_input("`splat-scene --out FILE`, `splat-export --out DIR`, `--data some/dir/..`", "exit 2 with one line; run folders never leave `outputs/`")
def test_default_run_dirs_are_new_timestamped_folders(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = get_method("3dgs").default_config().model_copy(update={"data": "synthetic/forward-tiny"})
    a = prepare_run_dir(cfg)
    (a / "config.json").write_text("{}")
    b = prepare_run_dir(cfg)  # same second: still a different folder
    assert a != b and a.parent == b.parent == Path("outputs") / "forward-tiny" / "3dgs"
    assert a.is_dir() and b.is_dir()
    assert not default_run_dir(cfg).exists()
    # the scene name comes from the resolved path: "--data some/dir/.." stays under outputs/
    (tmp_path / "some" / "dir").mkdir(parents=True)
    for data, scene in (("some/dir/..", "some"), ("some/dir/../..", tmp_path.name), ("/", "scene")):
        run = default_run_dir(cfg.model_copy(update={"data": data}))
        assert run.parts[:3] == ("outputs", scene, "3dgs") and ".." not in run.parts, run


@pytest.mark.bad_input("kill -9 during a checkpoint write", "partial `.tmp` files are removed when the run folder is opened again")
def test_run_folder_rules(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "step-0000010.ckpt").write_bytes(b"old")
    (run / "metrics.json").write_text("{}")
    (run / "notes.txt").write_text("keep me")
    cfg = get_method("3dgs").default_config().model_copy(update={"output": run})
    # a folder without a config.json that splat-train signed is not a run folder: never replaced
    for flags in ({}, {"overwrite": True}):
        with pytest.raises(DataError, match="not a run folder"):
            prepare_run_dir(cfg.model_copy(update=flags))
    save_config(cfg, run / "config.json")
    with pytest.raises(DataError, match="not empty.*--resume.*--overwrite"):
        prepare_run_dir(cfg)
    with pytest.raises(DataError, match="exclude"):
        prepare_run_dir(cfg.model_copy(update={"resume": True, "overwrite": True}))
    with pytest.raises(DataError, match="--output"):
        prepare_run_dir(cfg.model_copy(update={"resume": True, "output": None}))
    # partial files of a run killed mid-write (kill -9) are removed when the run starts again
    stale = [run / "checkpoints" / ".step-0000020.ckpt.ab12cd.tmp", run / ".metrics.json.x1y2.tmp"]
    for f in stale:
        f.write_bytes(b"\0" * 1000)
    assert prepare_run_dir(cfg.model_copy(update={"resume": True})) == run
    assert (run / "checkpoints" / "step-0000010.ckpt").exists()
    assert not any(f.exists() for f in stale) and (run / "notes.txt").exists()
    # --overwrite: the old run's config, checkpoints and metrics cannot leak into the new one
    prepare_run_dir(cfg.model_copy(update={"overwrite": True}))
    assert not (run / "checkpoints" / "step-0000010.ckpt").exists() and not (run / "metrics.json").exists()
    assert not (run / "config.json").exists() and (run / "notes.txt").read_text() == "keep me"
    # an empty folder is fine without flags
    empty = tmp_path / "empty"
    empty.mkdir()
    assert prepare_run_dir(cfg.model_copy(update={"output": empty})) == empty


def test_learning_rate_factor_does_not_compound(tmp_path):
    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    trainer.lr_factor = 0.5
    for step in (0, 1, 2, 3):
        trainer._set_learning_rates(step)
    base = trainer.model.learning_rates(3)
    for k, opt in trainer.optimizers.items():
        assert opt.param_groups[0]["lr"] == base[k] * 0.5


def test_a_model_loads_by_construction_then_restore(tmp_path, monkeypatch):
    from splat_framework.model.gaussians import GaussianModel

    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    payload = trainer.state_payload(0)
    built = []
    real_init = GaussianModel.__init__

    def spy(self, *args, **kwargs):
        built.append(kwargs.get("rows") is not None)
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(GaussianModel, "__init__", spy)
    monkeypatch.setattr(GaussianModel, "init_params", lambda *a: pytest.fail("a checkpoint is not initialised"))
    model = GaussianModel.from_checkpoint(trainer.config.model, RunFacts.of(trainer.config), trainer.model.scene_scale, payload)
    assert built == [True]  # normal construction, from the checkpoint's rows
    assert model.active_sh_degree == trainer.config.model.sh_degree
    for k, p in trainer.model.params.items():
        assert torch.equal(model.params[k], p.detach().cpu()) and model.params[k].requires_grad == p.requires_grad


def test_learning_rates_are_a_pure_function_of_the_step(tmp_path):
    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    model = trainer.model
    at_7 = model.learning_rates(7)
    for opt in trainer.optimizers.values():  # whatever the optimizers hold, the schedule does not read it
        for g in opt.param_groups:
            g["lr"] = 123.0
    assert model.learning_rates(7) == at_7
    assert model.learning_rates(0)["means"] > at_7["means"] > model.learning_rates(20)["means"]
    assert model.learning_rates(20)["means"] == pytest.approx(model.run.optim.means_lr_final * model.scene_scale)
    trainer._set_learning_rates(7)
    assert {k: o.param_groups[0]["lr"] for k, o in trainer.optimizers.items()} == at_7


def test_memory_budget_from_environment(tmp_path, monkeypatch):
    assert parse_bytes("1234") == 1234
    assert parse_bytes("2G") == 2 * 2**30 and parse_bytes("512M") == 512 * 2**20
    assert parse_bytes("1.5GiB") == int(1.5 * 2**30) and parse_bytes("3kb") == 3 * 1024
    with pytest.raises(DataError, match="SPLAT_IMAGE_MEMORY_BUDGET"):
        parse_bytes("lots")
    scene = load_scene(resolve_data_path("synthetic/forward-tiny"), views=3)
    one_view = view_bytes(scene, scene.train_indices[0])
    monkeypatch.setenv("SPLAT_IMAGE_MEMORY_BUDGET", str(2 * one_view + 10))
    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    dm = trainer.datamanager
    assert dm.lazy and 0 < len(dm._cache) < dm.num_train + dm.num_eval
    # on-demand views decode to the same pixels
    for cam, batch in dm.eval_views():
        assert batch["image"].shape == (cam.height, cam.width, 3)
    monkeypatch.setenv("SPLAT_IMAGE_MEMORY_BUDGET", "nonsense")
    with pytest.raises(DataError, match="SPLAT_IMAGE_MEMORY_BUDGET"):
        Trainer(tiny_config(tmp_path / "run2", steps=20, progress=False))


def test_impossible_memory_is_reported_before_training(tmp_path, monkeypatch, capsys):
    import splat_framework.pipeline.memory_plan as tr

    monkeypatch.setattr(tr, "physical_memory_bytes", lambda: 8 * 2**20)  # 8 MiB machine
    with pytest.raises(DataError, match="needs about .* of memory"):
        Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    # big enough for the Gaussians, but images above half the RAM: decoded on demand, with a warning
    img = 200 * 2**20
    monkeypatch.setattr(tr, "physical_memory_bytes", lambda: 10_000 * tr.BYTES_PER_GAUSSIAN * tr.DENSIFY_GROWTH + img)
    monkeypatch.setattr(tr, "estimate_image_bytes", lambda scene: img)
    monkeypatch.setattr(tr, "available_memory_bytes", lambda: None)
    trainer = Trainer(tiny_config(tmp_path / "run3", steps=20, progress=False))
    err = capsys.readouterr().err
    assert trainer.datamanager.memory_budget_bytes is not None
    warn = [line for line in err.splitlines() if "decoding the rest on demand" in line]
    assert len(warn) == 1


def test_config_json_checksum_detects_edits(tmp_path):
    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))
    path = trainer.run_dir / "config.json"
    payload = json.loads(path.read_text())
    assert payload["checksum"].startswith("sha256:")
    payload["config"]["seed"] = 123
    path.write_text(json.dumps(payload))
    with pytest.raises(DataError, match="checksum mismatch"):
        read_json(path)
    path.write_text(path.read_text()[:40])
    with pytest.raises(DataError, match="truncated or corrupt"):
        read_json(path)
    assert torch.isfinite(trainer.model.params["means"]).all()


def test_profiled_step_names_its_phases_and_costs_nothing_when_off(tmp_path):
    from splat_framework.runtime.profiling import exclusive, profiling, section

    with section("ignored"):  # off: a plain no-op
        pass
    trainer = Trainer(tiny_config(tmp_path / "run", steps=4, progress=False, checkpoint_every=2))
    trainer.train_step(0)
    trainer.save(1)
    before = {k: v.detach().clone() for k, v in trainer.model.params.items()}
    with profiling("cpu") as totals:
        trainer.train_step(1)
        with pytest.raises(RuntimeError, match="already on"):
            with profiling():
                pass
    for key in ("step", "step/forward/projection", "step/forward/binning", "step/forward/compositing",
                "step/loss/photometric", "step/backward/compositing backward", "step/backward/projection backward",
                "step/optimizer", "step/finiteness checks"):
        assert totals[key] > 0, key
    ex = exclusive(totals)
    assert sum(ex.values()) == pytest.approx(totals["step"], rel=1e-6)  # exclusive times partition the step
    assert all(v > -1e-9 for v in ex.values())
    assert "ignored" not in totals
    # a snapshot is loaded back exactly (the benchmark profiles from snapshots)
    trainer.train_step(2)
    assert trainer.load(trainer.checkpoint_dir / "step-0000001.ckpt") == 1
    assert all(torch.equal(before[k], v) for k, v in trainer.model.params.items())


def test_first_nonfinite_names_the_tensor():
    from splat_framework.engine.trainer import _first_nonfinite

    ok = torch.ones(3)
    assert _first_nonfinite({"a": ok, "b": None}) is None
    assert _first_nonfinite({"a": ok, "b": torch.tensor([1.0, float("nan")]), "c": torch.tensor([float("inf")])}) == "b"
    assert _first_nonfinite({}) is None
    big = torch.full((4,), 3e38)  # finite, but its sum overflows: the exact check names nothing
    assert _first_nonfinite({"a": big, "b": ok}) is None
    assert _first_nonfinite({"a": big, "b": torch.tensor([-float("inf"), float("inf")])}) == "b"


def test_the_render_settings_reach_the_model_and_the_environment_wins(tmp_path, monkeypatch):
    """The Trainer makes the render settings once (config, then SPLAT_COMPILE) and the model renders with them."""
    monkeypatch.delenv("SPLAT_COMPILE", raising=False)
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setenv("SPLAT_RASTERIZER", "torch")  # compiled, but no kernels to build or prove here
    assert get_method("3dgs").default_config().compile is True
    assert get_method("scgaussian").default_config().compile is True
    trainer = Trainer(tiny_config(tmp_path / "run", steps=20, progress=False))  # the default: compiled
    assert trainer.render_settings.compile and trainer.render_settings.rasterizer == "torch"
    assert trainer.model.render_settings is trainer.render_settings
    assert not trainer.model.absgrad  # the default strategy densifies on means2d.grad
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == str(Path(os.environ["SPLAT_CACHE"]) / "inductor")
    monkeypatch.setenv("SPLAT_COMPILE", "0")  # the environment wins
    assert not Trainer(tiny_config(tmp_path / "run2", steps=20, progress=False)).model.render_settings.compile
    monkeypatch.delenv("SPLAT_COMPILE")
    eager = Trainer(tiny_config(tmp_path / "run3", steps=20, progress=False, compile=False, strategy={"absgrad": True}))
    assert not eager.render_settings.compile
    assert eager.model.absgrad  # the strategy asks its training renders for AbsGS's sums
    eager.train_step(0)
    outputs = eager.model.get_outputs(eager.datamanager.train_view(0)[0], eager.background, step=1)
    outputs.rgb.sum().backward()
    assert outputs.meta["means2d"].absgrad.shape == outputs.meta["means2d"].shape


def test_trainer_checks_the_strategy_conventions(tmp_path, monkeypatch):
    """A model whose parameters and optimizers break the densification ops' conventions fails at start-up."""
    from splat_framework.model.gaussians import GaussianModel

    real = GaussianModel.make_optimizers
    monkeypatch.setattr(GaussianModel, "make_optimizers", lambda self: {k: v for k, v in real(self).items() if k != "quats"})
    with pytest.raises(ValueError, match="quats.*no optimizer"):
        Trainer(tiny_config(tmp_path / "run", steps=5, progress=False))


def test_the_config_picks_the_strategy_and_the_trainer_runs_any_strategy(tmp_path, monkeypatch):
    """The densification strategy is a seam: the config's strategy kind builds it (``setup``),
    any Strategy subclass (here one that counts its calls and never densifies) runs."""
    from splat_framework.config import DensifyConfig
    from splat_framework.model.strategy import DefaultStrategy, Strategy

    class Counting(Strategy):
        def __init__(self):
            self.calls = {"sanity": 0, "loss": 0, "pre": 0, "post": 0}

        def initialize_state(self, scene_scale=1.0):
            return {"scene_scale": scene_scale, "seen": 0}

        def check_sanity(self, params, optimizers):
            self.calls["sanity"] += 1

        def loss(self, params, step):  # a term the trainer adds to the model's loss
            self.calls["loss"] += 1
            return {"counting": 0.0 * params["opacities"].sum()}

        def step_pre_backward(self, params, optimizers, state, step, info):
            self.calls["pre"] += 1

        def step_post_backward(self, params, optimizers, state, step, info):
            self.calls["post"] += 1
            state["seen"] += 1
            return {"n_looked": 2, "n_moved": step % 2}  # what changed: summed into metrics.json

    assert isinstance(Trainer(tiny_config(tmp_path / "default", steps=4, progress=False)).strategy, DefaultStrategy)
    monkeypatch.setattr(DensifyConfig, "setup", lambda self: Counting())
    trainer = Trainer(tiny_config(tmp_path / "run", steps=12, progress=False))
    n0 = trainer.model.num_gaussians
    metrics = trainer.train()
    s = trainer.strategy
    assert isinstance(s, Counting) and s.calls == {"sanity": 1, "loss": 12, "pre": 12, "post": 12}
    assert metrics["densified"] == {"n_looked": 24, "n_moved": 6}  # the returned counts, summed over the run
    assert trainer.strategy_state["seen"] == 12 and trainer.model.num_gaussians == n0  # never densified
    clash = Counting()
    clash.loss = lambda params, step: {"photometric": params["opacities"].sum()}
    monkeypatch.setattr(DensifyConfig, "setup", lambda self: clash)
    with pytest.raises(ValueError, match=r"loss\(\) names \['photometric'\], which the model's loss already has"):
        Trainer(tiny_config(tmp_path / "clash", steps=4, progress=False)).train_step(0)
    monkeypatch.setattr(DensifyConfig, "setup", lambda self: object())
    with pytest.raises(TypeError, match=r"DensifyConfig.setup\(\) returned object, not a Strategy"):
        Trainer(tiny_config(tmp_path / "run2", steps=4, progress=False))


def test_a_model_hook_that_resizes_the_model_is_said_and_counted(tmp_path, monkeypatch, capsys):
    """When after_optimizer_step removes rows it returns the RowChange, which the strategy is given
    (rows_changed) to resize its own state; that step's densification is skipped (its screen-space
    statistics no longer line up): one note the first time, the count in metrics.json."""
    from splat_framework.model import ops
    from splat_framework.model.gaussians import GaussianModel
    from splat_framework.model.strategy import DefaultStrategy

    def drop_one_row(self, step, losses, optimizers):
        if step in (3, 6):
            mask = torch.zeros(self.num_gaussians, dtype=torch.bool)
            mask[-1] = True
            return ops.remove(self.params, optimizers, {}, mask)
        return None

    told = []
    real = DefaultStrategy.rows_changed

    def spy(self, params, opts, state, step, change):
        told.append((step, params["means"].shape[0], change.old_rows, change.new_rows))
        real(self, params, opts, state, step, change)

    monkeypatch.setattr(GaussianModel, "after_optimizer_step", drop_one_row)
    monkeypatch.setattr(DefaultStrategy, "rows_changed", spy)
    capsys.readouterr()
    trainer = Trainer(tiny_config(tmp_path / "run", steps=10, progress=False))
    n0 = trainer.model.num_gaussians
    metrics = trainer.train()
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "densification skips" in ln]
    assert len(notes) == 1 and "step 3" in notes[0], notes
    assert metrics["densify_skipped_steps"] == 2
    assert told == [(3, n0 - 1, n0, n0 - 1), (6, n0 - 2, n0 - 1, n0 - 2)]  # told after the rows changed
    state = trainer.strategy_state
    assert all(state[k] is None or state[k].shape[0] == trainer.model.num_gaussians for k in ("grad2d", "count", "radii"))


def test_a_model_hook_must_say_how_the_rows_changed(tmp_path, monkeypatch):
    """A hook that resizes the rows without returning the RowChange (or returning a wrong one) stops
    the run with a message naming the hook and the counts: the strategy's state would silently
    no longer line up with the rows."""
    from splat_framework.model import ops
    from splat_framework.model.gaussians import GaussianModel

    def silent(self, step, losses, optimizers):
        ops.remove(self.params, optimizers, {}, torch.arange(self.num_gaussians) == 0)

    monkeypatch.setattr(GaussianModel, "after_optimizer_step", silent)
    trainer = Trainer(tiny_config(tmp_path / "run", steps=4, progress=False))
    n = trainer.model.num_gaussians
    with pytest.raises(ValueError, match=rf"GaussianModel.after_optimizer_step changed the Gaussians \({n} -> {n - 1}\) "
                                         "but returned None"):
        trainer.train_step(0)

    def wrong(self, step, losses, optimizers):
        change = ops.remove(self.params, optimizers, {}, torch.arange(self.num_gaussians) == 0)
        return ops.RowChange(change.kept, added=1)

    monkeypatch.setattr(GaussianModel, "after_optimizer_step", wrong)
    with pytest.raises(ValueError, match=rf"returned a RowChange of {n - 1} -> {n - 1}, but the Gaussians went "
                                         rf"{n - 1} -> {n - 2}"):
        trainer.train_step(1)


def test_the_model_declares_its_batch_fields(tmp_path, monkeypatch):
    """The data manager makes the optional batch fields the method's model class declares
    (``batch_fields``), not what the trainer guesses from the config; a field no data manager
    makes is refused in one line naming it."""
    from splat_framework.model.gaussians import GaussianModel

    assert GaussianModel.batch_fields(tiny_config(tmp_path / "a").model) == frozenset()
    assert GaussianModel.batch_fields(tiny_config(tmp_path / "b", model={"reg": {"backdrop_weight": 0.5}}).model) == {"backdrop"}
    monkeypatch.setattr(GaussianModel, "batch_fields", classmethod(lambda cls, config: frozenset({"normals"})))
    with pytest.raises(ValueError, match=r"DataManager makes no batch field \['normals'\]"):
        Trainer(tiny_config(tmp_path / "run", steps=2, progress=False))


def test_backdrop_loss_makes_the_backdrop_empty_and_black(tmp_path):
    """With a ``backdrop`` mask in the batch: its mean rendered alpha is a loss term whose
    gradient lowers opacities, and the photometric target is black there; weight 0 (the default) turns it off."""
    model_options = {"init": {"num_points": 500}, "reg": {"backdrop_weight": 1.0}}
    trainer = Trainer(tiny_config(tmp_path / "run", steps=1, progress=False, model=model_options))
    model = trainer.model
    cam, batch = trainer.datamanager.next_train(0)
    back = torch.zeros_like(batch["image"][..., :1])
    back[: back.shape[0] // 2] = 1.0
    out = model.get_outputs(cam, trainer.background)
    losses = model.get_loss_dict(out, batch | {"backdrop": back}, cam, 0)
    mean_alpha = float((out.alpha * back).sum() / back.sum())
    assert mean_alpha > 0.1 and float(losses["backdrop"]) == pytest.approx(mean_alpha, rel=1e-5)
    black = model.get_loss_dict(out, batch | {"image": batch["image"] * (1 - back)}, cam, 0)
    assert float(losses["photometric"]) == pytest.approx(float(black["photometric"]), rel=1e-6)
    losses["backdrop"].backward()
    assert float(model.params["opacities"].grad.sum()) > 0  # gradient descent lowers opacity

    off = model.config.reg.model_copy(update={"backdrop_weight": 0.0})
    assert type(off)().backdrop_weight == 0.0  # the default
    model.config = model.config.model_copy(update={"reg": off})
    assert set(model.get_loss_dict(out, batch | {"backdrop": back}, cam, 0)) == {"photometric"}


def test_the_training_step_renders_with_drop_gaussian_and_evaluation_without(tmp_path, monkeypatch):
    """``model.reg.drop_rate``: the trainer's step renders with its ``step`` (some Gaussians
    dropped, the same ones when the run is repeated); a render after the step draws all of them."""
    drawn = []

    def run(name):
        trainer = Trainer(tiny_config(tmp_path / name, steps=4, progress=False, model={"init": {"num_points": 500}, "reg": {"drop_rate": 0.9}}))
        model = trainer.model
        render = model.get_outputs

        def spy(camera, background=None, step=None):
            ones = torch.ones(model.num_gaussians)
            drawn.append(model.drop_opacities(ones, step))
            return render(camera, background, step=step)

        monkeypatch.setattr(model, "get_outputs", spy)
        assert trainer.train_step(3) is not None
        model.get_outputs(trainer.datamanager.next_train(0)[0])
        return drawn[-2:]

    step, after = run("a")
    assert (step == 0).float().mean() == pytest.approx(0.9 * 3 / 4, abs=0.1) and torch.all(after == 1)
    assert torch.equal(step, run("b")[0])


def test_coarse_steps_train_on_area_averaged_images_with_cameras_scaled_to_match(tmp_path, monkeypatch, capsys):
    """``coarse_steps``: the steps before it render the training view resized by ``coarse_scale``
    (each axis by its own ratio) against the image averaged over each coarse pixel's area; later
    steps render the view as it is."""
    # a schedule field, set by the user: kept as set with --steps 6
    trainer = Trainer(tiny_config(tmp_path / "run", steps=6, progress=False, coarse_steps=3, coarse_scale=0.5))
    assert trainer.config.coarse_steps == 3
    model, dm = trainer.model, trainer.datamanager
    render = model.get_outputs
    seen = []

    def spy(camera, background=None, step=None):
        seen.append((step, camera))
        return render(camera, background, step=step)

    monkeypatch.setattr(model, "get_outputs", spy)
    for step in range(6):
        assert trainer.train_step(step) is not None
    full, batch = dm.next_train(0)
    coarse, small = dm.coarse_view(full, batch, 0.5)
    w, h = round(full.width * 0.5), round(full.height * 0.5)
    assert (coarse.width, coarse.height) == (w, h) and small["image"].shape == (h, w, 3)
    assert [cam.width for _, cam in seen] == [w, w, w, full.width, full.width, full.width]
    assert "step 3: the 3 coarse steps (images at 0.5x) are done" in capsys.readouterr().err
    # a coarse camera sees a world point where the full one does, at its own pixel size
    point = full.cam_to_world @ torch.tensor([0.1, -0.05, 3.0, 1.0])
    uv_full, _ = full.project(point[None, :3])
    uv_coarse, _ = coarse.project(point[None, :3])
    assert torch.allclose(uv_coarse, uv_full * torch.tensor([w / full.width, h / full.height]), atol=1e-4)
    # the coarse image is the area average of the full one (checked on 2x2 blocks where they are whole)
    img = batch["image"]
    blocks = img[: 2 * (img.shape[0] // 2), : 2 * (img.shape[1] // 2)]
    blocks = blocks.reshape(img.shape[0] // 2, 2, img.shape[1] // 2, 2, 3).mean((1, 3))
    if img.shape[0] % 2 == 0 and img.shape[1] % 2 == 0:
        assert torch.allclose(small["image"], blocks, atol=1e-6)
    assert dm.coarse_view(full, batch, 0.5)[1]["image"] is small["image"]  # made once, then kept


class HundredPointsPipeline(Pipeline):
    """A pipeline that builds its model differently: from 100 init points, whatever the config says."""

    def build_model(self, generator):
        init = self.config.model.init.model_copy(update={"num_points": 100})
        return self.model_class.from_data(self.config.model.model_copy(update={"init": init}), self.run_facts,
                                          self.datamanager, generator)


def test_methods_run_through_their_pipeline_which_builds_the_data_and_model_and_a_foreign_class_is_refused(tmp_path):
    """3dgs names no pipeline of its own: the trainer drives the framework's Pipeline, which built the
    data manager and the model; SCGaussian's subclasses it (the baseline schedule); a subclass that
    builds its model differently trains; a spec naming a class that is not a Pipeline stops the run
    with its name."""
    import dataclasses

    from scg_plugin.pipeline import SCGaussianPipeline
    from splat_framework.errors import PluginError

    assert get_method("3dgs").pipeline_class() is Pipeline
    assert get_method("scgaussian").pipeline_class() is SCGaussianPipeline
    spec = get_method("3dgs")
    cfg = spec.default_config().model_copy(update=dict(data="synthetic/forward-tiny", steps=2, output=tmp_path / "a",
                                                       progress=False, save_renders=False))
    trainer = Trainer(cfg, spec=spec)
    assert type(trainer.pipeline) is Pipeline and trainer.config is trainer.pipeline.config
    assert trainer.pipeline.model is trainer.model and trainer.pipeline.datamanager is trainer.datamanager
    assert trainer.model.init_stats["num_points"] == cfg.model.init.num_points != 100
    trainer.release()
    own = dataclasses.replace(spec, pipeline=f"{__name__}:HundredPointsPipeline")
    trainer = Trainer(cfg.model_copy(update={"output": tmp_path / "c"}), spec=own)
    metrics = trainer.train()
    assert metrics["init_stats"]["num_points"] == 100 and trainer.model.config.init.num_points == 100
    assert cfg.model.init.num_points == trainer.config.model.init.num_points  # config.json keeps the run's config
    wrong = dataclasses.replace(spec, pipeline="splat_framework.model.gaussians:GaussianModel")
    with pytest.raises(PluginError, match="pipeline 'splat_framework.model.gaussians:GaussianModel' is not a Pipeline"):
        Trainer(cfg.model_copy(update={"output": tmp_path / "b"}), spec=wrong)

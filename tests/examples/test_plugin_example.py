"""The example plugin package in examples/ installs and trains through the public entry point; its own
tests (examples/splat-example-plugin/tests) pass from outside the repository."""

import os
import subprocess
import sys

import pytest

from cli_harness import run_cli
from support import REPO
from tiers import seed_kernels

EXAMPLE = REPO / "examples" / "splat-example-plugin"


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory):
    site = tmp_path_factory.mktemp("site")
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target", str(site), str(EXAMPLE)],
        capture_output=True, text=True, timeout=300,
    )
    if r.returncode != 0:
        pytest.fail(f"installing the example plugin failed: {r.stderr[-2000:]}")
    return site


def _env(site, tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    env["SPLAT_CACHE"] = str(seed_kernels(tmp_path / "cache"))
    env["SPLAT_INSTALLED_PLUGINS"] = "on"  # installed into site: its entry points are what these tests are about
    return env


def test_the_example_plugins_own_tests_pass_from_outside_the_repository(plugin_site, tmp_path):
    """examples/splat-example-plugin/tests (its method trains and prunes, its start starts 3dgs and
    resumes, its MCMC split rule), written against splat_framework.plugin and splat_framework.testing
    only, pass as its author runs them: the package installed, pytest started in another folder."""
    env = _env(plugin_site, tmp_path) | {"PYTHONDONTWRITEBYTECODE": "1"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(EXAMPLE / "tests")],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert r.returncode == 0 and "5 passed" in r.stdout, r.stdout[-3000:] + r.stderr[-2000:]


def test_example_plugin_widens_the_strategy_union(plugin_site, tmp_path):
    """The plugin's config accepts its own strategy kind and the framework's; a variant switches
    kind with ``kind = ...`` (the other kind's defaults, not the old kind's fields); others are refused."""
    code = """
import pydantic
from splat_framework.config import DensifyConfig, apply_overrides
from splat_framework.model.strategy import DefaultStrategy
from splat_framework.registry import get_method
from splat_example_plugin import PruneOnlyConfig
from splat_example_plugin.model import PruneOnlyStrategy

base = get_method("flat-3dgs").default_config()
assert isinstance(base.strategy, PruneOnlyConfig) and isinstance(base.strategy.setup(), PruneOnlyStrategy)
assert base.strategy.setup().every == base.strategy.every  # built from its strategy_class, "module:Class"
switched = apply_overrides(base, {"strategy": {"kind": "default", "reset_every": 7}})
assert isinstance(switched.strategy, DensifyConfig) and switched.strategy.reset_every == 7
assert type(switched.strategy.setup()) is DefaultStrategy
assert type(base).model_validate_json(switched.model_dump_json()) == switched  # what resume reads
try:
    apply_overrides(base, {"strategy": {"kind": "ray-gaussian"}})
except pydantic.ValidationError as e:
    assert "'prune-only', 'default'" in str(e), str(e)
else:
    raise AssertionError("a kind the method does not list must be refused")
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(plugin_site, tmp_path), timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-3000:]


MCMC_RUN = """
import json, sys
from splat_framework.cli.train import entrypoint, main

try:  # the plugin kind's flags in --help, without torch
    main(["3dgs", "--strategy.kind", "mcmc", "--help"])
except SystemExit:
    pass
assert "torch" not in sys.modules, "--help imported torch"
from splat_framework.engine import trainer
from splat_example_plugin.mcmc import MCMCStrategy

seen, counts = [], []
train_step, post = trainer.Trainer.train_step, MCMCStrategy.step_post_backward
trainer.Trainer.train_step = lambda self, step: seen.append(train_step(self, step)) or seen[-1]
MCMCStrategy.step_post_backward = lambda self, *a: counts.append(post(self, *a)) or counts[-1]
sys.argv = ["splat-train", *sys.argv[1:]]
try:
    entrypoint()
except SystemExit as e:
    assert not e.code, e.code
losses = seen[-1][0]
assert {"mcmc_opacity", "mcmc_scale"} <= set(losses), losses  # the strategy's loss terms, summed by the trainer
assert abs(losses["loss"] - sum(v for k, v in losses.items() if k != "loss")) < 1e-6 * max(1.0, losses["loss"])
print(json.dumps({"relocated": sum(c.get("n_relocate", 0) for c in counts), "added": sum(c.get("n_add", 0) for c in counts)}))
"""


def test_plugin_strategy_trains_3dgs(plugin_site, tmp_path):
    """``splat-train 3dgs --strategy.kind mcmc``, from outside the repository: the plugin's MCMC strategy
    (entry-point group splat_framework.strategies) relocates dead Gaussians, adds more and adds its
    regularisers to 3dgs's loss; the run's config.json names the kind and reads back."""
    out = tmp_path / "run"
    args = ["3dgs", "--strategy.kind", "mcmc", "--data", "synthetic/forward-tiny", "--steps", "20",
            "--output", str(out), "--no-progress", "--model.init.num-points", "1000",
            # refine at steps 5, 10, 15; the start's opacity is 0.1, so what the regulariser pushes below it is dead
            "--strategy.refine-every", "5", "--strategy.min-opacity", "0.0999"]
    r = subprocess.run([sys.executable, "-c", MCMC_RUN, *args], capture_output=True, text=True,
                       env=_env(plugin_site, tmp_path), cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    import json

    assert "--strategy.noise-lr" in r.stdout and "--strategy.grow-grad2d" not in r.stdout  # --help: mcmc's flags
    changed = json.loads(r.stdout.strip().splitlines()[-1])
    assert changed["relocated"] > 0 and changed["added"] > 0, changed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["strategy"] == "splat_example_plugin.mcmc.MCMCStrategy"
    assert metrics["num_gaussians"] == 1000 + changed["added"]
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["method"] == "3dgs" and cfg["strategy"]["kind"] == "mcmc" and cfg["strategy"]["refine_every"] == 5
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", *args, "--resume"], capture_output=True,
                       text=True, env=_env(plugin_site, tmp_path), cwd=tmp_path, timeout=600)
    assert r.returncode == 0 and "resumed from" in r.stdout + r.stderr, r.stderr[-3000:]  # the same experiment, read back


@pytest.mark.bad_input("a strategy kind the method does not accept (scgaussian --strategy.kind mcmc) or no registered one",
                       "exit 2, one line naming strategy.kind and what the method accepts")
def test_narrowed_method_refuses_a_plugin_strategy(plugin_site, tmp_path):
    """SCGaussian accepts only its ray-keeping strategy, even with a plugin kind registered; a kind
    nobody registered is named with the registered ones."""
    env = _env(plugin_site, tmp_path)
    run_cli("train", "scgaussian", "--strategy.kind", "mcmc", "--data", "synthetic/forward-tiny",
            "--output", str(tmp_path / "scg"), env=env, match=("--strategy.kind", "'mcmc' is not one of ray-gaussian"), watch=[tmp_path],
            allowed=[tmp_path / "cache"])
    run_cli("train", "3dgs", "--strategy.kind", "nope", "--data", "synthetic/forward-tiny",
            "--output", str(tmp_path / "3dgs"), env=env, match="--strategy.kind: 'nope' is not one of default, mcmc")


def test_the_plugins_table_is_its_pyproject_entry_points():
    """The example declares its parts once: ENTRY_POINTS in its package is what its pyproject.toml's
    entry points hold (the installed path and the SPLAT_PLUGINS path register the same parts)."""
    import ast
    import tomllib

    declared = (EXAMPLE / "pyproject.toml").read_text()
    entry_points = tomllib.loads(declared)["project"]["entry-points"]
    tree = ast.parse((EXAMPLE / "src" / "splat_example_plugin" / "__init__.py").read_text())
    table = next(ast.literal_eval(n.value) for n in tree.body
                 if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", None) == "ENTRY_POINTS")
    assert table == entry_points


def test_a_plugin_registers_a_strategy_and_a_start_without_installing(tmp_path):
    """``SPLAT_PLUGINS=splat_example_plugin`` with its ``src/`` on PYTHONPATH, nothing installed: 3dgs
    trains with the plugin's MCMC strategy and its lattice start, as an installed plugin's would."""
    import json

    from cli_harness import cli_env

    path = os.pathsep.join(p for p in (str(EXAMPLE / "src"), os.environ.get("PYTHONPATH")) if p)
    env = cli_env(PYTHONPATH=path, SPLAT_PLUGINS="splat_example_plugin", SPLAT_COMPILE="0")
    out = tmp_path / "run"
    run_cli("train", "3dgs", "--strategy.kind", "mcmc", "--model.init.kind", "grid", "--model.init.per-axis", "8",
            "--data", "synthetic/forward-tiny", "--steps", "10", "--strategy.refine-every", "5",
            "--no-progress", "--no-save-renders", "--output", out, code=0, env=env)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["strategy"] == "splat_example_plugin.mcmc.MCMCStrategy"
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["strategy"]["kind"] == "mcmc" and cfg["model"]["init"] == {"kind": "grid", "per_axis": 8}
    listed = run_cli("train", "--help", code=0, env=env).stdout  # its variant, from its configs package
    assert "flat-3dgs-often" in listed


def test_the_plugins_photo_matcher_is_registered_without_installing(monkeypatch):
    """The example's ORB matcher, registered through SPLAT_PLUGINS, finds a photo's texture again in a
    copy shifted by 7 pixels: every match 7 pixels apart, in continuous pixel coordinates."""
    import numpy as np

    from splat_framework.sfm.photo_matchers import photo_matchers

    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    monkeypatch.setenv("SPLAT_PLUGINS", "splat_example_plugin")
    match_photos = photo_matchers()["orb"].load()
    rng = np.random.default_rng(0)
    texture = (rng.random((30, 40)) * 255).astype(np.uint8).repeat(8, axis=0).repeat(8, axis=1)
    photo = np.stack([texture] * 3, axis=-1)
    found = match_photos([photo[:, :-7], photo[:, 7:]])
    pts_a, pts_b = found[(0, 1)]
    assert len(pts_a) > 50 and pts_a.shape == pts_b.shape and pts_a.shape[1] == 2
    shift = pts_a - pts_b
    assert np.median(shift[:, 0]) == pytest.approx(7, abs=0.5) and np.median(np.abs(shift[:, 1])) < 0.5


def test_the_plugins_two_view_pipeline_trains(monkeypatch, tmp_path):
    """``two-view-3dgs`` names its own Pipeline in its MethodSpec: each step renders two training
    views (the step's and its neighbour in the training order) and its loss has the second view's
    term; the run trains to the end and is evaluated through the same pipeline."""
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    monkeypatch.setenv("SPLAT_PLUGINS", "splat_example_plugin")
    from splat_framework.plugin import GaussianModel
    from splat_framework.testing import Trainer, get_method

    spec = get_method("two-view-3dgs")
    cfg = spec.default_config().model_copy(update=dict(
        data="synthetic/forward-tiny", steps=6, output=tmp_path / "run", progress=False, save_renders=False))
    trainer = Trainer(cfg, spec=spec)
    assert type(trainer.pipeline).__name__ == "TwoViewPipeline" and trainer.pipeline.model is trainer.model
    renders = []
    monkeypatch.setattr(GaussianModel, "get_outputs",
                        lambda self, camera, *a, _f=GaussianModel.get_outputs, **k: renders.append(camera) or _f(self, camera, *a, **k))
    losses, _ = trainer.train_step(0)
    assert len(renders) == 2 and renders[0] is not renders[1] and losses["second_view"] > 0
    assert float(losses["loss"]) == pytest.approx(sum(float(v) for k, v in losses.items() if k != "loss"), rel=1e-5)
    metrics = trainer.train()
    assert metrics["method"] == "two-view-3dgs" and metrics["mean"]["psnr"] > 5

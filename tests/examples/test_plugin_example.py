"""The example plugin package in examples/ installs and trains through the public entry point."""

import os
import subprocess
import sys

import pytest
from support import REPO

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
    env["SPLAT_CACHE"] = str(tmp_path / "cache")
    return env


def test_example_plugin_is_listed_and_trains(plugin_site, tmp_path):
    env = _env(plugin_site, tmp_path)
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "--help"], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0 and "flat-3dgs" in r.stdout
    out = tmp_path / "run"
    r = subprocess.run(
        [sys.executable, "-m", "splat_framework.cli.train", "flat-3dgs", "--data", "synthetic/forward-tiny",
         "--steps", "20", "--output", str(out), "--no-progress",
         # the plugin's PruneOnlyStrategy: at step 10, drop Gaussians whose opacity sank below the start's 0.1
         "--strategy.every", "10", "--strategy.min-opacity", "0.1", "--model.init.num-points", "2000"],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert (out / "metrics.json").is_file()
    import json

    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["method"] == "flat-3dgs" and cfg["model"]["sh_degree"] == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["strategy"] == "splat_example_plugin.model.PruneOnlyStrategy"
    n = metrics["num_gaussians"]
    assert 0 < n < 2000, f"the plugin's strategy prunes and never grows: {n} Gaussians from 2000"


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

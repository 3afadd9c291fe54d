"""The minimal plugin docs/extending.md opens with (examples/minimal_plugin) trains through the CLI,
registered only by ``SPLAT_PLUGINS``: its method, its model's extra loss term and its strategy."""

import json
import os

from cli_harness import cli_env, run_cli
from support import REPO

MINIMAL = REPO / "examples" / "minimal_plugin"


def test_the_minimal_plugin_trains_through_splat_plugins(tmp_path):
    """``SPLAT_PLUGINS=my_plugin``, nothing installed: ``my-method`` trains on forward-tiny with its
    ``my-prune`` strategy, which runs at every step and removes the Gaussians below its opacity."""
    path = os.pathsep.join(p for p in (str(MINIMAL), os.environ.get("PYTHONPATH")) if p)
    env = cli_env(PYTHONPATH=path, SPLAT_PLUGINS="my_plugin", SPLAT_COMPILE="0")
    listed = run_cli("train", "my-method", "--help", "strategy", code=0, env=env).stdout
    assert "--strategy.min-opacity" in listed
    out = tmp_path / "run"
    # the init's opacity is 0.1: a Gaussian whose opacity fell after a step is below it and removed
    run_cli("train", "my-method", "--data", "synthetic/forward-tiny", "--steps", "6", "--model.init.num-points", "2000",
            "--strategy.min-opacity", "0.1", "--no-progress", "--no-save-renders", "--output", out, code=0, env=env)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["method"] == "my-method" and metrics["strategy"] == "my_plugin.model.MyPruneStrategy"
    pruned = metrics["densified"]["n_prune"]
    assert 0 < pruned < 2000 and metrics["num_gaussians"] == 2000 - pruned
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["strategy"] == {"kind": "my-prune", "enabled": True, "min_opacity": 0.1}

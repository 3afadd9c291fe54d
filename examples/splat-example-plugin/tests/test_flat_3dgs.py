"""flat-3dgs, the plugin's method: listed by ``splat-train --help``, trained, pruned by its own strategy."""

import json

from splat_framework.testing import run_cli


def test_flat_3dgs_is_listed_and_trains_and_its_strategy_only_prunes(splat, tmp_path):
    env, data = splat
    assert "flat-3dgs" in run_cli("train", "--help", code=0, env=env).stdout
    out = tmp_path / "run"
    # the plugin's PruneOnlyStrategy: at step 10, drop Gaussians whose opacity sank below the start's 0.1
    run_cli("train", "flat-3dgs", "--data", data, "--steps", "20", "--output", out, "--no-progress",
            "--strategy.every", "10", "--strategy.min-opacity", "0.1", "--model.init.num-points", "2000", code=0, env=env)
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["method"] == "flat-3dgs" and cfg["model"]["sh_degree"] == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["strategy"] == "splat_example_plugin.model.PruneOnlyStrategy"
    assert 0 < metrics["num_gaussians"] < 2000, f"the strategy prunes and never grows: {metrics['num_gaussians']} from 2000"

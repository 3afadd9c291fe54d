"""The plugin's init kind ``grid``: any method that takes registered init kinds is initialised from its lattice."""

import json

from splat_framework.testing import run_cli


def test_a_grid_start_has_its_own_flags_starts_3dgs_and_resumes(splat, tmp_path):
    env, data = splat
    out = tmp_path / "run"
    args = ["3dgs", "--model.init.kind", "grid", "--model.init.per-axis", "6", "--strategy.no-enabled",
            "--data", data, "--steps", "3", "--output", out, "--no-progress"]
    shown = run_cli("train", *args[:5], "--help", code=0, env=env).stdout
    assert "--model.init.per-axis" in shown and "--model.init.num-points" not in shown
    run_cli("train", *args, code=0, env=env, cwd=tmp_path)
    assert json.loads((out / "metrics.json").read_text())["num_gaussians"] == 6**3
    assert json.loads((out / "config.json").read_text())["config"]["model"]["init"] == {"kind": "grid", "per_axis": 6}
    resumed = run_cli("train", *args, "--resume", code=0, env=env, cwd=tmp_path)
    assert "resumed from" in resumed.stdout + resumed.stderr

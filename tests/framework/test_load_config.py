"""``splat-train --load-config RUN/config.json [overrides]``: a saved experiment trained again into a
new folder, through the CLI (issue 42)."""

from __future__ import annotations

import json

import pytest
from cli_harness import run_cli

from splat_framework.config import read_config_json, save_config


def test_load_config_reruns_the_saved_experiment_with_overrides_into_a_new_folder(run_dir, tmp_path):
    method, saved, _ = read_config_json(run_dir / "config.json")
    new = tmp_path / "again"
    result = run_cli("train", "--load-config", run_dir / "config.json", "--steps", "2", "--seed", "3",
                     "--output", new, "--no-progress", code=0, watch=[run_dir])
    assert "error" not in result.stderr.lower()
    _, again, _ = read_config_json(new / "config.json")
    assert (again["method"], again["seed"], again["steps"]) == (method, 3, 2)  # the file's method, the overrides
    assert again["model"]["init"] == saved["model"]["init"]  # the rest is the saved experiment's
    assert again["data"] == saved["data"] and again["optim"] == saved["optim"]
    assert (new / "metrics.json").is_file()


def test_load_config_takes_no_run_options_from_the_file(run_dir):
    from splat_framework.cli.train import load_saved_experiment
    from splat_framework.registry import discover_methods

    method, config = load_saved_experiment(str(run_dir / "config.json"), discover_methods())
    _, saved, _ = read_config_json(run_dir / "config.json")
    assert method == "3dgs" and saved["output"] is not None and saved["overwrite"]
    assert config.output is None and not config.overwrite and not config.resume  # a new folder, never the old one
    assert config.seed == saved["seed"] and config.model.init.num_points == saved["model"]["init"]["num_points"]


@pytest.mark.bad_input("`splat-train --load-config` of a missing, unreadable or foreign file, or naming another method",
                       "exit 2, one line naming the file; nothing written")
def test_load_config_of_a_bad_file_is_one_line(run_dir, tmp_path):
    run_cli("train", "--load-config", tmp_path / "missing.json", code=2, match=("missing.json", "no such file"),
            watch=[tmp_path])
    (tmp_path / "notes.json").write_text("not json at all")
    run_cli("train", "--load-config", tmp_path / "notes.json", code=2, match="notes.json", watch=[tmp_path])
    (tmp_path / "other.json").write_text(json.dumps({"hello": 1}))
    run_cli("train", "--load-config", tmp_path / "other.json", code=2, match="other.json", watch=[tmp_path])
    run_cli("train", "--load-config", run_dir / "config.json", "scaffold-gs", code=2,
            match=("'3dgs'", "leave out 'scaffold-gs'"), watch=[tmp_path, run_dir])
    # a config.json of a method no longer registered
    _, raw, _ = read_config_json(run_dir / "config.json")
    from splat_framework.registry import get_method

    config = type(get_method("3dgs").default_config()).model_validate(raw)
    save_config(config.model_copy(update={"method": "3dgs-gone"}), tmp_path / "gone.json")
    run_cli("train", "--load-config", tmp_path / "gone.json", code=2, match=("gone.json", "'3dgs-gone' is not registered"),
            watch=[tmp_path], allowed=[])

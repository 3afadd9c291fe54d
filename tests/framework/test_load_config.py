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


# The matching block of every config.json written before each matcher had a config of its own:
# one flat block of every matcher's fields, tagged by ``matcher`` (values: those versions' defaults).
FLAT_MATCHING = {
    "matcher": "auto", "auto_flow_max_angle": 15.0, "auto_min_matches": 1000, "auto_guided_flow_max_views": 4,
    "max_matches": 12000, "grid_cell": 16, "sift_features": 8000, "ratio": 0.8, "sift_upscale": 2.0,
    "dense_preset": "medium", "dense_upscale": 4.0, "fb_threshold": 1.0, "dense_oversample": 3.0,
    "min_texture": 1e-06, "min_confidence": 0.0, "max_keypoints": 2048, "learned_resize": 1024,
    "magsac_threshold": 1.0, "magsac_confidence": 0.999, "alpha_mask": True, "epipolar_check": True,
    "epipolar_threshold": 2.0, "seed": 0, "weights": None, "device": "cpu", "cache": True,
}


@pytest.mark.parametrize("variant, edits", [("scgaussian", {"max_matches": 3000}),
                                            ("scgaussian-sift", {"ratio": 0.7, "grid_cell": 8}),
                                            ("scgaussian-disk-lightglue", {"max_keypoints": 1024}),
                                            ("3dgs-triang", {"dense_upscale": 2.0})])
def test_a_flat_matching_block_of_an_old_run_loads_as_its_matchers_config(variant, edits, tmp_path):
    """An old run's ``matching`` block (one flat block, ``matcher`` its tag) is today's config of that
    matcher, its values kept and the other matchers' fields (never read by it) dropped; --load-config
    of that run gives the experiment the run trained."""
    from splat_framework.cli.train import load_saved_experiment
    from splat_framework.config import apply_overrides, experiment_fields
    from splat_framework.registry import discover_methods
    from splat_framework.runtime.io import atomic_write_json

    methods = discover_methods()
    config = methods[variant].default_config()
    at = ("model", "init") if variant.endswith("-triang") else ("model",)
    block = config.model.init.matching if variant.endswith("-triang") else config.model.matching
    config = apply_overrides(config, {at[0]: {at[1]: {"matching": edits}} if len(at) == 2 else {"matching": edits}})
    save_config(config, tmp_path / "config.json")
    payload = json.loads((tmp_path / "config.json").read_text())
    section = payload["config"]
    for key in at:
        section = section[key]
    section["matching"] = FLAT_MATCHING | {"matcher": block.kind} | edits  # as the old versions wrote it
    payload["schema_version"] = 1  # the version those files carry
    payload.pop("checksum")
    atomic_write_json(tmp_path / "config.json", payload)  # signed, as those versions signed it
    method, loaded = load_saved_experiment(str(tmp_path / "config.json"), methods)
    keep = experiment_fields(type(config))
    got, want = loaded.model_dump(include=keep), config.model_dump(include=keep)
    budgets, guided = [], []
    for dump in (got, want):
        for key in at:
            dump = dump[key]
        budgets.append(dump["matching"].pop("max_total_matches"))
        guided.append(dump["matching"].pop("auto_guided_flow_max_views", "n/a"))
    assert got == want and budgets == [0, block.max_total_matches]  # those versions had no total budget (schema 4)
    # the run's own view limit of guided flow is kept (today's default: any number of views)
    assert guided == ([4, None] if block.kind == "auto" else ["n/a", "n/a"])
    matching = loaded.model.init.matching if variant.endswith("-triang") else loaded.model.matching
    assert type(matching) is type(block) and all(getattr(matching, k) == v for k, v in edits.items())


@pytest.mark.bad_input("`splat-train --load-config` of an edited or unsigned config.json; one nested thousands deep",
                       "exit 2, one line naming the file and `--trust-edited-config`, which then loads it; "
                       "deep nesting: one line naming the file")
def test_load_config_of_an_edited_file_needs_and_takes_trust_edited_config(run_dir, tmp_path):
    """An edited config.json is refused naming ``--trust-edited-config``, and with it the edit is the experiment
    (checked before the parser: --help shows the edited value); a deeply nested file is one line."""
    payload = json.loads((run_dir / "config.json").read_text())
    payload["config"]["seed"] = 41  # edited by hand: the checksum no longer matches
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(payload))
    run_cli("train", "--load-config", edited, "--help", code=2, match=("edited.json", "--trust-edited-config"),
            watch=[tmp_path])
    new = tmp_path / "again"
    run_cli("train", "--load-config", edited, "--trust-edited-config", "--steps", "2", "--output", new,
            "--no-progress", "--no-save-renders", code=0, watch=[run_dir])
    assert read_config_json(new / "config.json").config["seed"] == 41
    run_cli("train", "--load-config", edited, "--trust-edited-config", "--no-trust-edited-config", code=2,
            match="--trust-edited-config", watch=[tmp_path])
    deep = tmp_path / "deep.json"
    deep.write_text('{"config": ' + "[" * 100_000 + "]" * 100_000 + "}")
    for trust in ((), ("--trust-edited-config",)):
        run_cli("train", "--load-config", deep, *trust, code=2, match=("deep.json", "nested too deeply"), watch=[tmp_path])
    payload["config"]["model"] = {"init": [[[[[[["x"]]]]]]]}
    (tmp_path / "odd.json").write_text(json.dumps(payload))
    run_cli("train", "--load-config", tmp_path / "odd.json", "--trust-edited-config", code=2,
            match=("odd.json", "not a 3dgs config"), watch=[tmp_path])

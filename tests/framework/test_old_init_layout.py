"""Run folders written before ``model.init`` was a tagged union (issue 41) still load, resume
bit-identically and evaluate: their config.json holds ``model.init`` "random"/"frustum" with
``init_num_points``, a ``3dgs-triang`` run's also ``model.matching`` and ``max_reprojection_px``,
a Scaffold-GS run's ``start_from``. The files under ``old_init_configs/`` are config.json files
written by commit c1c664c (``splat-train METHOD --data synthetic/forward-tiny --steps 60 --seed 0``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tests.framework.test_reliability import assert_same_params, fixed_config, private_cache, stop_at  # noqa: F401

from config_walk import overrides_in_every, sub_configs
from splat_framework.config import (
    MatchConfig,
    apply_overrides,
    experiment_fields,
    read_config_json,
    resolve_steps,
    upgrade_saved_config,
)
from splat_framework.config.matching import AutoMatchConfig
from splat_framework.data import resolve_views
from splat_framework.engine.run import load_trained_model
from splat_framework.engine.trainer import Trainer, TrainingInterrupted
from splat_framework.registry import get_method
from splat_framework.runtime.io import atomic_write_json, read_json

OLD = Path(__file__).parent / "old_init_configs"


@pytest.mark.parametrize("name", sorted(p.stem for p in OLD.glob("*.json")))
def test_old_config_json_is_todays_experiment(name):
    """Read as --resume and splat-eval read it, an old config.json is the experiment that today's
    command line gives (the -triang methods now TOML variants, starting from triangulated matches)."""
    saved = json.loads((OLD / f"{name}.json").read_text())["config"]["model"]
    assert isinstance(saved["init"], str) and "init_num_points" in saved
    method, raw, version = read_config_json(OLD / f"{name}.json")
    assert version == 1
    spec = get_method(method)
    defaults = spec.default_config()
    old = type(defaults).model_validate(upgrade_saved_config(raw, version, defaults))
    # learning rates chosen after these files were written (scgaussian's shape rates, 2026-11-26)
    # stay the saved ones: an old run resumes as it was trained
    command = {"data": "synthetic/forward-tiny", "steps": 60, "seed": 0, "optim": old.optim.model_dump()}
    now = resolve_steps(resolve_views(apply_overrides(defaults, command)))  # as the trainer settles it
    # so do scgaussian's densification threshold and opacity decay, chosen on 2026-11-27 (the decay is
    # rescaled with the schedule since then; these files hold it unscaled)
    later = {k: raw["strategy"][k] for k in ("grow_grad2d", "opacity_decay") if k in raw["strategy"]}
    now = apply_overrides(now, {"strategy": later})
    # and the matching prior's cap on matches per pair (12,000 since 2026-11-27; these files hold 4,000),
    # with no total budget over the pairs (schema 4, 2026-11-28)
    assert {(m.max_matches, m.max_total_matches) for m in sub_configs(old, MatchConfig)} <= {(4000, 0)}
    now = apply_overrides(now, overrides_in_every(now, MatchConfig, {"max_matches": 4000, "max_total_matches": 0}))
    # and matcher auto's guided flow up to 4 views (any number since 2026-11-29; these files hold 4)
    assert {m.auto_guided_flow_max_views for m in sub_configs(old, AutoMatchConfig)} <= {4}
    now = apply_overrides(now, overrides_in_every(now, AutoMatchConfig, {"auto_guided_flow_max_views": 4}))
    # and every iteration at the images' own size (scgaussian's coarse steps since schema 5, 2026-11-28)
    assert old.coarse_steps == 0
    now = apply_overrides(now, {"coarse_steps": 0})
    # and scgaussian's matched Gaussians bound to their rays all run (released after the warm-up since
    # 2026-12-03; these files hold them bound)
    if "ray_binding" in raw["model"]:
        assert raw["model"]["ray_binding"] is True
        now = apply_overrides(now, {"model": {"ray_binding": True}})
    # and scgaussian's schedule counted from 4 training views (from 3 since 2026-12-05; these files hold 4)
    assert old.schedule_views in (0, 4)
    now = apply_overrides(now, {"schedule_views": old.schedule_views})
    keep = experiment_fields(type(now))
    assert old.model_dump(include=keep) == now.model_dump(include=keep)
    rates = type(old.optim).model_fields
    assert all(getattr(old.optim, k) == v for k, v in raw["optim"].items() if k in rates)
    assert all(getattr(old.strategy, k) == v for k, v in later.items())
    assert old.model.init.kind == ("triangulated" if method.endswith("-triang") else "random")


def test_run_saved_in_the_old_layout_resumes_bit_identically(tmp_path):
    """A 3dgs run with frustum init, interrupted, its config.json rewritten in the old layout
    (``init = "frustum"``, ``init_num_points``), resumes to the uninterrupted run's parameters and loads."""
    def cfg_fn(out, **kw):
        return fixed_config("3dgs-frustum", out, **kw)

    straight = Trainer(cfg_fn(tmp_path / "a"))
    straight.train()
    with pytest.raises(TrainingInterrupted):
        Trainer(cfg_fn(tmp_path / "b", overwrite=True), [stop_at(15)]).train()
    path = tmp_path / "b" / "config.json"
    payload = read_json(path)
    model = payload["config"]["model"]
    assert model["init"] == {"kind": "frustum", "num_points": 300}
    model["init"], model["init_num_points"] = "frustum", 300
    payload["schema_version"] = 1  # the layout's version
    payload.pop("checksum", None)
    atomic_write_json(path, payload)
    assert json.loads(path.read_text())["config"]["model"]["init"] == "frustum"
    resumed = Trainer(cfg_fn(tmp_path / "b", resume=True))
    resumed.train()
    assert_same_params(straight.model, resumed.model)
    config, model = load_trained_model(tmp_path / "b")
    assert config.model.init.kind == "frustum" and model.num_gaussians == straight.model.num_gaussians


def test_flat_regularisers_and_anchor_learning_rates_find_their_groups():
    """Written before ``model.reg`` and Scaffold-GS's own ``optim`` (issue 41): a flat regulariser
    moves into ``model.reg``, an anchor learning rate from ``model`` into ``optim``, and the 3DGS
    fields Scaffold-GS never read (``model.sh_degree``, ``optim.means_lr``, ...) are dropped."""
    raw = json.loads((OLD / "scaffold-gs.json").read_text())["config"]
    assert "sh_degree" in raw["model"] and "means_lr" in raw["optim"] and "offset_lr" in raw["model"]
    raw["model"]["stereo_weight"], raw["model"]["offset_lr"] = 0.5, 0.02
    defaults = get_method(raw["method"]).default_config()
    config = type(defaults).model_validate(upgrade_saved_config(raw, 1, defaults))
    assert config.model.reg.stereo_weight == 0.5 and config.optim.offset_lr == 0.02
    assert "sh_degree" not in type(config.model).model_fields and "means_lr" not in type(config.optim).model_fields
    method, raw, version = read_config_json(OLD / "scgaussian.json")
    raw = upgrade_saved_config(raw, version, get_method(method).default_config())
    assert raw["model"]["reg"]["depth_smoothness"] == 5.0 and raw["model"]["sh_degree"] == 3  # scgaussian reads it

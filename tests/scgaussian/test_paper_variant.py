"""``scgaussian-paper``: the official SCGaussian code's recipe, field by field, and the paper's ablation
rows on it (``scgaussian-paper-*``), beside the same rows on the default (``scgaussian-*``)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib

import pytest

from splat_framework.testing import (
    Trainer,
    discover_methods,
    parse_train_args,
    resolve_steps,
    skip_without_matcher_weights,
)
from support import REPO

OFFICIAL = {
    # arguments/__init__.py: OptimizationParams (lines 73-90), ModelParams (49); train.py; scene/gaussian_model.py;
    # data_preprocess/get_match_info.py of github.com/prstrive/SCGaussian at efb29f6
    "steps": 2000, "default_steps": 2000, "schedule_views": 0,  # iterations = 2_000, whatever the views
    "coarse_steps": 0,  # every iteration at the images' own size
    "random_background": False,  # arguments/__init__.py:90; train.py:99-100, 141: the dataset's black or white
    "camera_refine.mode": "off",
    "model.lambda_dssim": 0.2, "model.init_opacity": 0.1, "model.init_scale": 1.0,
    "model.sh_degree": 3, "model.sh_degree_interval": 1000,
    "model.ray_binding": True, "model.schedule": "two-stage",
    "model.warmup_steps": 2000, "model.warmup_lr": 0.5, "model.warmup_lr_unit": "scene",
    "model.warmup_lr_halve_every": 500,
    "model.lambda_gp": 0.0, "model.lambda_rg": 0.3, "model.rg_start": 0,
    "model.cache_filter": True, "model.cache_until": 0, "model.filter_eta_px": 75.6,
    "model.z_lr": 1.6e-4, "model.z_lr_final": 1.6e-6, "model.sparse_matches": 0, "model.thin_prior_baseline": False,
    "model.init.kind": "random", "model.init.num_points": 0,
    "model.reg.backdrop_weight": 1.0, "model.reg.depth_smoothness": 0.0, "model.reg.stereo_weight": 0.0, "model.reg.multiview_weight": 0.0,
    "model.reg.anisotropy_weight": 0.0, "model.reg.drop_rate": 0.0, "model.reg.opacity_noise": 0.0,
    "model.matching.kind": "auto", "model.matching.max_matches": 2000, "model.matching.max_total_matches": 0,
    "model.matching.magsac_threshold": 1.0, "model.matching.magsac_confidence": 0.999999,
    "model.matching.epipolar_check": False, "model.matching.alpha_mask": True,
    "strategy.enabled": True, "strategy.prune_opa": 0.005, "strategy.grow_grad2d": 0.0004,
    "strategy.grow_scale3d": 0.01, "strategy.grow_scale2d": 1000.0, "strategy.prune_scale3d": 0.2,
    "strategy.prune_scale2d": 0.0595, "strategy.refine_scale2d_stop_iter": 2000,
    "strategy.refine_start_iter": 500, "strategy.refine_stop_iter": 2000, "strategy.reset_every": 200,
    "strategy.opacity_decay": 1.0, "strategy.refine_every": 100, "strategy.pause_refine_after_reset": 0,
    "strategy.absgrad": False, "strategy.revised_opacity": False,
    "optim.means_lr": 1.6e-4, "optim.means_lr_final": 1.6e-4, "optim.scales_lr": 0.0055,
    "optim.quats_lr": 0.0015, "optim.opacities_lr": 0.055, "optim.sh0_lr": 0.002, "optim.shN_lr": 1e-4,
}
"""The official code's values, as this project's fields (docs/methods.md says where each is)."""

ROWS = ("hybrid", "hybrid-rg", "hybrid-rg-dual", "only-ray", "only-nonstructure", "single-stage")
"""The paper's ablation rows, each a variant of the default (``scgaussian-ROW``) and of the recipe
(``scgaussian-paper-ROW``)."""

METHODS = discover_methods()


def flat(d: dict, prefix: str = "") -> dict:
    """{dotted key: leaf value} of a nested dict."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out |= flat(v, f"{prefix}{k}.")
        else:
            out[prefix + k] = v
    return out


def config(name: str, steps: int | None = None) -> dict:
    """The flattened default config of a registered name (resolved to ``steps`` iterations if given)."""
    cfg = METHODS[name].default_config()
    if steps is not None:
        cfg = resolve_steps(cfg.model_copy(update={"steps": steps}))
    return flat(cfg.model_dump(mode="json"))


def test_the_variant_file_sets_every_official_value_and_nothing_else():
    overrides = tomllib.loads((REPO / "configs" / "scgaussian-paper.toml").read_text())["overrides"]
    assert flat(overrides) == OFFICIAL


def test_the_resolved_config_has_the_official_values():
    """Inheriting from the default changes none of them (every one is written in the file)."""
    got = config("scgaussian-paper")
    assert {k: got[k] for k in OFFICIAL} == OFFICIAL
    assert resolve_steps(METHODS["scgaussian-paper"].default_config()).total_steps == 2000


def test_the_methods_page_table_gives_the_same_values():
    """docs/methods.md maps every field of the variant to the official value: one row per field, its
    value as in the TOML file."""
    page = (REPO / "docs" / "methods.md").read_text()
    rows = dict(re.findall(r"^\| `([a-z_.A-Z0-9]+)` \| `([^`]+)` \|", page, re.M))
    assert {k: tomllib.loads(f"v = {v}")["v"] for k, v in rows.items() if k in OFFICIAL} == OFFICIAL


def test_help_shows_the_official_values():
    env = dict(os.environ, COLUMNS="80", NO_COLOR="1", TERM="dumb")
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "scgaussian-paper", "--help", "all"],
                       capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    text = re.sub(r"[│╭╮╰╯─]", " ", r.stdout)
    blocks = re.split(r"\n\s+(?=--[a-z])", text)
    shown = {}
    for b in blocks:
        flag = b.split()[0].split(",")[0]
        default = re.findall(r"\(default: ([^)]*)\)", " ".join(b.split()))
        if flag.startswith("--") and default:
            shown[flag[2:]] = default[-1]
    for key, value in OFFICIAL.items():
        flag = key.replace("_", "-")
        if flag in shown:  # suppressed fields (default_steps, schedule_views) are not shown
            assert shown[flag] == str(value), (flag, shown[flag], value)
    assert shown["steps"] == "2000" and shown["model.warmup-lr"] == "0.5" and shown["strategy.grow-grad2d"] == "0.0004"


@pytest.mark.parametrize("row", ROWS)
def test_each_ablation_row_is_the_same_row_on_the_recipe(row):
    """``scgaussian-paper-ROW`` changes the recipe exactly where ``scgaussian-ROW`` changes the default
    (compared at the recipe's 2000 iterations): the same fields, to the same values, except those the
    base already has at that value (the recipe binds the matched Gaussians to their rays, as
    ``-hybrid`` sets on the default; the default releases them, as ``-paper-only-nonstructure`` sets
    on the recipe)."""
    default, default_row = config("scgaussian", 2000), config(f"scgaussian-{row}", 2000)
    paper, paper_row = config("scgaussian-paper", 2000), config(f"scgaussian-paper-{row}", 2000)
    changed = {k for k in default_row if k != "method" and default_row[k] != default[k]}
    changed_paper = {k for k in paper_row if k != "method" and paper_row[k] != paper[k]}
    both = changed | changed_paper
    assert both
    assert {k: paper_row[k] for k in both} == {k: default_row[k] for k in both}


def test_the_recipe_trains_on_the_tiny_scene(tmp_path):
    """A 10-iteration run of the recipe (warm-up, main stage, evaluation) on the built-in forward-tiny scene."""
    skip_without_matcher_weights()  # the recipe matches with ALIKED + LightGlue
    cfg = METHODS["scgaussian-paper"].default_config().model_copy(
        update=dict(data="synthetic/forward-tiny", steps=10, output=tmp_path / "run", progress=False))
    trainer = Trainer(cfg, spec=METHODS["scgaussian-paper"])
    trainer.train()
    # the official schedules: z decays from 1.6e-4 to 1.6e-6 (times the scale), the ordinary
    # Gaussians' positions keep 1.6e-4 (its update_learning_rate returns after z's group)
    model = trainer.model
    first, last = model.learning_rates(0), model.learning_rates(10)
    assert first["z"] == pytest.approx(1.6e-4 * model.scene_scale) and last["z"] == pytest.approx(1.6e-6 * model.scene_scale)
    assert first["means"] == last["means"] == pytest.approx(1.6e-4 * model.scene_scale)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert metrics["method"] == "scgaussian-paper" and metrics["init_stats"]["num_matches"] > 0
    assert metrics["mean"]["psnr"] > 0
    assert json.dumps(saved).count('"warmup_lr_unit": "scene"') == 1


def test_another_matcher_on_the_recipe_keeps_the_recipes_matching_values():
    """``splat-train scgaussian-paper --model.matching.kind dense``: the matcher changes, the recipe's
    2,000 matches a pair, no budget, MAGSAC settings and no epipolar check stay (before 2026-11-28 the
    switch gave the new kind's defaults: 12,000 a pair, a 100,000 budget, the epipolar check)."""
    parsed = parse_train_args(["scgaussian-paper", "--model.matching.kind", "dense", "--model.matching.dense-preset", "fast"])
    matching = flat(parsed.model.matching.model_dump())
    assert matching["kind"] == "dense" and matching["dense_preset"] == "fast"
    for key, value in OFFICIAL.items():
        if key.startswith("model.matching.") and key != "model.matching.kind":
            assert matching[key.removeprefix("model.matching.")] == value, key
    # a kind's own fields start from its defaults; a default config switched keeps the defaults
    default = METHODS["scgaussian"].default_config().model.matching
    sift = parse_train_args(["scgaussian", "--model.matching.kind", "sift"]).model.matching
    assert sift.kind == "sift" and (sift.max_matches, sift.max_total_matches) == (default.max_matches, default.max_total_matches)

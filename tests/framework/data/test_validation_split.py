"""Validation views (issue 63, item 3): views that are neither trained on nor tested, scored with
``--eval-split val`` so that defaults are chosen on them and the test views stay for reporting."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from splat_framework.data import DataError, load_scene
from splat_framework.data.run_data import held_out_views
from support import make_blender, make_dtu, make_llff
from tiers import seed_kernels


def test_llff_and_dtu_validate_on_every_view_neither_trained_nor_tested(tmp_path):
    llff = load_scene(make_llff(tmp_path / "fern", 20), views=3)
    val = llff.validation_indices
    assert val == [i for i in range(20) if i not in {*llff.train_indices, *llff.test_indices}] and len(val) == 14
    dtu = load_scene(make_dtu(tmp_path / "scan", 49), views=3)
    assert sorted(dtu.validation_indices + dtu.train_indices + dtu.test_indices) == list(range(49))
    assert len(dtu.validation_indices) == 49 - 25 - 3


def test_blender_validates_on_its_val_split_else_on_unused_training_frames(tmp_path):
    with_val = load_scene(make_blender(tmp_path / "a", 10, 16, n_val=20), views=2)
    assert len(with_val.cameras) == 46
    assert with_val.validation_indices == list(range(26, 46, 8))  # every 8th val frame, as the test views
    assert all(with_val.cameras[i].name.startswith("val_") for i in with_val.validation_indices)
    without = load_scene(make_blender(tmp_path / "b", 20, 16), views=2)
    unused = [i for i in range(20) if i not in without.train_indices]
    assert without.validation_indices == unused[::8] and not set(without.validation_indices) & set(without.train_indices)


def test_held_out_views_swaps_in_the_validation_views_or_says_there_are_none(tmp_path):
    scene = load_scene(make_llff(tmp_path / "fern", 20), views=3)
    assert held_out_views(scene, "test") is scene
    val = held_out_views(scene, "val")
    assert val.test_indices == scene.validation_indices and val.held_out == "val"
    assert val.train_indices == scene.train_indices
    small = load_scene(make_llff(tmp_path / "three", 4), views="all")  # 1 test view, 3 training views
    with pytest.raises(DataError, match=r"three: no validation views") as err:
        held_out_views(small, "val")
    assert "--eval-split test" in str(err.value) and "\n" not in str(err.value)


def test_a_run_scored_on_validation_views_says_so_and_eval_repeats_it(tmp_path, monkeypatch):
    """``--eval-split val``: the metrics are those of the validation views, labelled ``val`` per view
    and in metrics.json; config.json records them, so ``splat-eval`` of the run scores the same views."""
    from cli_harness import run_cli

    monkeypatch.setenv("SPLAT_CACHE", str(seed_kernels(tmp_path / "cache")))
    run = tmp_path / "run"
    run_cli("train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "5", "--eval-split", "val",
            "--model.init.num-points", "300", "--output", run, "--no-progress", "--no-save-renders", code=0)
    metrics = json.loads((run / "metrics.json").read_text())
    names = [v["view"] for v in metrics["per_view"]]
    assert metrics["eval_split"] == "val" and {v["split"] for v in metrics["per_view"]} == {"val"}
    saved = json.loads((run / "config.json").read_text())["config"]
    assert saved["eval_split"] == "val" and saved["resolved_data"]["test"] == names
    scene = load_scene(Path(saved["resolved_data"]["path"]), views=saved["views"])
    assert names == [scene.cameras[i].name for i in scene.validation_indices] and names
    res = run_cli("eval", run, "--no-renders", code=0)
    again = json.loads((run / "metrics.json").read_text())
    assert [v["view"] for v in again["per_view"]] == names and {v["split"] for v in again["per_view"]} == {"val"}, res

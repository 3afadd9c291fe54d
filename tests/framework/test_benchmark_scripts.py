"""The benchmark scripts' bookkeeping (the measuring itself is not a test: benchmarks are scripts)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pass(tmp_path: Path, name: str, step_ms: dict, load: float) -> Path:
    records = [{"method": m, "at": at, "num_gaussians": 1000 + at, "step_s": ms / 1e3}
               for (m, at), ms in step_ms.items()]
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps({"machine": {"torch_threads": 2, "loadavg_at_start": [load, 0, 0]},
                                "records": records}))
    return path


def test_train_step_compare_reports_mean_speedup_per_snapshot_and_fills_the_readme(tmp_path):
    train_step = load_script("train_step")
    before = [_pass(tmp_path, "b1", {("3dgs", 0): 600, ("3dgs", 500): 300}, 1.1),
              _pass(tmp_path, "b2", {("3dgs", 0): 400, ("3dgs", 500): 300}, 1.2)]
    after = [_pass(tmp_path, "a1", {("3dgs", 0): 250, ("3dgs", 500): 100, ("other", 0): 5}, 1.3)]
    readme = tmp_path / "README.md"
    readme.write_text("# R\n<!-- bench:train_step_speedup -->\nold\n<!-- /bench:train_step_speedup -->\nend\n")
    out = train_step.main(["--compare", *map(str, before), "--to", *map(str, after), "--label", "v0",
                           "--json", str(tmp_path / "cmp.json"), "--readme", str(readme)])
    rows = json.loads(out.read_text())["rows"]
    assert [(r["method"], r["at"]) for r in rows] == [("3dgs", 0), ("3dgs", 500)]  # only snapshots on both sides
    assert rows[0]["speedup"] == 2.0 and rows[1]["speedup"] == 3.0  # mean(600, 400) / 250, 300 / 100
    text = readme.read_text()
    assert "| `3dgs` @ 0 | 1,000 | 600 / 400 | 250 | **2.00x** | 4.00 |" in text
    assert "old" not in text and text.endswith("end\n") and "1.10, 1.20, 1.30" in text


def test_contention_compares_pairs_with_back_to_back_and_the_busy_loop_with_one_idle_thread(tmp_path):
    contention = load_script("contention")

    def rec(name, *walls, psnr=22.5):
        return {"scenario": name, "walls_s": list(walls), "first_step_s": [4.0] * len(walls), "psnr": [psnr] * len(walls),
                "before": {"loadavg": 0.2, "runnable": 1}, "runnable_during": 2.0}

    records = [rec("alone", 100.0), rec("alone-1", 150.0), rec("pair", 170.0, 180.0), rec("hog", 160.0, psnr=22.4),
               rec("alone", 110.0), rec("alone-1", 140.0), rec("pair", 200.0, 190.0), rec("hog", 147.0),
               rec("hog-1", 152.0), rec("hog-1", 151.0)]
    summary = contention.summarise(records, reps=2)
    assert summary["ratios"]["pair / back to back"] == [180.0 / 200.0, 200.0 / 220.0]  # the slower of the two runs
    assert summary["ratios"]["hog / alone-1"] == [160.0 / 150.0, 147.0 / 140.0]
    result = {"method": "3dgs", "data": "llff/fern", "views": 3, "steps": 300, "reps": 2, "env_note": "",
              "machine": "m", "date": "d", "records": records, "summary": summary}
    table = contention.markdown(result, "python benchmarks/contention.py")
    assert "| two runs started together | default | 180 / 200 | 4.0 / 4.0 | 0.90 / 0.91x back to back |" in table
    assert "| beside a 1-thread busy loop | default | 160 / 147 | 4.0 / 4.0 | 1.07 / 1.05x alone-1 |" in table
    assert "| 22.400000 / 22.500000 |" in table  # the default thread count moved the digits: both shown
    assert summary["pinned_same_psnr"] is True and "gave the same test PSNR to every digit" in table
    records.append(rec("pair-1", 150.0, 150.0, psnr=22.500001))
    assert contention.summarise(records, reps=2)["pinned_same_psnr"] is False


def test_coverage_counts_a_training_view_as_seen_wherever_it_rendered_something(tmp_path):
    """benchmarks/coverage.py: a test camera that is a training camera sees exactly the pixels its
    render covers; a camera turned away sees none of them; the photo is as sharp as itself and a
    blurred copy is softer."""
    import torch

    from splat_framework.config import RunFacts, apply_overrides
    from splat_framework.data import DataManager, load_scene
    from splat_framework.data.synthetic import generate_scene
    from splat_framework.model.gaussians import GaussianModel
    from splat_framework.registry import get_method

    coverage = load_script("coverage")
    root = generate_scene("forward", tmp_path / "scene", width=48, height=36, n_views=4, seed=2)
    dm = DataManager(load_scene(root, views=3), device="cpu", seed=0)
    config = apply_overrides(get_method("3dgs").default_config(), {"steps": 10, "model": {"init": {"num_points": 2000}}})
    model = GaussianModel.from_data(config.model, RunFacts.of(config), dm, torch.Generator().manual_seed(0))
    background = torch.zeros(3)
    with torch.no_grad():
        training = [(cam, model.get_outputs(cam, background).depth[..., 0]) for cam, _ in dm.train_views()]
        camera, depth = training[0]
        covered = coverage.covered_pixels(camera, depth, training, 0.05)
        assert torch.equal(covered, depth > 0) and covered.float().mean() > 0.5
        far = [(cam, torch.full_like(d, 1e3)) for cam, d in training]  # every training view saw something far behind
        assert not coverage.covered_pixels(camera, depth, far, 0.05).any()
    photo = next(iter(dm.train_views()))[1]["image"]
    everywhere = torch.ones(photo.shape[:2], dtype=torch.bool)
    assert coverage.sharpness(photo, photo, everywhere) == 1.0
    blurred = torch.nn.functional.avg_pool2d(photo.permute(2, 0, 1)[None], 3, 1, 1, count_include_pad=False)[0].permute(1, 2, 0)
    assert coverage.sharpness(blurred, photo, everywhere) < 0.5
    scores = coverage.split_scores(blurred, photo, covered)
    assert scores["covered"]["share"] + scores["uncovered"]["share"] == 1.0 and scores["all"]["psnr"] > 20


def test_first_hour_finds_the_longest_silence_and_tables_each_job(tmp_path):
    first_hour = load_script("first_hour")
    assert first_hour.longest_gap([1.0, 7.5, 8.0], 9.0) == 6.5  # between two lines
    assert first_hour.longest_gap([], 3.0) == 3.0  # a silent command: launch to exit
    assert first_hour.longest_gap([0.5], 12.0) == 11.5  # the last line to exit
    assert first_hour.silence_after([1.0, 7.5, 8.0], ["a", "b", "c"], 9.0) == "a"  # the line it followed
    assert first_hour.silence_after([6.0], ["a"], 7.0) == "(launch)"
    assert first_hour.silence_after([0.5], ["last"], 12.0) == "last"
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text(json.dumps({"timing": {"train_s": 81.04, "eval_s": 2.96, "other": 1}}))
    assert first_hour.phases_of(run) == {"train_s": 81.0, "eval_s": 3.0}
    assert first_hour.phases_of(tmp_path / "none") == {}
    assert first_hour.slowest_step_of(run) is None
    st = {"median_s": 0.1, "max_s": 0.25, "slowest_step": 601, "max_over_median": 2.5}
    (run / "metrics.json").write_text(json.dumps({"timing": {}, "step_times": st}))
    assert first_hour.slowest_step_of(run) == st
    records = [{"job": "fern", "wall_s": 95.04, "longest_silence_s": 2.5, "phases": {"train_s": 81.0},
                "step_times": st, "load_before": 0.1, "exit": 0},
               {"job": "export", "wall_s": 3.2, "longest_silence_s": 3.2, "phases": {}, "step_times": None,
                "load_before": 0.2, "exit": 0}]
    table = first_hour.markdown(records, "cpu, 2 cores", "2026-11-27 14:00 UTC")
    assert "| fern | 95.0 | 2.5 | train 81 | 0.25 s, step 601, 2.5x the median | 0.10 | 0 |" in table
    assert "| export | 3.2 | 3.2 | - | - | 0.20 | 0 |" in table and "cpu, 2 cores; 2026-11-27 14:00 UTC" in table


def test_first_hour_against_another_tree_gives_the_alternated_ratio_and_names_each_trees_commit(tmp_path):
    first_hour = load_script("first_hour")
    # run order: the other tree, this tree, the other, this; the load drifts, so each of this tree's runs
    # is set against the other tree's runs just before and after it
    records = [{"job": "fern", "tree": t, "wall_s": w, "longest_silence_s": 1.0, "phases": {}, "step_times": None,
                "load_before": 0.1, "exit": 0}
               for t, w in [("old", 200.0), ("new", 140.0), ("old", 210.0), ("new", 130.0)]]
    line = first_hour.alternated_ratio(records, "new", "old")
    assert line.startswith("fern, alternated: new 0.66x the wall time of old (means 135.0 s and 205.0 s")
    assert line.endswith("each run against its neighbours: 0.68x, 0.62x)")
    assert first_hour.alternated_ratio(records, "new", "missing") == ""
    table = first_hour.markdown(records, "cpu", "2026-11-28 22:00 UTC", line)
    assert "| fern (old) | 200.0 |" in table and "| fern (new) | 130.0 |" in table and line in table
    # a tree is named by its commit, "+" when its sources have uncommitted changes; else by its path
    assert first_hour.tree_label(tmp_path) == str(tmp_path)
    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "a.py").write_text("x = 1\n")
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "one"], check=True)
    head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert first_hour.tree_label(tmp_path) == head
    (tmp_path / "src" / "a.py").write_text("x = 2\n")
    assert first_hour.tree_label(tmp_path) == head + "+"
    with pytest.raises(SystemExit):  # not a checkout of the project: refused before any run
        first_hour.main(["--against", str(tmp_path), "--jobs", "fern", "--work", str(tmp_path / "w")])


def test_llff_table_sets_each_scene_beside_the_official_rerun_with_the_mean(tmp_path):
    llff = load_script("llff_table")
    row = {"method": "scgaussian", "n_ok": 3, "ssim_mean": 0.8, "st_lpips_mean": 0.1, "load_average_mean": 1.0}
    rows = [row | {"data": "llff/fern", "views": 3, "psnr_mean": 23.15, "psnr_std": 0.1,
                   "matches_digests": ["0123456789abcdef"]},
            row | {"data": "llff/trex", "views": 3, "psnr_mean": 20.12, "psnr_std": 0.2,
                   "matches_digests": ["0123456789abcdef", "fedcba9876543210"]},
            row | {"data": "llff/flower", "views": 3, "psnr_mean": 21.66, "psnr_std": 0.0},
            row | {"data": "llff/horns", "views": 5, "psnr_mean": 23.0, "psnr_std": 0.3},
            row | {"data": "llff/fern", "views": 3, "psnr_mean": 1.0, "method": "3dgs"}]
    (tmp_path / "results.json").write_text(json.dumps({"rows": rows}))
    text = llff.main([str(tmp_path), "--md", str(tmp_path / "t.md")])
    assert "| fern | 23.15 ± 0.10 / 0.800 / 0.100 | 3 | 22.15 / 0.741 | +1.00 | 22.65 | `01234567` |" in text
    assert "| trex | 20.12 ± 0.20 / 0.800 / 0.100 | 3 | 20.62 | -0.50 | 21.12 | `01234567` / `fedcba98` |" in text
    assert "| flower | 21.66 ± 0.00 / 0.800 / 0.100 | 3 | 21.66 | +0.00 | 22.16 | n/a |" in text  # an older sweep
    assert "| **mean of the 3** | **21.64** | | 21.48 | +0.17 | 21.98 | |" in text
    assert "#### 5 training views" in text and "| horns | 23.00 ± 0.30" in text and "#### 2 training views" not in text
    assert (tmp_path / "t.md").read_text() == text


def test_own_photos_scale_takes_photos_evenly_and_reads_each_phase_from_the_log(tmp_path):
    """benchmarks/own_photos_scale.py: the counts are spread over the capture (first and last kept),
    a run's log gives the posing's pairs, photos registered and seconds and the prior's pairs, and
    the table marks a run without held-out photos."""
    scale = load_script("own_photos_scale")
    photos = [tmp_path / f"IMG_{i:03d}.png" for i in range(62)]
    picked = scale.evenly(photos, 8)
    assert picked[0] == photos[0] and picked[-1] == photos[-1] and len(set(picked)) == 8
    with pytest.raises(SystemExit, match="only 62 photos"):
        scale.evenly(photos, 63)
    log = ("matching the photos for their poses (aliked-lightglue): 52/52 pairs, done in 0:01:47, 0.48 pairs/s\n"
           "photos: 16 of 16 images registered, 2,274 points, mean reprojection error 0.55 px, 120.5 s (incremental mapper)\n"
           "matching: 24 of the 91 pairs of training views, each view with its 3 best partners by frustum overlap\n"
           "matching the training views for the prior (auto): 24/24 pairs, done in 0:01:05, 0.37 pairs/s\n")
    row = scale.parse_log(log)
    assert row == {"registered": 16, "photos_in": 16, "posing_s": 120.5, "pose_all_pairs": 120, "pose_pairs": 52,
                   "pose_matching_s": 107, "prior_pairs": 24, "prior_s": 65, "prior_all_pairs": 91}
    text = scale.table([{"label": "16", "wall_s": 300.0, "psnr": 21.5, "held_out": True, **row},
                        {"label": "8", "wall_s": 100.0, "psnr": 30.0, "held_out": False, "matching_s": 9.6}])
    assert "| 16 | 300.0 | 120 | 52 of 120 | 16 of 16 | 24 of 91 | 65 |" in text
    assert "| 8 | 100.0 | – | – of – | – of – | – | 10 |" in text and "30.00 (training views)" in text


def test_own_photos_scale_shows_a_runs_output_as_it_comes_and_keeps_it(tmp_path, capfd):
    """A run of minutes is not silent: its stdout and stderr reach the terminal line by line and its log."""
    scale = load_script("own_photos_scale")
    code = "import sys; print('step 1', flush=True); print('warning: x.png', file=sys.stderr, flush=True); sys.exit(3)"
    rc, text = scale._shown_and_kept([sys.executable, "-c", code], dict(os.environ), tmp_path / "run.log")
    assert rc == 3 and text == "step 1\nwarning: x.png\n" == (tmp_path / "run.log").read_text()
    assert "    step 1\n    warning: x.png\n" in capfd.readouterr().out


def test_own_photos_scale_estimates_every_pair_from_a_sample_of_pairs():
    """--pair-sample: a matcher twice as slow on pairs of far-apart frames is timed on the chosen and
    on random pairs, every frame's features first, and the clip's posing is scaled to every pair."""
    scale = load_script("own_photos_scale")
    calls = []

    def match(a, b):
        calls.append((int(a), int(b)))
        time.sleep(0.002 if abs(int(a) - int(b)) <= 2 else 0.004)

    frames = list(range(20))
    chosen = [(i, j) for i in range(20) for j in range(i + 1, min(i + 3, 20))]
    rate = scale.sampled_pair_rate(frames, chosen, match, n=10, batch=5)
    assert calls[:10] == [(i, i + 1) for i in range(0, 19, 2)] and len(calls) == 30
    assert rate["chosen_pairs"] == 37 and rate["all_pairs"] == 190 and 1.4 < rate["random_over_chosen"] < 2.6
    fixed = {"chosen_pairs": 100, "all_pairs": 1000, "random_over_chosen": 1.0}
    assert scale.exhaustive_estimate({"posing_s": 600.0, "pose_matching_s": 500.0}, fixed) == 600 + 500 * 9


def test_the_gpu_check_reports_torchs_own_sync_count_where_it_has_one(tmp_path):
    cuda = load_script("cuda")
    path = tmp_path / "host-syncs.json"
    path.write_text(json.dumps({"counted_per_step": 2.0, "cuda_syncs_per_step": 3.5, "step_ms": 12.0, "gaussians": 9}))
    row = cuda.syncs_row({"step": "host-syncs", "rc": 0}, path)
    assert (row["syncs_per_step"], row["step_ms"], row["gaussians"]) == (3.5, 12.0, 9)
    path.write_text(json.dumps({"counted_per_step": 2.0, "step_ms": 30.0}))  # a CPU: the project's counter
    assert cuda.syncs_row({}, path)["syncs_per_step"] == 2.0
    assert cuda.syncs_row({"step": "x"}, tmp_path / "missing.json") == {"step": "x"}  # a step that failed


@pytest.mark.slow  # trains a run
def test_host_syncs_counts_a_tiny_run_by_place(tmp_path):
    record = load_script("host_syncs").main(["--warmup", "4", "--steps", "3", "--output", str(tmp_path / "run"),
                                             "--json", str(tmp_path / "syncs.json")])
    assert json.loads((tmp_path / "syncs.json").read_text()) == record
    assert record["counted_per_step"] >= 1 and any("numerics.py" in place for place in record["counted_places"])
    assert record["step_ms"] > 0 and "cuda_syncs_per_step" not in record

"""splat-sweep: grid parsing, run folders, resume, aggregation, failures, tables, local and Ray backends."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import shutil
import statistics
import sys
from pathlib import Path

import pytest

from splat_framework import sweep
from splat_framework.cli import sweep as cli_sweep
from splat_framework.sweep import Grid, SweepError, run_sweep
from support import REPO
from tiers import seed_kernels

TINY = {"model": {"init": {"num_points": 300}}, "save_renders": False, "compile": False}
"""Keeps the end-to-end runs to about a second of training each (eager kernels: Ray's workers do not
see the test environment's SPLAT_COMPILE, and compiling there took minutes)."""


@pytest.fixture(autouse=True)
def _own_cache(tmp_path, monkeypatch):
    """Each test's sweeps have a cache of their own, holding the machine's native kernels; after
    conftest's ``_private_cache``, whose SPLAT_COMPILE the sweeps' worker processes inherit (under
    that fixture's name this one replaced it, and each end-to-end sweep built the kernels: 45 s)."""
    monkeypatch.setenv("SPLAT_CACHE", str(seed_kernels(tmp_path / "cache")))


def fake_metrics(path: Path, method: str, data: str, psnr: float, ssim: float, lpips=None, steps=10, digest=None,
                 **timing):
    path.mkdir(parents=True, exist_ok=True)
    (path / "metrics.json").write_text(json.dumps({
        **({"init_stats": {"matches_digest": digest}} if digest else {}),
        "method": method, "data": data, "steps": steps,
        "mean": {"psnr": psnr, "ssim": ssim, "lpips": lpips, "avg": None if lpips is None else lpips / 2},
        "per_view": [],
        "timing": {"data_s": 0.1, "init_s": 0.2, "train_s": 10.0, "eval_s": 1.0, "total_s": 11.3, **timing},
        "num_gaussians": 1000, "render_fps": 50.0,
    }))


def no_training(*args, **kwargs):
    raise AssertionError("a run was trained although its metrics.json exists")


# ------------------------------------------------------------------ grid
def test_grid_toml_and_json(tmp_path):
    toml = tmp_path / "grid.toml"
    toml.write_text(
        'methods = ["3dgs", "scgaussian"]\ndata = "synthetic/forward"\nviews = [3, "all"]\n'
        'seeds = [0, 1]\nsteps = 500\nout = "sweeps/x"\nworkers = 2\n[overrides.model.init]\nnum_points = 100\n'
    )
    s = sweep.load_grid_file(toml)
    assert s == {"methods": ["3dgs", "scgaussian"], "data": ["synthetic/forward"], "views": [3, "all"],
                 "seeds": [0, 1], "steps": 500, "out": "sweeps/x", "workers": 2,
                 "overrides": {"model": {"init": {"num_points": 100}}}}
    js = tmp_path / "grid.json"
    js.write_text(json.dumps({"methods": "3dgs", "data": ["llff/fern"], "seeds": 3, "views": "6"}))
    assert sweep.load_grid_file(js) == {"methods": ["3dgs"], "data": ["llff/fern"], "seeds": [3], "views": [6]}
    bad = tmp_path / "bad.toml"
    bad.write_text('methods = ["3dgs"]\nseedz = [1]\n')
    with pytest.raises(SweepError, match="unknown key.*seedz"):
        sweep.load_grid_file(bad)
    bad.write_text('methods = ["3dgs"]\nviews = ["three"]\n')
    with pytest.raises(SweepError, match="views"):
        sweep.load_grid_file(bad)
    bad.write_text("methods = [")
    with pytest.raises(SweepError, match="not valid TOML"):
        sweep.load_grid_file(bad)


def test_cli_lists_override_the_file(tmp_path):
    toml = tmp_path / "grid.toml"
    toml.write_text('methods = ["3dgs"]\ndata = ["a/b"]\nseeds = [0]\nsteps = 100\nout = "o"\n[overrides.model]\nsh_degree = 1\n')
    p = cli_sweep.build_parser()
    args = p.parse_args([str(toml), "--seeds", "0", "1", "--steps", "50", "--views", "3", "all",
                         "--override", "model.init.num_points=300", "--override", "save_renders=false"])
    s = cli_sweep.settings_from_args(args)
    assert s["methods"] == ["3dgs"] and s["data"] == ["a/b"] and s["seeds"] == [0, 1]
    assert s["steps"] == 50 and s["views"] == [3, "all"] and s["out"] == "o"
    assert s["overrides"] == {"model": {"sh_degree": 1, "init": {"num_points": 300}}, "save_renders": False}
    args = p.parse_args(["--methods", "3dgs", "scgaussian", "--data", "synthetic/forward", "llff/fern",
                         "--views", "3", "--seeds", "0", "1", "--steps", "500", "--out", "sweeps/x"])
    s = cli_sweep.settings_from_args(args)
    runs = Grid(s["methods"], s["data"], s["views"], s["seeds"], s["steps"]).runs(Path(s["out"]))
    assert len(runs) == 8 and all(r.steps == 500 for r in runs)
    assert [(r.data, r.method, r.seed) for r in runs[:4]] == [
        ("synthetic/forward", "3dgs", 0), ("synthetic/forward", "3dgs", 1),
        ("synthetic/forward", "scgaussian", 0), ("synthetic/forward", "scgaussian", 1)]
    with pytest.raises(SweepError, match="no output folder"):
        cli_sweep.settings_from_args(p.parse_args(["--methods", "3dgs", "--data", "x"]))
    with pytest.raises(SweepError, match="no methods"):
        cli_sweep.settings_from_args(p.parse_args(["--data", "x", "--out", "o"]))
    with pytest.raises(SweepError, match="unknown method"):
        run_sweep(Grid(["3dgs", "no-such-method"], ["x"]), tmp_path / "o")


def test_run_folder_naming(tmp_path):
    assert sweep.scene_slug("synthetic/forward") == "synthetic-forward"
    assert sweep.scene_slug("llff/fern/") == "llff-fern"
    assert sweep.scene_slug("/data/nerf llff/fern") == "nerf_llff-fern"
    assert sweep.scene_slug("dtu\\scan37") == "dtu-scan37"
    assert sweep.run_dir(tmp_path, "llff/fern", "scgaussian", 3, 1) == tmp_path / "runs/llff-fern/scgaussian/v3-s1"
    assert sweep.run_dir(tmp_path, "blender/lego", "3dgs", "all", 0).name == "vall-s0"
    with pytest.raises(SweepError, match="share the run-folder name"):
        Grid(["3dgs"], ["a/b", "a-b"]).runs(tmp_path)


# ------------------------------------------------- resume and aggregation
def test_aggregation_and_resume_without_training(tmp_path, monkeypatch):
    out = tmp_path / "sw"
    grid = Grid(["3dgs", "scgaussian"], ["synthetic/forward"], [3], [0, 1, 2], steps=10)
    psnr = {"3dgs": [20.0, 21.0, 22.5], "scgaussian": [24.0, 25.0, 23.0]}
    for run in grid.runs(out):
        extra = ({"matching_s": 2.0 + run.seed, "warmup_s": 5.0, "digest": "b" * 16 if run.seed == 1 else "a" * 16}
                 if run.method == "scgaussian" else {})
        lp = 0.2 + 0.01 * run.seed if run.method == "scgaussian" else None
        fake_metrics(run.run_dir, run.method, run.data, psnr[run.method][run.seed], 0.5 + 0.1 * run.seed, lp, **extra)
    for name in ("run_local", "run_serial", "run_ray", "execute_run"):
        monkeypatch.setattr(sweep, name, no_training)
    res = run_sweep(grid, out, live=False)
    assert (res.ran, res.skipped, res.failed) == (0, 6, 0)
    by = {r["method"]: r for r in res.rows}
    assert by["3dgs"]["psnr_mean"] == pytest.approx(statistics.mean(psnr["3dgs"]))
    assert by["3dgs"]["psnr_std"] == pytest.approx(statistics.stdev(psnr["3dgs"]))
    assert by["scgaussian"]["ssim_mean"] == pytest.approx(0.6) and by["scgaussian"]["ssim_std"] == pytest.approx(0.1)
    assert by["scgaussian"]["matching_s_mean"] == pytest.approx(3.0)
    assert by["3dgs"]["lpips_mean"] is None and by["3dgs"]["matching_s_mean"] is None
    assert by["scgaussian"]["lpips_mean"] == pytest.approx(0.21)
    # the matches each row trained from: distinct digests in seed order; none for a method without matches
    assert by["scgaussian"]["matches_digests"] == ["a" * 16, "b" * 16] and by["3dgs"]["matches_digests"] == []

    md = (out / "results.md").read_text()
    line3 = next(ln for ln in md.splitlines() if ln.startswith("| 3dgs |"))
    cells = [c.strip() for c in line3.strip("|").split("|")]
    heads = [c.strip() for c in md.splitlines()[0].strip("|").split("|")]
    row = dict(zip(heads, cells))
    assert row["PSNR ↑"] == "21.17 ± 1.26" and row["LPIPS ↓"] == "n/a" and row["AVG ↓"] == "n/a"
    assert row["Matching (s)"] == "n/a" and row["Training (s)"] == "10.0 ± 0.0" and row["Status"] == "3/3 ok"
    assert {"Warm-up (s)", "Evaluation (s)", "Peak mem (MB)", "Gaussians", "FPS"} <= set(heads)
    sc = next(ln for ln in md.splitlines() if ln.startswith("| scgaussian |"))
    assert "24.00 ± 1.00" in sc and "0.210 ± 0.010" in sc

    rows = list(csv.DictReader(io.StringIO((out / "results.csv").read_text())))
    assert [r["method"] for r in rows] == ["3dgs", "scgaussian"]
    assert float(rows[0]["psnr_mean"]) == pytest.approx(21.1666, abs=1e-3) and rows[0]["lpips_mean"] == ""
    assert rows[1]["seeds"] == "0 1 2" and rows[1]["n_ok"] == "3"
    assert rows[1]["matches_digests"] == f"{'a' * 16} {'b' * 16}" and rows[0]["matches_digests"] == ""
    js = json.loads((out / "results.json").read_text())
    assert len(js["runs"]) == 6 and js["rows"][1]["warmup_s_mean"] == pytest.approx(5.0)
    assert [r["matches_digest"] for r in js["runs"] if r["method"] == "scgaussian"] == ["a" * 16, "b" * 16, "a" * 16]
    assert js["sweep"]["grid"]["seeds"] == [0, 1, 2]


def test_failures_are_recorded_not_raised(tmp_path, monkeypatch):
    from splat_framework.engine import trainer

    def boom(config):
        if config.seed == 1:
            raise RuntimeError("training diverged\nat step 3")
        return no_training()

    monkeypatch.setattr(trainer, "train", boom)
    out = tmp_path / "sw"
    grid = Grid(["3dgs"], ["synthetic/forward-tiny", "no/such/scene"], [3], [0, 1], steps=10)
    runs = grid.runs(out)
    fake_metrics(runs[0].run_dir, "3dgs", "synthetic/forward-tiny", 20.0, 0.5)             # done: skipped
    res = run_sweep(grid, out, backend="serial", live=False)
    recs = {(r["data"], r["seed"]): r for r in res.records}
    assert recs[("synthetic/forward-tiny", 0)]["status"] == "ok"
    bad = recs[("synthetic/forward-tiny", 1)]
    assert bad["status"] == "failed" and bad["error"] == "RuntimeError: training diverged at step 3"
    assert "RuntimeError" in (runs[1].run_dir / "sweep.log").read_text()
    assert recs[("no/such/scene", 0)]["status"] == "failed" and "no such dataset" in recs[("no/such/scene", 0)]["error"]
    assert (res.ran, res.skipped, res.failed) == (1, 1, 3)
    md = (out / "results.md").read_text()
    assert "1/2 ok, 1 failed" in md and "seed 1: RuntimeError: training diverged at step 3" in md
    # an old run with another step count is never overwritten; a bad override fails only its runs
    res = run_sweep(Grid(["3dgs"], ["synthetic/forward-tiny"], [3], [0], steps=20), out, backend="serial", live=False)
    assert res.records[0]["status"] == "failed" and "holds a 10-step run" in res.records[0]["error"]
    res = run_sweep(Grid(["3dgs"], ["synthetic/forward-tiny"], [3], [5], overrides={"model": {"nope": 1}}),
                    out, backend="serial", live=False)
    assert res.records[0]["error"].startswith("invalid config: model.nope")
    # a worker process that died without writing its result
    r = runs[1]
    rec = sweep.backends._child_result(r, "other-attempt", -9, None)
    assert rec["status"] == "failed" and "killed by signal 9 (out of memory?)" in rec["error"]


def test_live_table_renders(tmp_path):
    from rich.console import Console

    buf = io.StringIO()
    rep = sweep.Reporter(Console(file=buf, force_terminal=True, width=250), live=True, total=2)
    run = Grid(["3dgs"], ["a/b"], [3], [0, 1]).runs(tmp_path)
    recs = [sweep.record_for(run[0], "running"), sweep.record_for(run[1], "pending")]
    rep.start(recs)
    recs[0] = sweep.record_for(run[0], "ok", {"peak_rss_mb": 100.0}, {"mean": {"psnr": 20.0, "ssim": 0.5}, "timing": {}})
    rep.run_finished(recs[0])
    rep.update(recs)
    rep.stop(recs)
    assert rep.use_live and "20.00" in buf.getvalue() and "1 pending" in buf.getvalue()


# ------------------------------------------------------------ end to end
def test_local_backend_end_to_end_and_resume(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("SPLAT_THREADS", raising=False)
    out = tmp_path / "sw"
    argv = ["--methods", "3dgs", "--data", "synthetic/forward-tiny", "--seeds", "0", "1", "--steps", "10",
            "--out", str(out), "--workers", "2", "--override", "model.init.num_points=300",
            "--override", "save_renders=false", "--no-live"]
    res = cli_sweep.main(argv)
    assert (res.ran, res.skipped, res.failed) == (2, 0, 0), [r["error"] for r in res.records]
    for seed in (0, 1):
        d = out / "runs/synthetic-forward-tiny/3dgs" / f"v3-s{seed}"
        m = json.loads((d / "metrics.json").read_text())
        assert m["steps"] == 10 and m["num_gaussians"] > 0
        # a table's runs keep one thread count whatever the load (SPLAT_THREADS unset by the user)
        assert m["threads"]["setting"] == str(m["threads"]["counts"][0]) and len(m["threads"]["counts"]) == 1
    row = res.rows[0]
    assert row["n_ok"] == 2 and row["psnr_mean"] > 5 and row["psnr_std"] is not None
    assert row["peak_rss_mb_mean"] > 50 and row["train_s_mean"] > 0 and row["render_fps_mean"] > 0
    assert "| 3dgs | synthetic/forward-tiny | 3 | 2 |" in (out / "results.md").read_text()
    assert "[2/2]" in capsys.readouterr().out
    # killed or not, a second invocation trains nothing
    monkeypatch.setattr(sweep, "run_local", no_training)
    res = cli_sweep.main(argv)
    assert (res.ran, res.skipped) == (0, 2) and res.rows[0]["psnr_mean"] == pytest.approx(row["psnr_mean"])


def test_ray_backend_two_tiny_runs(tmp_path):
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install splat-framework[ray])")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        res = run_sweep(Grid(["3dgs"], ["synthetic/forward-tiny"], [3], [0, 1], steps=10, overrides=TINY),
                        tmp_path / "sw", backend="ray", threads=1, live=False)
    finally:
        ray.shutdown()
    assert (res.ran, res.failed) == (2, 0), [r["error"] for r in res.records]
    assert all((Path(r["run_dir"]) / "metrics.json").is_file() for r in res.records)
    assert res.rows[0]["n_ok"] == 2 and res.rows[0]["peak_rss_mb_mean"] > 50


def test_ray_missing_gives_install_hint(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(SweepError, match=r"pip install \"splat-framework\[ray\]\""):
        run_sweep(Grid(["3dgs"], ["x"]), tmp_path, backend="ray")


def load_ablation_script():
    spec = importlib.util.spec_from_file_location("ablation", REPO / "benchmarks" / "ablation.py")
    ablation = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ablation)
    return ablation


@pytest.mark.slow  # runs a sweep of training runs
def test_ablation_script_two_methods_writes_table_figure_and_readme(tmp_path):
    ablation = load_ablation_script()
    out = tmp_path / "abl"
    readme = tmp_path / "README.md"
    readme.write_text("# R\n\n<!-- ablation:synthetic-forward-tiny-v3 -->\nold table\n<!-- /ablation:synthetic-forward-tiny-v3 -->\ntail\n")
    md = ablation.main(["--data", "synthetic/forward-tiny", "--views", "3", "--steps", "10", "--seeds", "0",
                        "--methods", "3dgs", "scgaussian", "--out", str(out), "--workers", "2",
                        "--md", str(tmp_path / "results" / "abl.md"), "--readme", str(readme),
                        "--override", "model.init.num_points=300", "--no-live"])
    text = md.read_text()
    assert "### Ablation on `synthetic/forward-tiny`, 3 training views" in text
    lines = [ln for ln in text.splitlines() if ln.startswith("| ")]
    assert lines[1].startswith("| 3DGS (reference random init) | `3dgs` |") and "`scgaussian`" in lines[2]
    assert "failed" not in text and (out / "results.csv").is_file()
    # a trained run's matches reach its row: the digest its metrics.json records, none for 3dgs
    rows = {r["method"]: r for r in json.loads((out / "results.json").read_text())["rows"]}
    scg = json.loads((out / "runs/synthetic-forward-tiny/scgaussian/v3-s0/metrics.json").read_text())
    assert rows["scgaussian"]["matches_digests"] == [scg["init_stats"]["matches_digest"]]
    assert rows["3dgs"]["matches_digests"] == []
    fig = tmp_path / "results" / "abl-synthetic-forward-tiny-v3.jpg"
    assert fig.is_file() and "](abl-synthetic-forward-tiny-v3.jpg)" in text
    new = readme.read_text()
    assert "old table" not in new and new.startswith("# R\n") and new.endswith("<!-- /ablation:synthetic-forward-tiny-v3 -->\ntail\n")
    assert "| 3DGS (reference random init) | `3dgs` |" in new and "](results/abl-synthetic-forward-tiny-v3.jpg)" in new
    # --no-train: a table of what has finished, saying how many seeds each row holds; nothing trains;
    # the comparison figure is redrawn from the finished runs, as the table is
    shutil.rmtree(out / "figures")
    md2 = ablation.main(["--data", "synthetic/forward-tiny", "--views", "3", "--steps", "10", "--seeds", "0", "1",
                         "--methods", "3dgs", "--out", str(out), "--md", str(tmp_path / "abl2.md"),
                         "--override", "model.init.num_points=300", "--no-live", "--no-train"])
    assert "| 3DGS (reference random init) (1 of 2 seeds run) | `3dgs` |" in md2.read_text()
    assert not (out / "runs/synthetic-forward-tiny/3dgs/v3-s1/config.json").exists()
    assert (out / "figures" / "synthetic-forward-tiny-v3.png").is_file()
    assert "](abl2-synthetic-forward-tiny-v3.jpg)" in md2.read_text()
    # the Machine line states the load the runs were trained under (their sweep.json), not the load
    # while a table is regenerated; runs from before that record say so
    assert "load average when the runs started " in text and "by row)" in text
    sj = out / "runs/synthetic-forward-tiny/3dgs/v3-s0/sweep.json"
    rec = json.loads(sj.read_text())
    assert rec["load_average"] >= 0 and rec["started"][:4].isdigit()
    no_train = ["--data", "synthetic/forward-tiny", "--views", "3", "--steps", "10", "--seeds", "0", "--methods", "3dgs",
                "--out", str(out), "--md", str(tmp_path / "abl3.md"), "--no-live", "--no-train"]
    sj.write_text(json.dumps(rec | {"load_average": 7.25}))
    assert "load average when the runs started 7.25 (7.25-7.25 by row);" in ablation.main(no_train).read_text()
    sj.write_text(json.dumps({k: v for k, v in rec.items() if k != "load_average"}))
    assert "load average when the runs started not recorded;" in ablation.main(no_train).read_text()


@pytest.mark.slow  # runs a sweep of training runs
@pytest.mark.skipif(importlib.util.find_spec("pycolmap") is None, reason="--poses estimated needs pycolmap")
def test_ablation_poses_estimated_trains_on_both_poses_and_writes_one_table(tmp_path):
    """--poses estimated: the training views posed from their photos once, every row trained on the dataset's
    and on the estimated poses with the test-pose fit, one table with the pose errors; a second call retrains nothing."""
    ablation = load_ablation_script()
    out = tmp_path / "abl"
    key = "synthetic-forward-v3-estimated-poses"
    readme = tmp_path / "README.md"
    readme.write_text(f"<!-- ablation:{key} -->\nold\n<!-- /ablation:{key} -->\n")
    args = ["--data", "synthetic/forward", "--views", "3", "--steps", "5", "--seeds", "0", "--methods", "3dgs",
            "--poses", "estimated", "--test-pose-steps", "2", "--sfm-matcher", "sift", "--out", str(out),
            "--backend", "serial", "--md", str(tmp_path / "est.md"), "--override", "model.init.num_points=300",
            "--override", "compile=false", "--no-live"]
    text = ablation.main(args + ["--readme", str(readme)]).read_text()
    assert "3 of 3 training views registered from their photos alone (sift matches" in text
    rows = [[c.strip() for c in ln.split("|")[1:-1]] for ln in text.splitlines() if ln.startswith("| `3dgs`")]
    assert [r[1] for r in rows] == ["dataset (COLMAP, all views)", "from the 3 training photos"]
    assert all(float(r[2]) > 0 and float(r[3]) > 0 for r in rows), rows  # PSNR after and before the pose fit
    pose_file = out / "poses" / "synthetic-forward-v3.json"
    runs = {p: json.loads((out / f"{p}-poses/runs/synthetic-forward/3dgs/v3-s0/config.json").read_text())["config"]
            for p in ("dataset", "estimated")}
    assert runs["estimated"]["train_poses"] == str(pose_file.resolve()) and runs["dataset"]["train_poses"] is None
    assert runs["estimated"]["test_pose_steps"] == runs["dataset"]["test_pose_steps"] == 2
    assert "old" not in readme.read_text() and "| `3dgs` | from the 3 training photos |" in readme.read_text()
    stamp = pose_file.stat().st_mtime_ns
    assert ablation.main(args + ["--no-train"]).read_text().splitlines()[2] == text.splitlines()[2]
    assert pose_file.stat().st_mtime_ns == stamp


def test_ablation_readme_without_markers_is_a_clear_error():
    from splat_framework.errors import DataError

    ablation = load_ablation_script()
    with pytest.raises(DataError, match=r"README.md: no '<!-- ablation:llff-fern-v3 -->'"):
        ablation.splice_block("no markers here", "llff-fern-v3", "table", "README.md")


def test_comparison_figure_per_scene_from_finished_runs(tmp_path):
    import cv2
    import numpy as np

    from splat_framework.sweep import write_figures

    records = []
    for k, method in enumerate(["3dgs", "scgaussian"]):
        for seed in (1, 0):
            rd = tmp_path / "runs" / "fern" / method / f"v3-s{seed}"
            (rd / "renders").mkdir(parents=True)
            for view in ("image000", "image008"):
                img = np.full((12, 16, 3), 40 * (k + 1) + seed, np.uint8)
                cv2.imwrite(str(rd / "renders" / f"{view}_render.png"), img)
                cv2.imwrite(str(rd / "renders" / f"{view}_gt.png"), img * 0 + 200)
            records.append({"method": method, "data": "llff/fern", "views": 3, "seed": seed, "run_dir": str(rd), "status": "ok"})
    records.append({"method": "broken", "data": "llff/fern", "views": 3, "seed": 0, "run_dir": str(tmp_path / "none"), "status": "failed"})
    figs = write_figures(tmp_path, records)
    assert [f.name for f in figs] == ["llff-fern-v3.png"]
    fig = cv2.imread(str(figs[0]))
    assert fig is not None and fig.shape[0] > 3 * 12 and fig.shape[1] > 2 * 16  # GT row + 2 method rows, 2 views


@pytest.mark.parametrize("table, title, configs, label", [
    ("comp-tria", "Triangulated initialisation across representations (the paper's Tab. comp_tria)",
     ["3dgs", "3dgs-triang", "scaffold-gs-triang", "octree-gs-triang", "scgaussian"], "Triang. init + Octree-GS"),
    ("default-ablation", "The paper's ablation on the default `scgaussian` (its additions kept)",
     ["3dgs", "3dgs-triang", "scgaussian-hybrid", "scgaussian-hybrid-rg", "scgaussian-hybrid-rg-dual",
      "scgaussian-ray-bound", "scgaussian-single-stage", "scgaussian-only-ray", "scgaussian"],
     "+ dual optimisation (z warm-up)"),
])
def test_ablation_named_table_has_its_rows_title_and_readme_markers(tmp_path, table, title, configs, label):
    """--table NAME: the table's rows in its order (the default --methods), its title, and README markers
    of its own beside the scene's ablation table (comp-tria: the paper's comparison rows; default-ablation:
    the paper's ablation rows built on the default, apart from the 3dgs-against-scgaussian table)."""
    ablation = load_ablation_script()
    key = f"synthetic-forward-tiny-v3-{table}"
    readme = tmp_path / "README.md"
    readme.write_text(f"<!-- ablation:{key} -->\nOLD TABLE\n<!-- /ablation:{key} -->\n"
                      "<!-- ablation:synthetic-forward-tiny-v3 -->\nKEPT\n<!-- /ablation:synthetic-forward-tiny-v3 -->\n")
    md = ablation.main(["--table", table, "--data", "synthetic/forward-tiny", "--views", "3", "--seeds", "0",
                        "--out", str(tmp_path / "abl"), "--md", str(tmp_path / "t.md"), "--readme", str(readme),
                        "--no-live", "--no-train"])
    text = md.read_text()
    assert f"### {title} on " in text
    rows = [ln.split("|")[2].strip() for ln in text.splitlines() if ln.startswith("| ") and "`" in ln.split("|")[2]]
    assert rows == [f"`{c}`" for c in configs]
    assert label in text and "OLD TABLE" not in readme.read_text() and "KEPT" in readme.read_text()


@pytest.mark.bad_input("two identical `splat-sweep` commands at once", "the second exits 2 with one line naming the "
                       "sweep holding the folder, recording nothing; the first's running run is never marked failed")
def test_a_second_sweep_on_the_same_folder_is_refused_while_the_first_runs(tmp_path, tmp_path_factory):
    """The second sweep is refused before it plans (it never records the first's running run as failed);
    the first's fresh run logs no warning about a missing checkpoint. The first is then stopped: its run
    is pending again, not failed."""
    import signal
    import subprocess
    import time

    from cli_harness import cli_env, run_cli

    out = tmp_path / "sw"
    args = ["--methods", "3dgs", "--data", "synthetic/forward-tiny", "--seeds", "0", "--steps", "10", "--out", str(out),
            "--workers", "1", "--override", "model.init.num_points=300", "--override", "save_renders=false", "--no-live"]
    env = cli_env(SPLAT_CACHE=tmp_path_factory.getbasetemp() / "splatcache", SPLAT_COMPILE="0")  # the tiny scenes are there
    first = subprocess.Popen([sys.executable, "-m", "splat_framework.cli.sweep", *args], env=env, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    log = out / "runs/synthetic-forward-tiny/3dgs/v3-s0/sweep.log"
    deadline = time.time() + 240
    while "training from the start" not in (log.read_text() if log.is_file() else ""):  # the run is running
        assert first.poll() is None and time.time() < deadline, first.communicate()
        time.sleep(0.1)
    tables = (out / "results.json").read_bytes()
    run_cli("sweep", *args, code=2, env=env, match=(str(out), "another sweep is running into this folder", "pid "))
    assert (out / "results.json").read_bytes() == tables
    first.send_signal(signal.SIGTERM)
    first.communicate(timeout=120)
    assert first.returncode == 130
    assert json.loads((out / "results.json").read_text())["runs"][0]["status"] == "pending"
    assert "warning" not in log.read_text().lower(), log.read_text()

"""Evaluation: depth metrics against GT depth, labelled pictures, comparison figure, SCGaussian structure report."""

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from cli_harness import message_lines
from splat_framework.config import RunFacts
from splat_framework.errors import DataError
from splat_framework.evaluation.held_out import evaluate
from splat_framework.evaluation.metrics import DEPTH_KEYS, avg_metric, depth_metrics
from splat_framework.evaluation.pictures import label_panel
from splat_framework.render import RenderOutput


# ------------------------------------------------------------------ unit
def test_depth_metrics_values():
    gt = torch.tensor([[2.0, 4.0], [10.0, 0.0]])[..., None]
    pred = torch.tensor([[2.02, 4.4], [5.0, 7.0]])[..., None]
    alpha = torch.tensor([[0.9, 0.9], [0.4, 0.9]])[..., None]
    m = depth_metrics(pred, alpha, gt)
    # evaluated: (0,0) rel 0.01 and (0,1) rel 0.1; (1,0) has alpha <= 0.5, (1,1) no GT
    assert m["depth_abs_rel"] == pytest.approx(0.055, abs=1e-6)
    assert m["depth_within_5pct"] == pytest.approx(0.5)
    assert m["depth_coverage"] == pytest.approx(2 / 3)
    assert depth_metrics(pred, alpha, None) == dict.fromkeys(DEPTH_KEYS)
    none = depth_metrics(pred, torch.zeros_like(alpha), gt)
    assert none["depth_abs_rel"] is None and none["depth_within_5pct"] is None and none["depth_coverage"] == 0.0


def test_expected_depth_handles_both_modes_once():
    alpha = torch.tensor([0.5, 0.25])[:, None, None]
    acc = torch.tensor([1.0, 1.0])[:, None, None]
    out = RenderOutput(rgb=torch.zeros(2, 1, 3), depth=acc, alpha=alpha, depth_mode="accumulated")
    assert torch.allclose(out.expected_depth, torch.tensor([2.0, 4.0])[:, None, None])
    assert out.expected_depth is out.expected_depth  # computed once per render
    assert RenderOutput(rgb=torch.zeros(2, 1, 3), depth=acc, alpha=alpha, depth_mode="expected").expected_depth is acc


def test_label_panel_draws_in_the_corner_only():
    img = np.full((48, 64, 3), 200, np.uint8)
    out = label_panel(img, "GT")
    assert out is img
    assert (img[:8, :8] != 200).any()
    assert (img[-10:, -20:] == 200).all()


# ----------------------------------------------------------- integration
@pytest.mark.slow
def test_trained_run_reports_depth_metrics(run_dir):
    metrics = json.loads((run_dir / "metrics.json").read_text())
    mean = metrics["mean"]
    assert set(mean) == {"psnr", "ssim", "lpips", "lpips_alex", "avg", "st_lpips", *DEPTH_KEYS}
    from splat_framework.evaluation.metrics import STLPIPSMetric, lpips_metrics

    if STLPIPSMetric.available()[0]:  # beside LPIPS or not, under its own name
        assert 0 < mean["st_lpips"] < 1
    usable, note = lpips_metrics()
    assert metrics["lpips_note"] == note
    for key in ("lpips", "lpips_alex"):
        assert (mean[key] is None) == (key not in usable)
    assert 0 < mean["depth_abs_rel"] < 5
    assert 0 <= mean["depth_within_5pct"] <= 1
    assert 0 < mean["depth_coverage"] <= 1
    for v in metrics["per_view"]:
        assert v["depth_abs_rel"] is not None and 0 <= v["depth_within_5pct"] <= 1
    renders = run_dir / "renders"
    for v in metrics["per_view"]:
        for suffix in ("render", "gt", "depth", "grid"):
            assert (renders / f"{v['view']}_{suffix}.png").is_file()
    import cv2

    grid = cv2.imread(str(renders / f"{metrics['per_view'][0]['view']}_grid.png"))
    gt = cv2.imread(str(renders / f"{metrics['per_view'][0]['view']}_gt.png"))
    assert grid.shape == (gt.shape[0], 4 * gt.shape[1], 3)
    # the GT panel carries a caption: its corner differs from the plain GT image
    assert (grid[:6, :10] != gt[:6, :10]).any()
    assert (grid[-10:, : gt.shape[1]] == gt[-10:]).all()


class _NoDepth:
    """A datamanager view without GT depth."""

    def __init__(self, dm):
        self.dm, self.scene = dm, dm.scene

    def eval_views(self):
        return [(c, {k: v for k, v in b.items() if k != "depth"}) for c, b in self.dm.eval_views()]

    def train_views(self):
        return [(c, {k: v for k, v in b.items() if k != "depth"}) for c, b in self.dm.train_views()]


@pytest.mark.slow
def test_depth_mode_does_not_change_the_metrics_and_no_gt_gives_none(run_dir):
    from splat_framework.engine.run import load_run
    from splat_framework.pipeline.scene import background_for

    config, dm, model = load_run(run_dir)
    bg = background_for(dm.scene, "cpu")
    assert "depth" in dm.eval_views()[0][1]
    res = {}
    for mode in ("expected", "accumulated"):
        model.config = config.model.model_copy(update={"depth_mode": mode})
        res[mode] = evaluate(model, dm, bg)["mean"]
    for k in DEPTH_KEYS:
        assert res["expected"][k] == pytest.approx(res["accumulated"][k], rel=1e-4), k
    nogt = evaluate(model, _NoDepth(dm), bg)["mean"]
    assert all(nogt[k] is None for k in DEPTH_KEYS)
    assert nogt["psnr"] == pytest.approx(res["expected"]["psnr"])


@pytest.mark.slow
def test_comparison_figure(run_dir, tmp_path):
    import cv2

    from splat_framework.evaluation.figures import comparison_figure, run_views

    views = run_views(run_dir)
    assert len(views) == 3
    out = comparison_figure([("3DGS", run_dir), ("3DGS again", run_dir)], tmp_path / "fig.png")
    fig = cv2.imread(str(out))
    h, w = cv2.imread(str(run_dir / "renders" / f"{views[0]}_render.png")).shape[:2]
    factor = int(np.ceil(160 / h))
    assert fig.shape[0] > 3 * h * factor and fig.shape[1] > 3 * w * factor  # GT row + 2 methods, 3 views
    # a run without renders shows grey tiles instead of failing
    empty = tmp_path / "empty"
    (empty / "renders").mkdir(parents=True)
    comparison_figure([("3DGS", run_dir), ("missing", empty)], tmp_path / "fig2.png", views=views[:1])
    with pytest.raises(DataError):
        comparison_figure([("missing", empty)], tmp_path / "fig3.png")
    with pytest.raises(DataError):
        comparison_figure([], tmp_path / "fig4.png")


# ------------------------------------------------------- SCGaussian report
def true_correspondences(dm, a=0, b=1, n=150, seed=0):
    """Matches from GT depth: pixels of view a lifted and projected into view b (visible there)."""
    views = dm.train_views()
    cams = [c for c, _ in views]
    da, db = (views[i][1]["depth"][..., 0] for i in (a, b))
    h, w = da.shape
    rng = np.random.default_rng(seed)
    xs, ys = torch.as_tensor(rng.integers(0, w, 6 * n)), torch.as_tensor(rng.integers(0, h, 6 * n))
    uv_a = torch.stack([xs + 0.5, ys + 0.5], 1).float()
    z = da[ys, xs].double()
    pts = cams[a].unproject_depth(uv_a.double(), z)
    uv_b, zb = cams[b].project(pts)
    ok = (z > 0) & (zb > 0) & (uv_b[:, 0] > 0) & (uv_b[:, 0] < w) & (uv_b[:, 1] > 0) & (uv_b[:, 1] < h)
    px = uv_b.floor().long()
    px[:, 0] = px[:, 0].clamp(0, w - 1)
    px[:, 1] = px[:, 1].clamp(0, h - 1)
    ok &= (db[px[:, 1], px[:, 0]].double() - zb).abs() < 0.01 * zb
    return uv_a[ok][:n], uv_b[ok][:n].float(), pts[ok][:n]


@pytest.mark.slow
def test_scgaussian_report_measures_distance_to_surface():
    from scg_plugin.model import SCGaussianModel
    from scg_plugin.ray_gaussians import build_ray_bundle
    from splat_framework.data import DataManager, load_scene
    from splat_framework.data.synthetic import ensure_scene
    from splat_framework.registry import get_method

    dm = DataManager(load_scene(ensure_scene("forward-tiny"), views=3), device="cpu", seed=0)
    views = dm.train_views()
    cams, images = [c for c, _ in views], [b["image"] for _, b in views]
    uv_a, uv_b, pts = true_correspondences(dm)
    assert len(pts) > 30
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], cams, torch.Generator().manual_seed(0))
    bundle.z = (pts.float().repeat_interleave(2, 0) - bundle.origins).norm(dim=-1)
    config = get_method("scgaussian-ray-bound").default_config()  # bound: z alone moves them (below)
    empty = torch.zeros(0, 3)
    model = SCGaussianModel(config.model, RunFacts.of(config), dm.scene.scene_radius, empty, empty, bundle, cams, images)

    exact = model.report(dm)
    assert exact["num_match_gaussians"] == 2 * len(pts)
    assert exact["ray_depth_evaluated"] == 2 * len(pts)
    assert exact["ray_depth_rel_err_median"] < 1e-3
    assert exact["ray_depth_within_1pct"] > 0.9 and exact["ray_depth_within_5pct"] > 0.95
    assert exact["match_reprojection_px_median"] < 0.1

    with torch.no_grad():
        model.params["z"].mul_(1.1)  # 10% too far along every ray = 10% too deep
    off = model.report(dm)
    assert off["ray_depth_rel_err_median"] == pytest.approx(0.1, abs=2e-3)
    assert off["ray_depth_rel_err_p90"] >= off["ray_depth_rel_err_median"]
    assert off["ray_depth_within_5pct"] < 0.05 and off["ray_depth_within_1pct"] == 0.0

    no_gt = model.report(_NoDepth(dm))
    assert "ray_depth_rel_err_median" not in no_gt and "match_reprojection_px_median" in no_gt


@pytest.mark.parametrize("device, where", [("bogus", "config.json"), ("cuda:7", "config.json")])
def test_a_run_saved_with_an_unusable_device_is_one_line_exit_2(run_dir, tmp_path, monkeypatch, capsys, device, where):
    """splat-eval of a run whose config.json names a device torch does not have: exit 2, the file named."""
    import shutil
    import sys

    from splat_framework.cli.eval import entrypoint
    from splat_framework.config import read_config_json, save_config
    from splat_framework.registry import get_method

    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    method, raw, _ = read_config_json(run / "config.json")
    config = type(get_method(method).default_config()).model_validate(raw)
    save_config(config.model_copy(update={"device": device}), run / "config.json")  # a valid checksum
    before = (run / "metrics.json").read_bytes()
    monkeypatch.setattr(sys, "argv", ["splat-eval", str(run)])
    with pytest.raises(SystemExit) as e:
        entrypoint()
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.strip().count("\n") == 0 and where in err and device in err, err
    assert (run / "metrics.json").read_bytes() == before


@pytest.mark.bad_input("a run's `config.json` without its checksum or edited", "refused (exit 2) unless `--trust-edited-config`")
def test_an_edited_or_unsigned_config_is_refused_unless_trusted(run_dir, tmp_path):
    """config.json stripped of its checksum (or edited): splat-eval exits 2 naming the file and the flag;
    with --trust-edited-config it is used."""
    import shutil

    from splat_framework.runtime.io import CHECKSUM_KEY

    run = tmp_path / "run"
    shutil.copytree(run_dir, run, ignore=shutil.ignore_patterns("renders"))
    payload = json.loads((run / "config.json").read_text())
    del payload[CHECKSUM_KEY]
    (run / "config.json").write_text(json.dumps(payload))
    before = (run / "metrics.json").read_bytes()

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "splat_framework.cli.eval", str(run), "--no-renders", *args],
                              capture_output=True, text=True, timeout=300)

    r = cli()
    assert r.returncode == 2 and len(message_lines(r.stderr)) == 1, r.stderr
    assert "config.json" in r.stderr and "no checksum" in r.stderr and "--trust-edited-config" in r.stderr
    assert (run / "metrics.json").read_bytes() == before
    r = cli("--trust-edited-config")
    assert r.returncode == 0, r.stderr


class _GreyViews:
    """Three held-out views of a uniform grey photo (64x64), no mask."""

    scene = SimpleNamespace(masked_metrics=False, held_out="test")

    def eval_views(self):
        return [(SimpleNamespace(name=f"v{i}"), {"image": torch.full((64, 64, 3), 0.5), "index": i})
                for i in range(3)]


def _grey_render(value: float = 0.5) -> RenderOutput:
    return RenderOutput(rgb=torch.full((64, 64, 3), value), depth=torch.ones(64, 64, 1), alpha=torch.ones(64, 64, 1))


def test_render_fps_leaves_out_the_first_renders_warm_up():
    """A model whose first render pays a one-off cost (torch.compile) is timed on its
    steady renders: ``fps`` reflects 3 fast renders, not the 0.4 s warm-up."""
    import time

    class SlowFirst:
        calls = 0

        def get_outputs(self, camera, background):
            SlowFirst.calls += 1
            time.sleep(0.4 if SlowFirst.calls == 1 else 0.01)
            return _grey_render()

    res = evaluate(SlowFirst(), _GreyViews(), torch.zeros(3))
    assert SlowFirst.calls == 4  # one untimed warm-up, then one render per view
    assert res["fps"] > 3 / 0.4  # the warm-up counted would give < 7.5 FPS
    assert res["mean"]["psnr"] is not None


def test_evaluate_reports_both_lpips_beside_st_lpips(monkeypatch):
    """Where LPIPS can be computed, both backbones are reported (lpips: VGG, lpips_alex: AlexNet)
    and ST-LPIPS beside them, each under its own name; AVG uses the VGG LPIPS."""
    from splat_framework.evaluation import held_out

    class Fixed:
        """A metric giving one value (0.4 unless told: the ST-LPIPS stand-in), always available."""

        def __init__(self, value=0.4, device=None):
            self.value = value

        def compute(self, pred, gt, mask=None):
            return self.value

        @staticmethod
        def available():
            return True, ""

    monkeypatch.setattr(held_out, "lpips_metrics", lambda device=None: ({"lpips": Fixed(0.2), "lpips_alex": Fixed(0.3)}, None))
    monkeypatch.setattr(held_out, "STLPIPSMetric", Fixed)

    class Grey:
        def get_outputs(self, camera, background):
            return _grey_render(0.45)

    res = evaluate(Grey(), _GreyViews(), torch.zeros(3))
    mean = res["mean"]
    assert (mean["lpips"], mean["lpips_alex"], mean["st_lpips"]) == pytest.approx((0.2, 0.3, 0.4)) and res["lpips_note"] is None
    assert mean["avg"] == pytest.approx(avg_metric(mean["psnr"], mean["ssim"], 0.2))


def test_splat_eval_fits_the_test_poses_when_asked(run_dir, tmp_path):
    """--test-pose-steps N: each test camera is fitted to its photo first; how far it moved is recorded."""
    import shutil

    from splat_framework.cli.eval import EvalArgs, main

    run = tmp_path / "run"
    shutil.copytree(run_dir, run, ignore=shutil.ignore_patterns("renders"))
    metrics = main(EvalArgs(run_dir=run, renders=False, test_pose_steps=10))
    assert metrics["test_pose_steps"] == 10
    assert json.loads((run / "metrics.json").read_text())["test_pose_steps"] == 10
    for v in metrics["per_view"]:
        assert 0 <= v["pose_refined_deg"] < 5 and 0 <= v["pose_refined_shift"] < 1
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.eval", str(run), "--test-pose-steps", "-1"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and len(message_lines(r.stderr)) == 1 and "--test-pose-steps" in r.stderr, r.stderr

"""Binocular consistency: a sideways-shifted partner render, warped back with the rendered depth."""

from __future__ import annotations

import pytest
import torch

from splat_framework.cameras import Camera, intrinsics
from splat_framework.config import RunFacts, apply_overrides
from splat_framework.losses import stereo_consistency
from splat_framework.model.gaussians import GaussianModel
from splat_framework.registry import get_method


def test_shifted_camera_sees_a_point_at_depth_z_focal_times_shift_over_z_pixels_left():
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, 3] = torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    cam = Camera(K=intrinsics(50.0, 50.0, 32.0, 24.0).double(), world_to_cam=w2c, width=64, height=48)
    points = torch.tensor([[0.1, 0.2, 3.0], [-0.4, 0.1, 7.0]], dtype=torch.float64)
    uv, z = cam.project(points)
    uv2, z2 = cam.shifted_sideways(0.25).project(points)
    torch.testing.assert_close(z2, z)
    torch.testing.assert_close(uv[:, 1], uv2[:, 1])
    torch.testing.assert_close(uv[:, 0] - uv2[:, 0], 50.0 * 0.25 / z)


def _stripes(h: int, w: int) -> torch.Tensor:
    """[H, W, 3] a texture that changes along every row (so a wrong disparity shows)."""
    u = torch.arange(w, dtype=torch.float64)
    row = torch.stack([0.5 + 0.4 * torch.sin(u / 2.0), 0.5 + 0.4 * torch.cos(u / 3.0), (u % 7) / 7.0], dim=-1)
    return row[None].expand(h, w, 3).clone()


def test_stereo_consistency_is_zero_at_the_true_depth_and_ignores_uncovered_pixels():
    h, w, d = 8, 40, 3  # the partner sees every pixel 3 columns further left: partner(x) = photo(x + 3)
    photo = _stripes(h, w)
    partner = torch.cat([photo[:, d:], torch.zeros(h, d, 3, dtype=photo.dtype)], dim=1)
    scale = torch.tensor(6.0, dtype=torch.float64)  # focal x shift; true depth 2 -> disparity 3
    alpha = torch.ones(h, w, 1, dtype=torch.float64)
    true = torch.full((h, w, 1), 2.0, dtype=torch.float64)
    assert stereo_consistency(partner, true, alpha, photo, scale).item() == pytest.approx(0.0, abs=1e-9)
    wrong = torch.full((h, w, 1), 3.0, dtype=torch.float64, requires_grad=True)  # disparity 2
    loss = stereo_consistency(partner, wrong, alpha, photo, scale)
    assert loss.item() > 0.05
    loss.backward()
    assert wrong.grad.abs().sum() > 0  # the depth learns from it
    # the error lives only where alpha says "covered": a photo that differs elsewhere changes nothing
    half = alpha.clone()
    half[:, : w // 2] = 0.0
    other = photo.clone()
    other[:, : w // 2] = 1.0 - other[:, : w // 2]
    assert stereo_consistency(partner, true, half, other, scale).item() == pytest.approx(0.0, abs=1e-9)
    # no covered pixel: zero, with a graph
    empty = stereo_consistency(partner, wrong, torch.zeros_like(alpha), photo, scale)
    assert empty.item() == 0.0 and empty.requires_grad


def test_the_stereo_term_joins_the_loss_after_its_start_and_reaches_the_gaussians(dm):
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 90, "model": {"reg": {"stereo_weight": 1.0, "stereo_start": 0.5}, "init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cam, batch = next(iter(dm.train_views()))

    def losses(step):
        out = model.get_outputs(cam, step=step)
        return model.get_loss_dict(out, batch, cam, step)

    assert "stereo" not in losses(44)
    term = losses(45)["stereo"]
    assert term.item() > 0
    assert term.item() == pytest.approx(losses(45)["stereo"].item())  # the partner is a draw of (seed, step)
    assert term.item() != pytest.approx(losses(46)["stereo"].item())
    term.backward()
    assert model.params["sh0"].grad.abs().sum() > 0 and model.params["means"].grad.abs().sum() > 0


def test_the_regularisers_get_what_they_need_not_the_model(dm):
    """``regulariser_terms`` reads a config, the render and the batch, and calls back only what it is
    handed: the log-scales (when the anisotropy term is on) and one re-render, of the camera moved
    sideways (the stereo term's partner); each is called once per step, never when its term is off."""
    from splat_framework.config import RegularisersConfig
    from splat_framework.model.regularisers import regulariser_terms

    cfg = apply_overrides(get_method("3dgs").default_config(), {"model": {"init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cam, batch = next(iter(dm.train_views()))
    out = model.get_outputs(cam, step=10)
    calls = []

    def log_scales():
        calls.append("scales")
        return model.params["scales"]

    def render(view):
        calls.append(float((view.center - cam.center).norm()))
        return model.get_outputs(view, step=10)

    reg = RegularisersConfig(anisotropy_weight=0.1, max_anisotropy=1.0, stereo_weight=1.0, stereo_start=0.0)
    target, terms = regulariser_terms(reg, out, batch, cam, 10, seed=0, total_steps=100, log_scales=log_scales, render=render)
    assert target is batch["image"] and sorted(terms) == ["anisotropy", "stereo"]
    assert calls[0] == "scales" and len(calls) == 2 and calls[1] > 0  # the partner camera moved
    calls.clear()
    _, terms = regulariser_terms(RegularisersConfig(), out, batch, cam, 10, seed=0, total_steps=100,
                                 log_scales=log_scales, render=render)
    assert terms == {} and calls == []

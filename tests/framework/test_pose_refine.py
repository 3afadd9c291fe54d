"""Test-time pose refinement (splat_framework.evaluation.pose_refine): a perturbed test camera is fitted back to its photo."""

from __future__ import annotations

import dataclasses
import math

import cv2  # at collection: its first import takes seconds on a busy machine, not a test's time
import numpy as np
import pytest
import torch
from torch import nn

from splat_framework.cameras import Camera, intrinsics, look_at, pose_differences
from splat_framework.evaluation.metrics import psnr
from splat_framework.evaluation.pose_refine import refine_pose, rigid_correction
from splat_framework.render import RenderSettings, rasterize

NATIVE = RenderSettings(rasterizer="native", compile=True)


def pose_change(a, b) -> tuple[float, float]:
    """(degrees, centre distance) between two [4, 4] world-to-camera tensors."""
    deg, dist = pose_differences(a.double().numpy()[None], b.double().numpy()[None])
    return float(deg[0]), float(dist[0])


class CloudModel(nn.Module):
    """A fixed cloud of small coloured Gaussians with the model interface refine_pose uses."""

    def __init__(self, n: int = 3000, seed: int = 0) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        xy = torch.rand(n, 2, generator=g) * 4 - 2
        z = 4 + 0.5 * torch.sin(3 * xy[:, :1]) + torch.rand(n, 1, generator=g)
        self.means = nn.Parameter(torch.cat([xy, z], 1))
        self.colors = nn.Parameter(torch.rand(n, 1, 3, generator=g))
        self.quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
        self.scales = torch.full((n, 3), 0.06)
        self.opacities = torch.full((n,), 0.9)

    def positions(self):
        return self.means

    def get_outputs(self, camera: Camera, background=None):
        return rasterize(self.means, self.quats, self.scales, self.opacities, self.colors,
                         camera.world_to_cam.float(), camera.K.float(), camera.width, camera.height,
                         sh_degree=0, background=background, settings=NATIVE)


@pytest.mark.slow  # fits a pose over hundreds of renders
def test_a_perturbed_test_camera_is_fitted_back_to_its_photo():
    model = CloudModel()
    w2c = look_at(torch.tensor([0.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 4.5]), torch.tensor([0.0, -1.0, 0.0])).float()
    true = Camera(K=intrinsics(60.0, 60.0, 40.0, 30.0), world_to_cam=w2c, width=80, height=60, near=1.0, far=10.0)
    bg = torch.zeros(3)
    with torch.no_grad():
        photo = model.get_outputs(true, bg).rgb
    off = rigid_correction(torch.tensor([0.012, -0.018, 0.008]), torch.tensor([0.05, -0.03, 0.04])) @ w2c  # 1.3 degrees
    start = dataclasses.replace(true, world_to_cam=off)
    deg0, shift0 = pose_change(w2c, off)
    assert 1.0 < deg0 < 1.6
    grads_before = [p.grad for p in model.parameters()]
    with torch.no_grad():  # as evaluate() calls it
        fitted = refine_pose(model, start, photo, bg, steps=150)
        before, after = psnr(model.get_outputs(start, bg).rgb, photo), psnr(model.get_outputs(fitted, bg).rgb, photo)
    deg, shift = pose_change(w2c, fitted.world_to_cam)
    assert deg < 0.2 * deg0 and shift < 0.2 * shift0, (deg, shift, deg0, shift0)
    assert after > before + 8, (before, after)
    assert all(p.requires_grad for p in model.parameters())  # the model is left as it was
    assert [p.grad for p in model.parameters()] == grads_before
    assert refine_pose(model, start, photo, bg, steps=0) is start
    half = torch.zeros(60, 80)
    half[:, :40] = 1.0  # a masked metric's pixels: the fit looks only there
    with torch.no_grad():
        fitted = refine_pose(model, start, photo, bg, mask=half)  # 200 steps
        wrong = photo.clone()
        wrong[:, 40:] = 1.0  # what lies outside the mask does not matter
        assert torch.equal(refine_pose(model, start, wrong, bg, steps=20, mask=half).world_to_cam,
                           refine_pose(model, start, photo, bg, steps=20, mask=half).world_to_cam)
    assert pose_change(w2c, fitted.world_to_cam)[0] < 0.2 * deg0
    assert math.isclose(pose_change(w2c, w2c)[0], 0.0, abs_tol=1e-3)


@pytest.mark.slow  # trains a run
def test_a_perturbed_training_camera_is_refined_back_while_training():
    """CameraRefiner as the trainer drives it (apply, backward of the render loss, step with the
    decaying rate): a training view's 1.3 degree error shrinks; the first view never moves."""
    from splat_framework.pipeline.camera_refine import CameraRefiner

    model = CloudModel()
    for p in model.parameters():
        p.requires_grad_(False)
    w2c = look_at(torch.tensor([0.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 4.5]), torch.tensor([0.0, -1.0, 0.0])).float()
    true = Camera(K=intrinsics(60.0, 60.0, 40.0, 30.0), world_to_cam=w2c, width=80, height=60, near=1.0, far=10.0)
    bg = torch.zeros(3)
    with torch.no_grad():
        photo = model.get_outputs(true, bg).rgb
    off = rigid_correction(torch.tensor([0.012, -0.018, 0.008]), torch.tensor([0.05, -0.03, 0.04])) @ w2c
    start = dataclasses.replace(true, world_to_cam=off)
    refiner = CameraRefiner(2, 5e-3, 5e-3 * 4.5, total_steps=150)
    assert torch.equal(refiner.apply(start, 0).world_to_cam, start.world_to_cam)
    for step in range(150):
        refiner.set_learning_rates(step)
        (model.get_outputs(refiner.apply(start, 1), bg).rgb - photo).abs().mean().backward()
        refiner.step()
    deg0, shift0 = pose_change(w2c, off)
    deg, shift = pose_change(w2c, refiner.apply(start, 1).world_to_cam.detach())
    assert deg < 0.25 * deg0 and shift < 0.25 * shift0, (deg, shift, deg0, shift0)
    assert refiner.optimizer.param_groups[0]["lr"] == pytest.approx(5e-3 * 0.01 ** (149 / 150))
    assert refiner.rotation[0].abs().sum() == 0 and refiner.translation[0].abs().sum() == 0
    # a focal length 4 % long, the pose exact: the shared focal factor comes back
    long = dataclasses.replace(true, K=true.K * torch.tensor([[1.04, 1, 1], [1, 1.04, 1], [1, 1, 1]]))
    refiner = CameraRefiner(1, 5e-3, 5e-3 * 4.5, total_steps=150, focal=True)
    for step in range(150):
        refiner.set_learning_rates(step)
        (model.get_outputs(refiner.apply(long, 0), bg).rgb - photo).abs().mean().backward()
        refiner.step()
    fitted = refiner.apply(long, 0)
    assert torch.equal(fitted.world_to_cam, true.world_to_cam)
    assert fitted.K[0, 0].item() == pytest.approx(60.0, rel=0.01) and fitted.K[0, 2].item() == 40.0
    assert refiner.report([long])[0]["focal_factor"] == pytest.approx(1 / 1.04, rel=0.01)


def test_training_poses_count_as_estimated_for_a_pose_file_or_a_folder_of_photos(tmp_path):
    from splat_framework.pipeline.camera_refine import poses_estimated, refine_enabled
    from splat_framework.registry import get_method

    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        cv2.imwrite(str(photos / f"p{i}.png"), np.full((8, 8, 3), 40 * i, np.uint8))
    base = get_method("3dgs").default_config().model_copy(update={"data": "synthetic/forward-tiny"})
    assert not poses_estimated(base)  # a built-in scene: a dataset's poses
    assert poses_estimated(base.model_copy(update={"train_poses": tmp_path / "poses.json"}))
    assert poses_estimated(base.model_copy(update={"data": str(photos)}))
    on = base.model_copy(update={"camera_refine": base.camera_refine.model_copy(update={"mode": "on"})})
    assert refine_enabled(on) and not refine_enabled(base)


def test_a_focal_factor_scales_fx_and_fy_only_and_passes_gradients():
    cam = Camera(K=intrinsics(400.0, 380.0, 252.0, 189.0), world_to_cam=torch.eye(4), width=504, height=378)
    scaled = cam.with_focal_factor(1.04)
    assert scaled.K[0, 0].item() == pytest.approx(416.0) and scaled.K[1, 1].item() == pytest.approx(395.2)
    assert torch.equal(scaled.K[:, 2], cam.K[:, 2]) and (scaled.width, scaled.height) == (504, 378)
    log_focal = torch.zeros((), requires_grad=True)
    cam.with_focal_factor(log_focal.exp()).K[0, 0].backward()
    assert log_focal.grad.item() == pytest.approx(400.0)


def test_a_refiner_without_focal_refinement_trains_and_saves_no_focal_factor():
    from splat_framework.pipeline.camera_refine import CameraRefiner

    plain = CameraRefiner(3, 1e-3, 1e-3, 100)
    assert set(plain.tensors()) == {"camera_refine.rotation", "camera_refine.translation"}
    assert all(group["params"] for group in plain.optimizer.param_groups)
    with_focal = CameraRefiner(3, 1e-3, 1e-3, 100, focal=True)
    assert "camera_refine.log_focal" in with_focal.tensors()

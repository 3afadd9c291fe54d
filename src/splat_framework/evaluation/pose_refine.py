"""Test-time pose refinement: a test camera's pose fitted to its photo with the trained model frozen.

When the training poses are estimated from the few training photos (``splat-process``),
the test cameras, brought into that frame by a Sim(3) alignment, inherit its error: a
1.3 degree rotation moves fern's image by about 9 pixels, and the test PSNR then measures
misregistration rather than image quality. Pose-free methods therefore refine each test
camera before scoring it: BARF (Lin et al., ICCV 2021, Sec. 4, "test-time photometric
optimization"), NoPe-NeRF and CF-3DGS (Fu et al., CVPR 2024) freeze the trained scene and
optimise the test pose against the test image with the photometric loss. This module does
the same: a left-multiplied SE(3) correction ``exp([w, v]) @ world_to_cam`` (rotation
vector ``w``, translation ``v`` in scene units), Adam on the L1 photometric error, with a
learning rate decaying exponentially to 1 % over the steps. Intrinsics stay fixed.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from ..cameras import Camera


def rigid_correction(w: Tensor, v: Tensor) -> Tensor:
    """[4, 4] rigid transform of rotation vector ``w`` [3] and translation ``v`` [3]."""
    from kornia.geometry.conversions import axis_angle_to_rotation_matrix

    top = torch.cat([axis_angle_to_rotation_matrix(w[None])[0], v[:, None]], dim=1)
    return torch.cat([top, top.new_tensor([[0.0, 0.0, 0.0, 1.0]])], dim=0)


def refine_pose(model, camera: Camera, image: Tensor, background: Tensor, steps: int = 200,
                lr_rotation: float = 5e-3, lr_translation: float | None = None, mask: Tensor | None = None) -> Camera:
    """``camera`` with its pose fitted to ``image`` [H, W, 3] by ``steps`` Adam steps on the L1 error
    of ``model``'s render; the model's parameters are not changed (nor their gradients).

    ``mask`` [H, W] or [H, W, 1]: fit only where it is > 0.5, the pixels a masked metric scores (DTU's
    object masks: over the whole image, the wrongly reconstructed table and backdrop of DTU's far views
    pulled their cameras 1-3.7 degrees away and cost 5-8 dB).

    Args:
        lr_rotation: initial step of the rotation vector (radians).
        lr_translation: initial step of the translation (scene units); default ``lr_rotation``
            times the median depth of the model's Gaussians in front of the camera (a rotation
            by ``lr_rotation`` moves those points by about as much).
    """
    if steps <= 0:
        return camera
    base = camera.world_to_cam.detach().float()
    if lr_translation is None:
        with torch.no_grad():
            z = camera.world_to_camera_points(model.positions().detach().to(base))[:, 2]
            z = z[z > camera.near]
            lr_translation = lr_rotation * (float(z.median()) if len(z) else camera.far)
    w = torch.zeros(3, device=base.device, requires_grad=True)
    v = torch.zeros(3, device=base.device, requires_grad=True)
    opt = torch.optim.Adam([{"params": [w], "lr": lr_rotation}, {"params": [v], "lr": lr_translation}])
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=0.01 ** (1.0 / steps))
    params = [p for p in model.parameters() if p.requires_grad]
    target = image.to(base.device)
    weight = None if mask is None else (mask.to(base.device).reshape(*target.shape[:2], 1) > 0.5).to(target.dtype)
    try:
        for p in params:
            p.requires_grad_(False)
        with torch.enable_grad():  # evaluation runs under no_grad
            _fit(model, camera, base, w, v, target, weight, background, opt, sched, steps)
    finally:
        for p in params:
            p.requires_grad_(True)
    with torch.no_grad():
        return dataclasses.replace(camera, world_to_cam=(rigid_correction(w, v) @ base).to(camera.world_to_cam.dtype))


def _fit(model, camera: Camera, base: Tensor, w: Tensor, v: Tensor, target: Tensor, weight: Tensor | None,
         background: Tensor, opt: torch.optim.Optimizer, sched, steps: int) -> None:
    for _ in range(steps):
        cam = dataclasses.replace(camera, world_to_cam=rigid_correction(w, v) @ base)
        err = (model.get_outputs(cam, background).rgb - target).abs()
        loss = err.mean() if weight is None else (err * weight).sum() / (3 * weight.sum()).clamp_min(1)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()

"""The opt-in regularisers of ``config.model.reg`` (:class:`~splat_framework.config.RegularisersConfig`)
as loss terms any model adds with one call, :func:`regulariser_terms`, in its ``get_loss_dict``.

DropGaussian (``reg.drop_rate``) is not a loss term: a model applies it to the opacities of its
training renders (``GaussianModel.drop_opacities``)."""

from __future__ import annotations

import torch
from torch import Tensor

from ..cameras import Camera
from ..runtime.profiling import section
from ..runtime.rng import keyed_generator
from ..losses import depth_smoothness, scale_anisotropy, stereo_consistency
from ..render import RenderOutput


def regulariser_terms(model, outputs: RenderOutput, batch: dict, camera: Camera, step: int) -> tuple[Tensor, dict[str, Tensor]]:
    """(the photometric target [H, W, 3], {term: scalar}) of the regularisers ``model.config.model.reg``
    switches on, for the training render ``outputs`` of ``camera`` at ``step``.

    ``backdrop`` (mean alpha [H, W, 1] over the batch's ``backdrop`` mask, whose target colour
    becomes black: the returned target), ``depth_smooth`` (losses.depth_smoothness of the rendered
    depth), ``anisotropy`` (losses.scale_anisotropy of ``model.gaussian_log_scales(outputs)``) and
    ``stereo`` (losses.stereo_consistency, from its start), each when its weight is > 0.
    """
    reg = model.config.model.reg
    target = batch["image"]
    backdrop = batch.get("backdrop")
    terms = {}
    if backdrop is not None and reg.backdrop_weight > 0:
        target = target * (1.0 - backdrop)
        terms["backdrop"] = reg.backdrop_weight * (outputs.alpha * backdrop).sum() / backdrop.sum().clamp_min(1.0)
    if reg.depth_smoothness > 0:
        terms["depth_smooth"] = reg.depth_smoothness * depth_smoothness(
            outputs.expected_depth, batch["image"], outputs.alpha, gamma=reg.depth_smoothness_gamma)
    if reg.anisotropy_weight > 0:
        terms["anisotropy"] = reg.anisotropy_weight * scale_anisotropy(model.gaussian_log_scales(outputs), reg.max_anisotropy)
    if reg.stereo_weight > 0 and step >= reg.stereo_start * model.config.total_steps:
        with section("stereo"):
            terms["stereo"] = reg.stereo_weight * _stereo_loss(model, outputs, batch["image"], camera, step)
    return target, terms


def _stereo_loss(model, outputs: RenderOutput, image: Tensor, camera: Camera, step: int) -> Tensor:
    """losses.stereo_consistency against a partner render shifted by a keyed draw of (seed, step), up
    to ``stereo_disparity`` x width pixels of disparity at the view's mean covered expected depth."""
    depth = outputs.expected_depth
    cover = outputs.alpha[..., 0] > 0.5
    if not bool(cover.any()):
        return depth.sum() * 0.0
    mean_z = float(depth.detach()[..., 0][cover].mean())
    fx = float(camera.K[0, 0])
    draw = float(torch.rand((), generator=keyed_generator(model.config.seed, step, 1))) * 2.0 - 1.0
    shift = draw * model.config.model.reg.stereo_disparity * camera.width * mean_z / fx
    shifted = model.get_outputs(camera.shifted_sideways(shift), outputs.meta.get("background"), step=step)
    return stereo_consistency(shifted.rgb, depth, outputs.alpha, image, depth.new_tensor(fx * shift))

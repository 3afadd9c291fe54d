"""The opt-in regularisers of ``config.model.reg`` (:class:`~splat_framework.config.RegularisersConfig`)
as loss terms any model adds with one call in its ``get_loss_dict`` (``GaussianModel.regulariser_terms``,
which hands :func:`regulariser_terms` what the terms need: the seed, the run's length, the log-scales
and a re-render).

DropGaussian (``reg.drop_rate``) is not a loss term: a model applies it to the opacities of its
training renders (``GaussianModel.drop_opacities``)."""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

from ..cameras import Camera
from ..config import RegularisersConfig
from ..losses import depth_smoothness, multiview_photometric, scale_anisotropy, stereo_consistency
from ..render import RenderOutput
from ..runtime.profiling import section
from ..runtime.rng import keyed_generator


def regulariser_terms(
    reg: RegularisersConfig, outputs: RenderOutput, batch: dict, camera: Camera, step: int, *, seed: int,
    total_steps: int, log_scales: Callable[[], Tensor], render: Callable[[Camera], RenderOutput],
    partners: Callable[[int, float], list[tuple[Camera, Tensor]]] = lambda k, angle: [],
    own: Callable[[], tuple[Camera, Tensor] | None] = lambda: None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """(the photometric target [H, W, 3], {term: scalar}) of the regularisers ``reg`` switches on,
    for the training render ``outputs`` of ``camera`` at ``step`` of a ``total_steps`` run with ``seed``.

    ``backdrop`` (mean alpha [H, W, 1] over the batch's ``backdrop`` mask, whose target colour
    becomes black: the returned target), ``depth_smooth`` (losses.depth_smoothness of the rendered
    depth), ``anisotropy`` (losses.scale_anisotropy of ``log_scales()``, [N, 3] log-scales of the
    Gaussians it acts on) and ``stereo`` (losses.stereo_consistency against ``render(partner)``, a
    training render of a sideways-shifted copy of ``camera``, from its start) and ``multiview``
    (losses.multiview_photometric against ``partners(k, angle)``, the (camera, photo) of the ``k``
    training views nearest the batch's whose viewing direction is within ``angle`` degrees of its
    own, until its stop; none for a view outside the training split or without such partners) and
    ``pseudo_view`` (:func:`pseudo_view_consistency` between ``own()``, the (camera, photo) of the
    batch's training view at the photos' size, and the nearest of its multi-view partners, until its
    stop), each when its weight is > 0. A model hands these in (``GaussianModel.regulariser_terms``);
    nothing here reads the model.
    """
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
        terms["anisotropy"] = reg.anisotropy_weight * scale_anisotropy(log_scales(), reg.max_anisotropy)
    if reg.stereo_weight > 0 and step >= reg.stereo_start * total_steps:
        with section("stereo"):
            draw = float(torch.rand((), generator=keyed_generator(seed, step, 1))) * 2.0 - 1.0  # stream 1 (2: background, 3: pseudo view)
            terms["stereo"] = reg.stereo_weight * _stereo_loss(outputs, batch["image"], camera, draw * reg.stereo_disparity, render)
    if reg.multiview_weight > 0 and step < reg.multiview_until * total_steps:
        views = partners(reg.multiview_partners, reg.multiview_max_angle)
        if views:
            with section("multi-view"):
                terms["multiview"] = reg.multiview_weight * multiview_photometric(
                    outputs.expected_depth, outputs.alpha, batch["image"], camera, views,
                    downsample=reg.multiview_downsample, edge_ratio=reg.multiview_edge_ratio,
                    compare=reg.multiview_compare, min_texture=reg.multiview_min_texture)
    if reg.pseudo_view_weight > 0 and step < reg.pseudo_view_until * total_steps:
        home, nearest = own(), partners(1, reg.multiview_max_angle)
        if home is not None and nearest:
            with section("pseudo view"):
                t = float(torch.rand((), generator=keyed_generator(seed, step, 3)))  # stream 3 (1: stereo, 2: background)
                terms["pseudo_view"] = reg.pseudo_view_weight * pseudo_view_consistency(
                    home, nearest[0], t, render, downsample=reg.pseudo_view_downsample, edge_ratio=reg.multiview_edge_ratio)
    return target, terms


def pseudo_view_consistency(home: tuple[Camera, Tensor], partner: tuple[Camera, Tensor], t: float,
                            render: Callable[[Camera], RenderOutput], *, downsample: int = 2,
                            edge_ratio: float = 0.0) -> Tensor:
    """A render from a view no photo was taken from must agree with the photos: the camera
    ``home.between(partner, t)`` (at 1/``downsample`` of ``home``'s size) is rendered, and each of its
    covered pixels, lifted to its rendered depth, must find its rendered colour in one of the two
    photos (:func:`~splat_framework.losses.multiview_photometric`, the render's colour in place of a
    photo). Gradients reach the render's colour and depth: a surface drawn see-through, or at a depth
    that only the training views' own pixels agree with, shows in such a view and not in theirs.

    Args:
        home: (camera, photo [H, W, 3]) of the training view, at the photo's size.
        partner: (camera, photo [h, w, 3]) of a training view near it.
        t: where between them the view lies (0: ``home``, 1: ``partner``).
        render: the model's training render of a camera.
    Returns:
        A scalar.
    """
    camera = home[0].between(partner[0], t)
    camera = camera.resized(max(1, camera.width // downsample), max(1, camera.height // downsample))
    out = render(camera)
    return multiview_photometric(out.expected_depth, out.alpha, out.rgb, camera, [home, partner], edge_ratio=edge_ratio)


def _stereo_loss(outputs: RenderOutput, image: Tensor, camera: Camera, disparity: float,
                 render: Callable[[Camera], RenderOutput]) -> Tensor:
    """losses.stereo_consistency against ``render`` of ``camera`` shifted sideways by ``disparity``
    (a fraction of the width, signed) pixels of disparity at the view's mean covered expected depth."""
    depth = outputs.expected_depth
    cover = outputs.alpha[..., 0] > 0.5
    if not bool(cover.any()):
        return depth.sum() * 0.0
    mean_z = float(depth.detach()[..., 0][cover].mean())
    fx = float(camera.K[0, 0])
    shift = disparity * camera.width * mean_z / fx
    shifted = render(camera.shifted_sideways(shift))
    return stereo_consistency(shifted.rgb, depth, outputs.alpha, image, depth.new_tensor(fx * shift))

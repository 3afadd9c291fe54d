"""SCGaussian's matching-prior losses.

Both losses are reprojection errors of matched pixels in the partner view,
L1 over (u / W, v / H) so that they do not depend on the resolution:

- Gaussian-position loss L_gp: the ray-based Gaussian of a match, projected
  into the partner view, should land on the partner pixel (both directions).
- Rendering-geometry loss L_rg: the point lifted from the *rendered* depth at
  a matched pixel, projected into the partner view, should land on the
  partner pixel.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from splat_framework.plugin import Camera


def reprojection_error(points: Tensor, camera: Camera, target_uv: Tensor) -> Tensor:
    """[M] normalised L1 distance between the projections of ``points`` [M, 3] and ``target_uv`` [M, 2].

    Points behind the camera get the error of their (clamped) projection, so the
    loss still pushes them forward.
    """
    uv, z = camera.project(points)
    scale = torch.tensor([camera.width, camera.height], dtype=uv.dtype, device=uv.device)
    err = ((uv - target_uv) / scale).abs().sum(-1)
    behind = z <= 1e-6  # no `if behind.any()`: that read would wait for the device every step
    return torch.where(behind, err.detach() + 1.0 - z, err)


def sample_depth(depth: Tensor, uv: Tensor) -> Tensor:
    """Bilinearly sample a [H, W, 1] depth map at continuous pixel coordinates ``uv`` [M, 2] -> [M]."""
    h, w = depth.shape[:2]
    grid = torch.stack([uv[:, 0] / w * 2 - 1, uv[:, 1] / h * 2 - 1], -1)[None, None]
    img = depth.permute(2, 0, 1)[None]
    return F.grid_sample(img, grid.to(img.dtype), mode="bilinear", padding_mode="border", align_corners=False)[0, 0, 0]


def rendering_geometry_loss(
    depth: Tensor, camera: Camera, uv: Tensor, partner: Camera, partner_uv: Tensor, valid: Tensor | None = None
) -> Tensor:
    """L_rg for the matches of the rendered view.

    Args:
        depth: [H, W, 1] rendered expected depth (camera z) of ``camera``.
        uv: [M, 2] matched pixels in ``camera``.
        partner: the other view of each match (one camera for the whole batch).
        partner_uv: [M, 2] the matched pixels in ``partner``.
        valid: optional [M] bool, e.g. pixels with enough rendered alpha.
    """
    z = sample_depth(depth, uv)
    ok = z > 1e-6
    if valid is not None:
        ok = ok & valid
    # every match computed and the others masked out (selecting them would read their count on the
    # host); the left-out ones are lifted at depth 1, so nothing non-finite reaches the gradient
    pts = camera.unproject_depth(uv, torch.where(ok, z, 1.0))
    err = torch.where(ok, reprojection_error(pts, partner, partner_uv), 0.0)
    return err.sum() / ok.sum().clamp_min(1)  # the mean over the kept matches; 0 when none is

"""The shared differentiable Gaussian rasterizer (PyTorch, device-agnostic).

See ``rasterize`` for the full contract. Implementation: EWA projection with
plain autograd (``_project.py``); tile binning with an opacity-aware footprint,
depth chunks and front-to-back compositing in rounds with a hand-written
backward (``_composite.py``); the per-round kernels (``_kernels.py``) run eagerly
by default. While kernels are compiled (``RenderSettings.compile``: training
and rendering runs), the projection is compiled by ``torch.compile``, and the
binning and compositing run as native C++ kernels on a CPU (``_native.py``),
the compositing as Triton kernels on CUDA (``_triton.py``), or as
``torch.compile``'d rounds elsewhere (the choice: ``backend.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import torch
from torch import Tensor

from ..runtime.profiling import section
from ..runtime.threads import follow_load
from ._composite import TileGrid, composite, pixel_basis, tile_footprints
from ._kernels import get_kernels
from ._project import ProjectFn, footprint, project, reference_radii
from .backend import kernels_for
from .settings import RenderSettings

__all__ = ["RenderOutput", "rasterize"]

_DEFAULT_SETTINGS = RenderSettings()
"""What a render without ``settings`` takes: the eager torch kernels."""


@dataclass
class RenderOutput:
    """Result of ``rasterize``.

    Attributes:
        rgb: [H, W, 3] composited colour (background blended in).
        depth: [H, W, 1] sum_i w_i z_i (camera z), or that divided by alpha
            when ``depth_mode="expected"``.
        alpha: [H, W, 1] accumulated opacity sum_i w_i.
        meta: "means2d" [N, 2] pixel-space centres whose ``.grad`` after
            backward holds the screen-space positional gradient; "radii" [N]
            int pixel radius (0 = not rendered); "visible" [N] bool;
            "depths" [N] camera z; "width", "height" ints.
        depth_mode: the mode ``depth`` was rendered in ("accumulated" or "expected").
    """

    rgb: Tensor
    depth: Tensor
    alpha: Tensor
    meta: dict = field(default_factory=dict)
    depth_mode: Literal["accumulated", "expected"] = "accumulated"

    @cached_property
    def expected_depth(self) -> Tensor:
        """[H, W, 1] expected depth sum_i w_i z_i / alpha whichever mode ``depth`` was rendered in,
        computed on first use and kept (every loss term and metric shares one)."""
        if self.depth_mode == "expected":
            return self.depth
        return self.depth / self.alpha.clamp_min(1e-6)


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    depth_mode: Literal["accumulated", "expected"] = "accumulated",
    eps2d: float = 0.3,
    tile_size: int = 8,
    block: int | None = None,
    chunk_pairs: int | None = None,
    settings: RenderSettings | None = None,
    absgrad: bool = False,
) -> RenderOutput:
    """Render 3D Gaussians into one pinhole camera (3DGS reference semantics).

    Camera convention (``splat_framework.cameras``): OpenCV axes (x right,
    y down, z forward); a Gaussian projected to continuous pixel position
    (u, v) = (fx x/z + cx, fy y/z + cy) is evaluated at pixel (px, py) at the
    pixel centre (px + 0.5, py + 0.5).

    Pipeline:
      1. Projection (EWA): camera-space mean p = R mean + t; Gaussians with
         z outside [near_plane, far_plane] are culled. 2D covariance
         J W Sigma W^T J^T + eps2d * I, with the 3D covariance
         Sigma = R(q) S S^T R(q)^T and the Jacobian J evaluated at x/z, y/z
         clamped to 1.3x the field of view (asymmetric for an off-centre
         principal point, as in gsplat), so huge off-screen Gaussians stay
         finite. No opacity compensation for the eps2d dilation (like 3DGS).
      2. Colours: ``colors`` [N, 3] are used as they are; SH coefficients
         [N, K, 3] are evaluated at the unit direction camera centre -> mean
         with ``sh_degree`` (default: the largest degree K allows), and the
         colour is max(SH + 0.5, 0).
      3. Compositing, per pixel, front to back in order of camera z:
         alpha_i = min(0.99, o_i exp(-q_i / 2)) with q_i the squared
         Mahalanobis distance under the 2D covariance; Gaussians with alpha_i < 1/255
         are skipped; a Gaussian whose inclusion would bring the
         transmittance below 1e-4 is not included and compositing stops
         for that pixel. w_i = alpha_i T_i, T_i = prod_{j<i} (1 - alpha_j).
         Gaussians whose opacity-aware footprint (where alpha >= 1/255)
         misses the image are not rendered at all.

    Gradients flow to means, quats, scales, opacities, colours / SH
    coefficients, background and (when it requires grad) viewmat from rgb,
    depth and alpha (means and viewmat also get the SH view-direction term). The hard thresholds (1/255 skip, termination) have zero
    gradient; where the 0.99 clamp is active alpha has zero gradient
    (as in gsplat; the 3DGS CUDA backward ignores the clamp).

    Args:
        means: [N, 3] world-space centres.
        quats: [N, 4] rotations as (w, x, y, z) quaternions, not necessarily
            normalised.
        scales: [N, 3] standard deviations along the local axes (activated,
            i.e. already exp'd).
        opacities: [N] opacities in [0, 1] (activated).
        colors: [N, 3] RGB colours, or [N, K, 3] SH coefficients
            (K >= (sh_degree + 1)^2, 3DGS ordering).
        viewmat: [4, 4] world-to-camera transform.
        K: [3, 3] intrinsics (fx, fy, cx, cy; any principal point).
        width: image width W in pixels.
        height: image height H in pixels.
        sh_degree: active SH degree 0..3 when ``colors`` is [N, K, 3]
            (None: sqrt(K) - 1). Must be None for [N, 3] colours.
        background: [3] colour blended in as background * (1 - alpha)
            (default black).
        near_plane: Gaussians with camera z < near_plane are culled.
        far_plane: Gaussians with camera z > far_plane are culled.
        depth_mode: "accumulated" -> depth = sum_i w_i z_i;
            "expected" -> that divided by alpha (0 where alpha == 0).
        eps2d: low-pass dilation added to the 2D covariance diagonal (px^2).
        tile_size: tile edge in pixels used for binning (performance only;
            8 measured fastest on CPU at 504x378).
        block: pairs per tile evaluated per compositing round (performance
            only; early termination drops finished tiles between rounds).
            None: 8 with the compiled kernels, 4 with the eager ones (each
            measured fastest on real fern training steps); the native CPU
            kernels walk each tile's whole list and do not use it.
        chunk_pairs: (tile, Gaussian) pairs binned per depth chunk
            (performance only; None: 128 per tile). Tiles finished by nearer
            chunks are skipped by farther ones.
        settings: which kernels render (:class:`.settings.RenderSettings`;
            None: the eager torch kernels). With ``compile``: the native C++
            kernels for CPU tensors (:mod:`._native`), the Triton kernels for
            CUDA tensors (:mod:`._triton`), torch.compile'd per-round kernels
            elsewhere or where neither can run (eager fallback on any compile
            failure); ``rasterizer`` names one (:mod:`.backend`).
        absgrad: the backward also leaves ``meta["means2d"].absgrad`` [N, 2]:
            per Gaussian, the sums over the pixels of each pixel's |dL/du| and
            |dL/dv| (pixel units), the criterion of AbsGS (Ye et al. 2024;
            gsplat's ``absgrad``): unlike ``means2d.grad``, opposite pixel
            gradients of a large Gaussian do not cancel. The native kernels
            and the eager torch kernels compute it (a compiled torch backward
            runs eager for such a render).

    Environment:
        SPLAT_THREADS: the process's CPU threads (:mod:`splat_framework.runtime.threads`);
            each CPU call lets the "auto" count follow the machine's load.

    Returns:
        RenderOutput with
            rgb: [H, W, 3] sum_i w_i c_i + background * (1 - alpha).
            depth: [H, W, 1] see ``depth_mode`` (camera z, not ray length).
            alpha: [H, W, 1] sum_i w_i = 1 - final transmittance.
            meta: dict with
                "means2d": [N, 2] projected centres in pixels (u, v); part of
                    the graph, ``retain_grad()`` is called on it when grad is
                    enabled, so after backward ``meta["means2d"].grad`` is the
                    screen-space positional gradient (pixel units), summed over
                    all pixels (zero for Gaussians that were not rendered);
                    with ``absgrad`` also ``meta["means2d"].absgrad``.
                "radii": [N] int32, ceil(3 sqrt(largest eigenvalue of the 2D
                    covariance)) like the 3DGS reference for rendered
                    Gaussians, 0 for culled ones.
                "visible": [N] bool, the Gaussian was rendered (inside
                    near/far, opacity >= 1/255, footprint touches the image).
                "depths": [N] camera-space z of every mean (also culled ones).
                "conics": [N, 3] inverse 2D covariance (a, b, c).
                "width", "height": ints.
                "background": [3] the colour blended in.
    """
    if means.device.type == "cpu":
        follow_load()
    return _rasterize(
        means, quats, scales, opacities, colors, viewmat, K, width, height,
        sh_degree=sh_degree, background=background, near_plane=near_plane,
        far_plane=far_plane, depth_mode=depth_mode, eps2d=eps2d, tile_size=tile_size,
        block=block, chunk_pairs=chunk_pairs, settings=_DEFAULT_SETTINGS if settings is None else settings, absgrad=absgrad,
    )


def _rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None,
    background: Tensor | None,
    near_plane: float,
    far_plane: float,
    depth_mode: str,
    eps2d: float,
    tile_size: int,
    block: int | None,
    chunk_pairs: int | None,
    settings: RenderSettings,
    absgrad: bool,
) -> RenderOutput:
    if depth_mode not in ("accumulated", "expected"):
        raise ValueError(f"depth_mode must be 'accumulated' or 'expected', got {depth_mode!r}")
    device, dtype = means.device, means.dtype
    n = means.shape[0]
    opacities = opacities.reshape(n)  # also accept [N, 1]
    width = int(width)
    height = int(height)

    viewmat = viewmat.to(device=device, dtype=dtype)
    K = K.to(device=device, dtype=dtype)
    if colors.dim() == 2:
        if colors.shape[-1] != 3:
            raise ValueError(f"colors must be [N, 3] or [N, K, 3], got {tuple(colors.shape)}")
        if sh_degree is not None:
            raise ValueError("sh_degree given but colors is [N, 3]; pass SH as [N, K, 3]")
    elif colors.dim() != 3 or colors.shape[-1] != 3:
        raise ValueError(f"colors must be [N, 3] or [N, K, 3], got {tuple(colors.shape)}")
    if background is None:
        background = torch.zeros(3, device=device, dtype=dtype)
    else:
        background = background.to(device=device, dtype=dtype)
    opacities = opacities.to(dtype)

    # ------------------------------------------------- projection, colours
    cfg = (width, height, near_plane, far_plane, eps2d, sh_degree)
    proj_inputs = (means, quats, scales, colors, viewmat, K)
    with section("projection"):
        if torch.is_grad_enabled() and any(t.requires_grad for t in proj_inputs):
            # one autograd node, its backward one timed section
            means2d, conics, cov2d, depths, valid, rgb_g = ProjectFn.apply(*proj_inputs, cfg, settings)
            if means2d.requires_grad:
                means2d.retain_grad()
        else:
            means2d, conics, cov2d, depths, valid, rgb_g = project(*proj_inputs, cfg, settings)
        ext_x, ext_y, ok, qmax = footprint(cov2d, opacities, valid)
    grid = TileGrid(
        tile=tile_size,
        ntx=(width + tile_size - 1) // tile_size,
        nty=(height + tile_size - 1) // tile_size,
        width=width,
        height=height,
    )
    kernels = kernels_for(device, settings)
    with section("binning"):
        fp = tile_footprints(means2d, ext_x, ext_y, ok, depths, cov2d, qmax, grid,
                             kernels.binning if kernels is not None else None)

    # --------------------------------------------------------- compositing
    basis = pixel_basis(tile_size, device, dtype)
    if chunk_pairs is None:
        chunk_pairs = (kernels.chunk_pairs_per_tile if kernels is not None else 128) * grid.n_tiles
    if block is None:
        block = 8 if settings.compile else 4
    with section("compositing"):
        rgb, depth, alpha = composite(
            means2d, conics, opacities, rgb_g.to(dtype), depths, background, fp, grid, basis, block,
            chunk_pairs, kernels, None if kernels is not None else get_kernels(settings), absgrad,
        )
    if depth_mode == "expected":
        depth = torch.where(alpha > 0, depth / alpha.clamp_min(1e-12), torch.zeros_like(depth))

    meta = {
        "means2d": means2d,
        "radii": reference_radii(cov2d, fp.hit),
        "visible": fp.hit,
        "depths": depths,
        "conics": conics,
        "width": width,
        "height": height,
        "background": background,
    }
    return RenderOutput(rgb=rgb, depth=depth, alpha=alpha, meta=meta, depth_mode=depth_mode)

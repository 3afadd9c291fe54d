"""Photometric losses: L1 and the 3DGS-reference SSIM.

Images are [H, W, 3] (or [B, H, W, 3]) float tensors, channels last. Masks are
[H, W] / [H, W, 1] (or with a leading B), bool or float in [0, 1].

SSIM is written here (a few lines of ``F.conv2d``) rather than taken from
``kornia.metrics.ssim`` because kornia's ``padding="same"`` pads with
``reflect`` and adds ``eps`` to the denominator, while the 3DGS reference pads
the image with zeros (``F.conv2d(..., padding=5)``); the two differ near the
border (0.9485 vs 0.9452 mean SSIM for a noisy 64x64 pair), so kornia would not
reproduce 3DGS numbers.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

if TYPE_CHECKING:
    from .cameras import Camera
    from .render.settings import RenderSettings

C1 = 0.01**2
C2 = 0.03**2


def _to_bchw(img: Tensor) -> Tensor:
    if img.dim() == 3:
        img = img[None]
    if img.dim() != 4:
        raise ValueError(f"expected [H,W,C] or [B,H,W,C] image, got shape {tuple(img.shape)}")
    return img.permute(0, 3, 1, 2)


def mask_bhw1(mask: Tensor, like: Tensor) -> Tensor:
    """Mask as float [B, H, W, 1] broadcastable against ``like`` ([H,W,C] or [B,H,W,C])."""
    m = mask.to(like.dtype)
    if like.dim() == 3:
        m = m.reshape(1, *like.shape[:2], 1)
    else:
        m = m.reshape(-1, *like.shape[1:3], 1)
    return m


def _gaussian_1d(window: int, sigma: float, like: Tensor) -> Tensor:
    """[window] normalised Gaussian taps (the 3DGS reference window is its outer product)."""
    r = window // 2
    x = torch.tensor([math.exp(-((i - r) ** 2) / (2 * sigma**2)) for i in range(window)], dtype=torch.float64)
    return (x / x.sum()).to(device=like.device, dtype=like.dtype)


def gaussian_blur(t: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """[B, C, H, W] -> [B, C, H, W]: each channel convolved with the window x window Gaussian, zero padded.

    Separable (a row pass, then a column pass): 2 * window taps per pixel instead of
    window^2, and equal to the 2D convolution with zero padding (zero rows stay zero)."""
    c, pad = t.shape[1], window // 2
    g = _gaussian_1d(window, sigma, t)
    t = F.conv2d(t, g.reshape(1, 1, 1, window).expand(c, 1, 1, window), padding=(0, pad), groups=c)
    return F.conv2d(t, g.reshape(1, 1, window, 1).expand(c, 1, window, 1), padding=(pad, 0), groups=c)


def ssim_map(pred: Tensor, gt: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """Per-pixel SSIM [B, H, W, C] exactly as the 3DGS reference (zero padding, C1, C2).

    The five local means (x, y, x^2, y^2, xy) come from one separable blur of their stack."""
    if pred.shape != gt.shape:
        raise ValueError(f"shape mismatch {tuple(pred.shape)} vs {tuple(gt.shape)}")
    x, y = _to_bchw(pred), _to_bchw(gt)
    mu1, mu2, ex2, ey2, exy = gaussian_blur(torch.cat([x, y, x * x, y * y, x * y], 1), window, sigma).chunk(5, 1)
    mu1_sq, mu2_sq, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    s1 = ex2 - mu1_sq
    s2 = ey2 - mu2_sq
    s12 = exy - mu12
    m = ((2 * mu12 + C1) * (2 * s12 + C2)) / ((mu1_sq + mu2_sq + C1) * (s1 + s2 + C2))
    return m.permute(0, 2, 3, 1)


def ssim(pred: Tensor, gt: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """Mean SSIM over all pixels and channels (3DGS reference ``ssim``); differentiable scalar."""
    return ssim_map(pred, gt, window, sigma).mean()


def l1_loss(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean absolute error; with ``mask``, the mean over masked pixels (all channels)."""
    if mask is None:
        return (pred - gt).abs().mean()
    m = mask_bhw1(mask, pred)
    err = (pred - gt).abs().reshape(m.shape[0], *pred.shape[-3:]) * m
    return err.sum() / (m.sum() * pred.shape[-1]).clamp_min(1e-8)


def photometric_loss(pred: Tensor, gt: Tensor, lambda_dssim: float = 0.2, mask: Tensor | None = None,
                     settings: RenderSettings | None = None) -> Tensor:
    """(1 - lambda) * L1 + lambda * (1 - SSIM), the 3DGS training loss.

    With ``mask``, both terms are averaged over masked pixels only (the SSIM
    map is still computed on the whole image).

    While kernels are compiled (``settings``, the model's ``render_settings``: training runs), the
    unmasked loss of a prediction on the CPU that needs a gradient runs in the native kernels
    (render/native/loss.cpp): on fern's 504x378 views, forward and backward in a few ms instead of
    27 ms eager (2 threads). Elsewhere (CUDA) it runs eagerly: torch.compile would save 0.9 ms a
    step on an H200 but cost 60 s of compiling in every process (docs/rasterizer.md#on-cuda).
    """
    if mask is None and pred.requires_grad and settings is not None and settings.compile:
        native = _native_loss(pred, gt, settings)
        if native is not None:
            return _NativePhotometric.apply(pred, gt, float(lambda_dssim), native)
    return _photometric(pred, gt, lambda_dssim, mask)


def _native_loss(pred: Tensor, gt: Tensor, settings: RenderSettings):
    """The native kernels (``photometric_forward`` / ``photometric_backward``, render/native/loss.cpp) for
    one [H, W, C] prediction on a CPU against a constant photo, where they could be built; else None."""
    if pred.dim() != 3 or pred.shape != gt.shape or gt.requires_grad or pred.dtype != gt.dtype:
        return None
    from .render import backend

    native = backend.native_for(pred.device, settings)
    return native if native is not None and hasattr(native, "photometric_forward") else None


class _NativePhotometric(torch.autograd.Function):
    """The unmasked photometric loss by the native kernels: the same value as ``_photometric`` up to
    rounding, no tracing, and the same result for any thread count (sums in a fixed order)."""

    @staticmethod
    def forward(ctx, pred, gt, lambda_dssim, native):  # type: ignore[override]
        taps = _gaussian_1d(11, 1.5, pred)
        loss, stats = native.photometric_forward(pred, gt, taps, lambda_dssim)
        ctx.save_for_backward(pred, gt, taps, stats)
        ctx.lambda_dssim, ctx.native = lambda_dssim, native
        return loss

    @staticmethod
    def backward(ctx, grad):  # type: ignore[override]
        pred, gt, taps, stats = ctx.saved_tensors
        return ctx.native.photometric_backward(pred, gt, taps, ctx.lambda_dssim, stats, grad), None, None, None


def _photometric(pred: Tensor, gt: Tensor, lambda_dssim: float = 0.2, mask: Tensor | None = None) -> Tensor:
    l1 = l1_loss(pred, gt, mask)
    if mask is None:
        s = ssim(pred, gt)
    else:
        m = mask_bhw1(mask, pred)
        smap = ssim_map(pred, gt) * m
        s = smap.sum() / (m.sum() * pred.shape[-1]).clamp_min(1e-8)
    return (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - s)


def depth_smoothness(depth: Tensor, image: Tensor, alpha: Tensor, gamma: float = 10.0, min_alpha: float = 0.5) -> Tensor:
    """Edge-aware smoothness of a rendered depth map (Monodepth's disparity smoothness, on depth).

    Mean over neighbouring pixel pairs (rows and columns) of ``|depth_a - depth_b| / mean depth
    * exp(-gamma * mean_c |image_a - image_b|)``: a colour edge of the photo lets the depth jump;
    the mean depth (detached) makes the term independent of the scene's scale. Only pairs whose
    rendered ``alpha`` both exceed ``min_alpha`` count (empty space has no depth).

    Args:
        depth: [H, W, 1] rendered (expected) depth.
        image: [H, W, 3] the photo, in [0, 1].
        alpha: [H, W, 1] rendered opacity.
    Returns:
        A scalar; 0 (with a graph) when no pair is covered.
    """
    cover = (alpha[..., 0] > min_alpha).to(depth.dtype)
    n = cover.sum()
    d = depth[..., 0] / ((depth[..., 0] * cover).sum() / n.clamp_min(1.0)).detach().clamp_min(1e-6)
    total, count = depth.sum() * 0.0, depth.new_zeros(())
    for dim in (0, 1):
        if d.shape[dim] < 2:
            continue
        m = cover.narrow(dim, 0, d.shape[dim] - 1) * cover.narrow(dim, 1, d.shape[dim] - 1)
        edge = torch.exp(-gamma * torch.diff(image, dim=dim).abs().mean(-1))
        total = total + (torch.diff(d, dim=dim).abs() * edge * m).sum()
        count = count + m.sum()
    return total / count.clamp_min(1.0)


def multiview_photometric(depth: Tensor, alpha: Tensor, image: Tensor, camera: Camera,
                          partners: list[tuple[Camera, Tensor]], min_alpha: float = 0.5, downsample: int = 1,
                          edge_ratio: float = 0.0, compare: str = "colour", min_texture: float = 1e-4) -> Tensor:
    """Multi-view photometric consistency of a rendered depth: each pixel of the view, lifted to its
    rendered depth and projected into the other training views, must find there the colour it has
    in its own photo (the plane-sweep rule of multi-view stereo, on the training photos themselves).

    Per pixel the smallest mean absolute colour difference over the ``partners`` that see the
    point (in front of the camera, inside the image; Monodepth2's minimum reprojection, so a pixel
    occluded in one partner is judged by another), averaged over pixels whose ``alpha`` exceeds
    ``min_alpha`` and that some partner sees. The partners' photos are constants: gradients reach
    the depth only, and only where a partner's photo has texture (a flat wall gives none). With
    ``downsample`` f > 1 the comparison runs on the depth, opacity and photos area-averaged to 1/f
    of their size, with the cameras resized to match: the consistency of the coarse geometry, at
    1/f^2 of the cost.

    ``compare="ncc"`` judges a pixel by the normalised cross-correlation of the grey 3x3 patches
    around it, its photo's against the partner's colours at the projections of the patch's pixels
    (error ``(1 - ncc) / 2``, 0 for patches equal up to gain and offset), as multi-view stereo does:
    a change of exposure or a sheen between the photos costs nothing, and a pixel whose own patch's
    grey variance is at most ``min_texture`` is left out (a flat wall says nothing of its depth).

    Args:
        depth: [H, W, 1] the view's rendered (expected) depth, camera z (``camera``'s size).
        alpha: [H, W, 1] the view's rendered opacity.
        image: [H, W, 3] the view's photo, at the render's size.
        camera: the rendered camera.
        partners: (camera, photo [h, w, 3]) of other views, each photo at its camera's size.
    Returns:
        A scalar; 0 (with a graph) when no pixel is valid.
    """
    flat = _depth_span(depth.detach(), camera, downsample) <= edge_ratio if edge_ratio > 0 else None
    if downsample > 1:
        depth, alpha, image = (_area(t, camera, downsample) for t in (depth, alpha, image))
        partners = [(_shrunk(c, downsample), _area(p.to(depth.dtype), c, downsample)) for c, p in partners]
        camera = _shrunk(camera, downsample)
    u = torch.arange(camera.width, device=depth.device, dtype=depth.dtype) + 0.5
    v = torch.arange(camera.height, device=depth.device, dtype=depth.dtype) + 0.5
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)  # [H, W, 2]
    points = camera.unproject_depth(uv, depth[..., 0])
    best = depth.new_full(depth.shape[:2], float("inf"))
    for partner, photo in partners:
        puv, pz = partner.project(points)
        pw, ph = partner.width, partner.height
        inside = (pz > 1e-6) & (puv[..., 0] >= 0.5) & (puv[..., 0] <= pw - 0.5) & (puv[..., 1] >= 0.5) & (puv[..., 1] <= ph - 0.5)
        grid = torch.stack([2.0 * puv[..., 0] / pw - 1.0, 2.0 * puv[..., 1] / ph - 1.0], dim=-1)
        seen = F.grid_sample(_to_bchw(photo.to(depth.dtype)), grid[None], mode="bilinear", padding_mode="border",
                             align_corners=False)[0].permute(1, 2, 0)
        if compare == "ncc":
            err, textured = _patch_ncc_error(image, seen)
            inside = inside & (textured > min_texture)
        else:
            err = (seen - image).abs().mean(-1)
        best = torch.where(inside & (err < best), err, best)
    valid = (alpha[..., 0] > min_alpha) & torch.isfinite(best)
    if flat is not None:
        valid = valid & flat
    err = torch.where(valid, best, 0.0).sum() + depth.sum() * 0.0  # a graph even when nothing is seen
    return err / valid.sum().clamp_min(1)  # no host sync


def _patch_ncc_error(image: Tensor, seen: Tensor) -> tuple[Tensor, Tensor]:
    """([h, w] ``(1 - ncc) / 2`` of the grey 3x3 patches of ``image`` and ``seen`` [h, w, 3] around
    each pixel, [h, w] the grey variance of ``image``'s patch); patches cut by the border are averaged
    over their pixels inside."""
    a, b = image.mean(-1)[None, None], seen.mean(-1)[None, None]

    def box(t: Tensor) -> Tensor:
        return F.avg_pool2d(t, 3, 1, 1, count_include_pad=False)
    mean_a, mean_b = box(a), box(b)
    var_a, var_b = box(a * a) - mean_a * mean_a, box(b * b) - mean_b * mean_b
    ncc = (box(a * b) - mean_a * mean_b) / torch.sqrt(var_a.clamp_min(0) * var_b.clamp_min(0) + 1e-8)
    return ((1 - ncc) / 2)[0, 0], var_a[0, 0]


def _depth_span(depth: Tensor, camera: Camera, factor: int) -> Tensor:
    """[h, w] largest / smallest of ``depth`` [H, W, 1] over each compared pixel's block (1/``factor``
    size) and its 3x3 neighbours: large across an occluding edge, near 1 on a surface."""
    d = _to_bchw(depth.clamp_min(1e-6))
    small = _shrunk(camera, factor)
    hi, lo = (F.adaptive_max_pool2d(s * d, (small.height, small.width)) * s for s in (1.0, -1.0))
    hi, lo = F.max_pool2d(hi, 3, 1, 1), -F.max_pool2d(-lo, 3, 1, 1)
    return (hi / lo)[0, 0]


def _shrunk(camera: Camera, factor: int) -> Camera:
    """``camera`` for its image area-averaged to 1/``factor`` of its size (at least one pixel)."""
    return camera.resized(max(1, camera.width // factor), max(1, camera.height // factor))


def _area(img: Tensor, camera: Camera, factor: int) -> Tensor:
    """[H, W, C] ``img`` (``camera``'s size) area-averaged to ``_shrunk(camera, factor)``'s size."""
    small = _shrunk(camera, factor)
    return F.interpolate(_to_bchw(img), size=(small.height, small.width), mode="area")[0].permute(1, 2, 0)


def scale_anisotropy(log_scales: Tensor, max_ratio: float) -> Tensor:
    """Anisotropy regulariser (PhysGaussian, Xie et al., CVPR 2024): mean over Gaussians of
    ``max(largest scale / smallest scale - max_ratio, 0)``, so that no Gaussian grows into a
    needle that is thin in the training views and a streak in a novel one.

    Args:
        log_scales: [N, 3] log-scales.
        max_ratio: the ratio above which a Gaussian is penalised (>= 1).
    Returns:
        A scalar; 0 (with a graph) for no Gaussians.
    """
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    spread = log_scales.amax(dim=-1) - log_scales.amin(dim=-1)
    return F.relu(torch.exp(spread.clamp_max(30.0)) - max_ratio).mean()


def stereo_consistency(shifted_rgb: Tensor, depth: Tensor, alpha: Tensor, image: Tensor, disparity_scale: Tensor,
                       min_alpha: float = 0.5) -> Tensor:
    """Binocular consistency (Han et al., "Binocular-Guided 3D Gaussian Splatting", NeurIPS 2024):
    the render of a camera shifted sideways, warped back to the view with the disparity of the
    view's rendered depth, must match the photo.

    A pixel at column u (centres at +0.5) and depth z is seen at ``u - disparity_scale / z`` in the
    shifted render (``disparity_scale`` = focal length x shift, see :meth:`Camera.shifted_sideways`);
    the mean absolute colour difference over pixels whose ``alpha`` exceeds ``min_alpha`` and whose
    partner lies inside the shifted image. Gradients reach both the shifted render and the depth.

    Args:
        shifted_rgb: [H, W, 3] render of the shifted camera.
        depth: [H, W, 1] the view's rendered (expected) depth.
        alpha: [H, W, 1] the view's rendered opacity.
        image: [H, W, 3] the view's photo.
        disparity_scale: scalar tensor, focal length (pixels) x shift (world units).
    Returns:
        A scalar; 0 (with a graph) when no pixel is valid.
    """
    h, w = depth.shape[:2]
    u = torch.arange(w, device=depth.device, dtype=depth.dtype) + 0.5
    v = torch.arange(h, device=depth.device, dtype=depth.dtype) + 0.5
    u_src = u[None, :] - disparity_scale / depth[..., 0].clamp_min(1e-6)  # [H, W]
    grid = torch.stack([2.0 * u_src / w - 1.0, (2.0 * v / h - 1.0)[:, None].expand(h, w)], dim=-1)
    warped = F.grid_sample(_to_bchw(shifted_rgb), grid[None], mode="bilinear", padding_mode="border",
                           align_corners=False)[0].permute(1, 2, 0)
    valid = ((alpha[..., 0] > min_alpha) & (u_src >= 0.5) & (u_src <= w - 0.5)).to(depth.dtype)
    err = (warped - image).abs().mean(-1)
    return (err * valid).sum() / valid.sum().clamp_min(1.0)

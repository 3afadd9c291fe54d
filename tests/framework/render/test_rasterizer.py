"""Tests for the pure-PyTorch Gaussian rasterizer against a brute-force reference.

The reference below evaluates every Gaussian at every pixel, sorts explicitly by
depth and composites with a plain Python loop over Gaussians (vectorised over
pixels) exactly like the 3DGS CUDA forward; gradients come from autograd.
"""

from __future__ import annotations

import math
import shutil
import warnings

import pytest
import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix

from splat_framework.cameras import intrinsics, look_at
from splat_framework.render import RenderOutput, RenderSettings, eval_sh, rasterize


# ----------------------------------------------------------------------------- reference
def reference_render(
    means,
    quats,
    scales,
    opacities,
    colors,
    viewmat,
    K,
    width,
    height,
    *,
    sh_degree=None,
    background=None,
    near_plane=0.01,
    far_plane=1e10,
    eps2d=0.3,
    return_means2d=False,
):
    dtype = means.dtype
    viewmat = viewmat.to(dtype)
    K = K.to(dtype)
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if colors.dim() == 3:
        deg = int(math.isqrt(colors.shape[1])) - 1 if sh_degree is None else sh_degree
        campos = -R.T @ t
        d = means - campos
        d = d / d.norm(dim=-1, keepdim=True)
        colors = torch.clamp_min(eval_sh(deg, colors, d) + 0.5, 0.0)
    if background is None:
        background = torch.zeros(3, dtype=dtype)

    pc = means @ R.T + t
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    keep = (z >= near_plane) & (z <= far_plane)
    zs = torch.where(keep, z, torch.ones_like(z))
    Rq = quaternion_to_rotation_matrix(quats / quats.norm(dim=-1, keepdim=True))
    Sigma = Rq @ torch.diag_embed(scales**2) @ Rq.transpose(1, 2)
    lim_xp = (width - cx) / fx + 0.3 * 0.5 * width / fx
    lim_xn = cx / fx + 0.3 * 0.5 * width / fx
    lim_yp = (height - cy) / fy + 0.3 * 0.5 * height / fy
    lim_yn = cy / fy + 0.3 * 0.5 * height / fy
    tx = torch.clamp(x / zs, -lim_xn, lim_xp) * zs
    ty = torch.clamp(y / zs, -lim_yn, lim_yp) * zs
    J = torch.zeros(means.shape[0], 2, 3, dtype=dtype)
    J[:, 0, 0] = fx / zs
    J[:, 0, 2] = -fx * tx / zs**2
    J[:, 1, 1] = fy / zs
    J[:, 1, 2] = -fy * ty / zs**2
    cov2d = J @ R @ Sigma @ R.T @ J.transpose(1, 2) + eps2d * torch.eye(2, dtype=dtype)
    conic = torch.linalg.inv(cov2d)
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
    if return_means2d and means2d.requires_grad:
        means2d.retain_grad()

    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij"
    )
    pix = torch.stack([xs, ys], -1).reshape(-1, 2) + 0.5  # [HW, 2]
    d = pix[:, None, :] - means2d[None, :, :]  # [HW, N, 2]
    q = torch.einsum("pni,nij,pnj->pn", d, conic, d)
    alpha = torch.clamp(opacities[None, :] * torch.exp(-0.5 * q), max=0.99)
    alpha = alpha * keep[None, :]

    order = torch.argsort(z.detach(), stable=True)
    hw = height * width
    T = torch.ones(hw, dtype=dtype)
    done = torch.zeros(hw, dtype=torch.bool)
    C = torch.zeros(hw, 3, dtype=dtype)
    D = torch.zeros(hw, dtype=dtype)
    for i in order.tolist():
        a = alpha[:, i]
        use = (a >= 1.0 / 255.0) & ~done
        test_T = T * (1 - a)
        stop = use & (test_T < 1e-4)
        done = done | stop
        use = use & ~stop
        w = torch.where(use, a * T, torch.zeros_like(a))
        C = C + w[:, None] * colors[i][None, :]
        D = D + w * z[i]
        T = torch.where(use, test_T, T)
    A = 1 - T
    rgb = C + T[:, None] * background
    out = (
        rgb.reshape(height, width, 3),
        D.reshape(height, width, 1),
        A.reshape(height, width, 1),
    )
    if return_means2d:
        return out + (means2d,)
    return out


# ----------------------------------------------------------------------------- scenes
def make_camera(width, height, f=None, cx=None, cy=None, dtype=torch.float32):
    f = f if f is not None else 0.9 * max(width, height)
    K = intrinsics(f, f, width / 2 if cx is None else cx, height / 2 if cy is None else cy)
    viewmat = look_at(
        torch.tensor([0.3, -0.2, -4.0]), torch.tensor([0.0, 0.0, 0.0]), torch.tensor([0.0, -1.0, 0.0])
    )
    return viewmat.to(dtype), K.to(dtype)


def random_scene(n, seed, dtype=torch.float64, sh_k=None, spread=1.2, scale=(-2.5, 0.4)):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) - 0.5) * 2 * spread
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.exp(scale[0] + scale[1] * torch.randn(n, 3, generator=g, dtype=dtype))
    opac = 0.05 + 0.9 * torch.rand(n, generator=g, dtype=dtype)
    if sh_k is None:
        colors = torch.rand(n, 3, generator=g, dtype=dtype)
    else:
        colors = 0.3 * torch.randn(n, sh_k, 3, generator=g, dtype=dtype)
        colors[:, 0] += 0.8
    return means, quats, scales, opac, colors


def _loss_weights(h, w, seed, dtype):
    g = torch.Generator().manual_seed(seed)
    return (
        torch.randn(h, w, 3, generator=g, dtype=dtype),
        torch.randn(h, w, 1, generator=g, dtype=dtype),
        torch.randn(h, w, 1, generator=g, dtype=dtype),
    )


def _compare(n, seed, width, height, dtype, sh_k=None, sh_degree=None, tile_size=16, block=32,
             chunk_pairs=None, fwd_tol=1e-4, grad_rtol=1e-6, **cam):
    viewmat, K = make_camera(width, height, dtype=dtype, **cam)
    viewmat.requires_grad_()  # camera pose gradients flow through the projection too
    params = [p.requires_grad_() for p in random_scene(n, seed, dtype=dtype, sh_k=sh_k)]
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=dtype)
    wr, wd, wa = _loss_weights(height, width, seed + 1, dtype)

    out = rasterize(*params, viewmat, K, width, height, sh_degree=sh_degree, background=bg,
                    tile_size=tile_size, block=block, chunk_pairs=chunk_pairs)
    loss = (out.rgb * wr).sum() + 0.1 * (out.depth * wd).sum() + (out.alpha * wa).sum()
    grads = torch.autograd.grad(loss, params + [viewmat])

    rgb, depth, alpha = reference_render(*params, viewmat, K, width, height, sh_degree=sh_degree,
                                         background=bg)
    assert alpha.max() > 0.5, "scene renders nothing; test is vacuous"
    torch.testing.assert_close(out.rgb, rgb, atol=fwd_tol, rtol=0)
    torch.testing.assert_close(out.alpha, alpha, atol=fwd_tol, rtol=0)
    torch.testing.assert_close(out.depth, depth, atol=fwd_tol * 10, rtol=fwd_tol)
    ref_loss = (rgb * wr).sum() + 0.1 * (depth * wd).sum() + (alpha * wa).sum()
    ref_grads = torch.autograd.grad(ref_loss, params + [viewmat])
    names = ["means", "quats", "scales", "opacities", "colors", "viewmat"]
    for name, ga, gb in zip(names, grads, ref_grads):
        scale = gb.abs().max().clamp_min(1e-3)
        err = (ga - gb).abs().max() / scale
        assert err < grad_rtol, f"grad {name}: rel err {err:.3g}"


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_bruteforce_float64(seed):
    _compare(40, seed, 37, 29, torch.float64)


def test_matches_bruteforce_small_tiles_small_blocks_many_chunks():
    # many rounds and depth chunks, termination across rounds and chunks, tile size 8
    _compare(60, 3, 33, 26, torch.float64, tile_size=8, block=4, chunk_pairs=16)


def test_matches_bruteforce_float32():
    _compare(40, 5, 37, 29, torch.float32, grad_rtol=2e-3)


@pytest.mark.parametrize("deg", [0, 1, 2, 3])
def test_matches_bruteforce_sh(deg):
    _compare(30, 10 + deg, 27, 21, torch.float64, sh_k=16, sh_degree=deg)


def test_non_square_off_centre_principal_point():
    _compare(40, 7, 41, 17, torch.float64, cx=14.0, cy=11.5)
    _compare(40, 8, 19, 45, torch.float64, cx=12.0, cy=20.0, f=30.0)


def test_early_termination_dense_opaque_scene():
    # many opaque, large Gaussians: transmittance drops below 1e-4 quickly
    dtype = torch.float64
    width, height = 24, 20
    viewmat, K = make_camera(width, height, dtype=dtype)
    means, quats, scales, opac, colors = random_scene(80, 21, dtype=dtype, spread=0.5,
                                                     scale=(-1.0, 0.2))
    opac = 0.7 + 0.29 * torch.rand(80, generator=torch.Generator().manual_seed(0), dtype=dtype)
    params = [p.requires_grad_() for p in (means, quats, scales, opac, colors)]
    out = rasterize(*params, viewmat, K, width, height, block=8, tile_size=8, chunk_pairs=30)
    rgb, depth, alpha = reference_render(*params, viewmat, K, width, height)
    assert (1 - alpha).min() < 1e-3  # termination actually happens
    out1 = rasterize(*params, viewmat, K, width, height)  # single chunk
    torch.testing.assert_close(out1.rgb, out.rgb)
    torch.testing.assert_close(out.rgb, rgb, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.depth, depth, atol=1e-6, rtol=1e-6)
    wr, wd, wa = _loss_weights(height, width, 3, dtype)
    g1 = torch.autograd.grad((out.rgb * wr).sum() + (out.depth * wd).sum(), params)
    g2 = torch.autograd.grad((rgb * wr).sum() + (depth * wd).sum(), params)
    for a, b in zip(g1, g2):
        torch.testing.assert_close(a, b, atol=1e-7 * b.abs().max().item(), rtol=1e-6)


def test_clamped_alpha_opacity_one():
    # opacity 1 (alpha clamped at 0.99 near the centres): clamped pairs composite but
    # pass no gradient through alpha
    dtype = torch.float64
    width, height = 26, 22
    viewmat, K = make_camera(width, height, dtype=dtype)
    means, quats, scales, opac, colors = random_scene(30, 17, dtype=dtype, spread=0.6,
                                                     scale=(-1.8, 0.2))
    opac = torch.where(torch.arange(30) % 2 == 0, torch.ones_like(opac), opac)
    params = [p.requires_grad_() for p in (means, quats, scales, opac, colors)]
    for kw in [dict(), dict(tile_size=8, block=3, chunk_pairs=10)]:
        out = rasterize(*params, viewmat, K, width, height, **kw)
        rgb, depth, alpha = reference_render(*params, viewmat, K, width, height)
        torch.testing.assert_close(out.rgb, rgb, atol=1e-6, rtol=0)
        wr, wd, wa = _loss_weights(height, width, 5, dtype)
        loss = (out.rgb * wr).sum() + (out.depth * wd).sum() + (out.alpha * wa).sum()
        ref = (rgb * wr).sum() + (depth * wd).sum() + (alpha * wa).sum()
        for a, b in zip(torch.autograd.grad(loss, params), torch.autograd.grad(ref, params)):
            torch.testing.assert_close(a, b, atol=1e-7 * b.abs().max().item(), rtol=1e-6)


def test_gradcheck_tiny_scene():
    dtype = torch.float64
    width, height = 12, 10
    viewmat, K = make_camera(width, height, dtype=dtype, f=14.0)
    means = torch.tensor([[0.1, 0.0, 0.0], [-0.3, 0.2, 0.5], [0.4, -0.3, -0.4]], dtype=dtype)
    quats = torch.tensor([[1.0, 0.1, -0.2, 0.3], [0.5, 0.5, 0.1, -0.2], [0.9, -0.1, 0.3, 0.2]],
                         dtype=dtype)
    scales = torch.tensor([[0.5, 0.3, 0.4], [0.3, 0.6, 0.2], [0.4, 0.4, 0.5]], dtype=dtype)
    opac = torch.tensor([0.6, 0.5, 0.7], dtype=dtype)
    colors = torch.tensor([[0.9, 0.1, 0.2], [0.2, 0.8, 0.3], [0.1, 0.3, 0.9]], dtype=dtype)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=dtype)
    wd = _loss_weights(height, width, 0, dtype)

    def f(m, q, s, o, c):
        out = rasterize(m, q, s, o, c, viewmat, K, width, height, background=bg, tile_size=8)
        return (out.rgb * wd[0]).sum() + (out.depth * wd[1]).sum() + (out.alpha * wd[2]).sum()

    inputs = [t.clone().requires_grad_() for t in (means, quats, scales, opac, colors)]
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_culling_near_far_behind_offscreen():
    dtype = torch.float64
    width, height = 20, 16
    viewmat = torch.eye(4, dtype=dtype)
    K = intrinsics(20.0, 20.0, 10.0, 8.0).to(dtype)
    means = torch.tensor(
        [
            [0.0, 0.0, 3.0],  # visible
            [0.0, 0.0, -3.0],  # behind the camera
            [0.0, 0.0, 0.05],  # in front of the near plane
            [0.0, 0.0, 50.0],  # beyond the far plane
            [40.0, 0.0, 3.0],  # entirely off screen
            [0.1, 0.1, 4.0],  # visible
        ],
        dtype=dtype,
        requires_grad=True,
    )
    n = means.shape[0]
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=dtype).repeat(n, 1).requires_grad_()
    scales = torch.full((n, 3), 0.3, dtype=dtype, requires_grad=True)
    opac = torch.full((n,), 0.8, dtype=dtype, requires_grad=True)
    colors = torch.rand(n, 3, dtype=dtype, generator=torch.Generator().manual_seed(0))
    colors.requires_grad_()
    params = [means, quats, scales, opac, colors]
    out = rasterize(*params, viewmat, K, width, height, near_plane=0.1, far_plane=20.0)
    assert out.meta["visible"].tolist() == [True, False, False, False, False, True]
    radii = out.meta["radii"]
    assert radii.dtype in (torch.int32, torch.int64)
    assert (radii[[1, 2, 3, 4]] == 0).all() and (radii[[0, 5]] > 0).all()
    rgb, depth, alpha = reference_render(*params, viewmat, K, width, height, near_plane=0.1,
                                         far_plane=20.0)
    torch.testing.assert_close(out.rgb, rgb, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.depth, depth, atol=1e-6, rtol=0)
    loss = out.rgb.sum() + out.depth.sum()
    loss.backward()
    for p in params:
        assert torch.isfinite(p.grad).all()
    assert (means.grad[1:5] == 0).all() and means.grad[0].abs().sum() > 0
    torch.testing.assert_close(out.meta["depths"].detach(), means[:, 2].detach())


def test_zero_gaussians_returns_background():
    bg = torch.tensor([0.3, 0.6, 0.9])
    viewmat, K = make_camera(15, 11)
    e = torch.zeros(0, 3, requires_grad=True)
    out = rasterize(e, torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3),
                    viewmat, K, 15, 11, background=bg)
    assert isinstance(out, RenderOutput)
    assert out.rgb.shape == (11, 15, 3) and out.alpha.shape == (11, 15, 1)
    assert out.depth.shape == (11, 15, 1)
    torch.testing.assert_close(out.rgb, bg.expand(11, 15, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    assert out.meta["means2d"].shape == (0, 2) and out.meta["radii"].shape == (0,)
    out.rgb.sum().backward()  # graph stays connected, no error
    # without background: black
    out = rasterize(e, torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3),
                    viewmat, K, 15, 11, depth_mode="expected")
    assert (out.rgb == 0).all() and (out.depth == 0).all()


def test_huge_gaussian_covers_image_and_stays_finite():
    dtype = torch.float64
    width, height = 30, 22
    viewmat, K = make_camera(width, height, dtype=dtype)
    means = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.2, -3.0], [2.0, 1.0, -3.85]], dtype=dtype)
    quats = torch.tensor([[1.0, 0.2, 0.1, 0.0], [1.0, 0.0, 0.0, 0.3], [0.3, 0.1, 0.0, 1.0]],
                         dtype=dtype)
    scales = torch.tensor([[30.0, 25.0, 20.0], [3.0, 2.0, 1.0], [5.0, 0.01, 0.02]], dtype=dtype)
    opac = torch.tensor([0.9, 0.5, 0.8], dtype=dtype)
    colors = torch.tensor([[0.2, 0.4, 0.6], [0.9, 0.1, 0.1], [0.1, 0.9, 0.1]], dtype=dtype)
    params = [p.clone().requires_grad_() for p in (means, quats, scales, opac, colors)]
    out = rasterize(*params, viewmat, K, width, height)
    assert (out.alpha > 0.5).all()
    rgb, depth, alpha = reference_render(*params, viewmat, K, width, height)
    torch.testing.assert_close(out.rgb, rgb, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.alpha, alpha, atol=1e-6, rtol=0)
    (out.rgb.sum() + out.depth.mean()).backward()
    for p in params:
        assert torch.isfinite(p.grad).all()


def test_means2d_grad_is_screen_space_gradient():
    dtype = torch.float64
    width, height = 25, 19
    viewmat, K = make_camera(width, height, dtype=dtype)
    params = [p.requires_grad_() for p in random_scene(20, 4, dtype=dtype)]
    wr, wd, wa = _loss_weights(height, width, 9, dtype)
    out = rasterize(*params, viewmat, K, width, height)
    m2d = out.meta["means2d"]
    assert m2d.shape == (20, 2) and m2d.requires_grad
    ((out.rgb * wr).sum() + (out.depth * wd).sum()).backward()
    assert m2d.grad is not None
    rgb, depth, _, ref_m2d = reference_render(*[p.detach().requires_grad_() for p in params],
                                              viewmat, K, width, height, return_means2d=True)
    ((rgb * wr).sum() + (depth * wd).sum()).backward()
    torch.testing.assert_close(m2d.grad, ref_m2d.grad, atol=1e-8, rtol=1e-6)
    torch.testing.assert_close(m2d.detach(), ref_m2d.detach())
    vis = out.meta["visible"]
    assert (m2d.grad[~vis] == 0).all()
    # no retain_grad under no_grad
    with torch.no_grad():
        out = rasterize(*params, viewmat, K, width, height)
    assert not out.meta["means2d"].requires_grad


def _absgrad_reference(params, viewmat, K, width, height, wr, wd, wa):
    """[N, 2] sums over the pixels of each pixel's |d loss / d means2d|, from the brute-force reference
    (one backward per pixel)."""
    rgb, depth, alpha, m2d = reference_render(*params, viewmat, K, width, height, return_means2d=True)
    per_pixel = ((rgb * wr).sum(-1) + (depth * wd)[..., 0] + (alpha * wa)[..., 0]).reshape(-1)
    return sum(torch.autograd.grad(per_pixel[p], m2d, retain_graph=True)[0].abs() for p in range(per_pixel.numel()))


def check_absgrad(tile_size=8):
    """``rasterize(absgrad=True)`` leaves means2d.absgrad equal to the reference's per-pixel absolute sums;
    without it there is none. Float64, a scene where opposite pixel gradients do cancel."""
    dtype = torch.float64
    width, height = 25, 19
    viewmat, K = make_camera(width, height, dtype=dtype)
    params = [p.requires_grad_() for p in random_scene(20, 4, dtype=dtype)]
    wr, wd, wa = _loss_weights(height, width, 9, dtype)

    def loss(out):
        return (out.rgb * wr).sum() + (out.depth * wd).sum() + (out.alpha * wa).sum()

    out = rasterize(*params, viewmat, K, width, height, tile_size=tile_size)
    loss(out).backward()
    assert not hasattr(out.meta["means2d"], "absgrad")
    out = rasterize(*params, viewmat, K, width, height, tile_size=tile_size, absgrad=True)
    m2d = out.meta["means2d"]
    loss(out).backward()
    ref = _absgrad_reference([p.detach().requires_grad_() for p in params], viewmat, K, width, height, wr, wd, wa)
    assert ref.max() > 0.1, "nothing rendered: the test is vacuous"
    torch.testing.assert_close(m2d.absgrad, ref, atol=1e-8, rtol=1e-6)
    assert (m2d.absgrad >= m2d.grad.abs() - 1e-9).all()
    assert (m2d.absgrad > 1.5 * m2d.grad.abs() + 1e-6).any(), "no cancellation: absgrad would equal |grad|"


@pytest.mark.parametrize("tile_size", [8, 16])
def test_absgrad_matches_bruteforce(tile_size):
    check_absgrad(tile_size)


def test_expected_depth_mode():
    dtype = torch.float64
    width, height = 21, 17
    viewmat, K = make_camera(width, height, dtype=dtype)
    params = random_scene(25, 12, dtype=dtype)
    acc = rasterize(*params, viewmat, K, width, height)
    exp = rasterize(*params, viewmat, K, width, height, depth_mode="expected")
    a = acc.alpha
    ref = torch.where(a > 0, acc.depth / a.clamp_min(1e-30), torch.zeros_like(a))
    torch.testing.assert_close(exp.depth, ref)
    assert torch.isfinite(exp.depth).all()


def test_float32_outputs_and_meta_types():
    width, height = 23, 18
    viewmat, K = make_camera(width, height)
    params = random_scene(30, 2, dtype=torch.float32)
    out = rasterize(*params, viewmat, K, width, height)
    assert out.rgb.dtype == torch.float32 and out.rgb.shape == (height, width, 3)
    m = out.meta
    assert m["radii"].shape == (30,) and not m["radii"].is_floating_point()
    assert m["visible"].dtype == torch.bool and m["depths"].shape == (30,)
    assert m["width"] == width and m["height"] == height
    assert ((m["radii"] > 0) == m["visible"]).all()


def test_tile_and_block_settings_agree():
    width, height = 40, 30
    viewmat, K = make_camera(width, height, dtype=torch.float64)
    params = random_scene(80, 13, dtype=torch.float64)
    ref = rasterize(*params, viewmat, K, width, height)
    for ts, blk, cp in [(8, 16, None), (16, 1, 5), (32, 64, 1), (8, 3, 40)]:
        out = rasterize(*params, viewmat, K, width, height, tile_size=ts, block=blk,
                        chunk_pairs=cp)
        torch.testing.assert_close(out.rgb, ref.rgb)
        torch.testing.assert_close(out.depth, ref.depth)


def test_fused_kernel_variant_matches(monkeypatch):
    # the functional kernels that SPLAT_COMPILE=1 compiles, run uncompiled here
    from splat_framework.render import _composite, _kernels

    monkeypatch.setattr(
        _composite, "get_kernels",
        lambda: (_kernels.gathering_fwd(_kernels.fwd_round_fused), _kernels.gathering_bwd(_kernels.bwd_round_fused)),
    )
    _compare(50, 31, 30, 22, torch.float64, tile_size=8, block=5, chunk_pairs=40)
    test_clamped_alpha_opacity_one()


@pytest.mark.parametrize("tile", [8, 16])
def test_tile_pairs_cover_every_contributing_pixel(tile):
    # the opacity-aware, per-row-tightened footprint must list every (tile, Gaussian)
    # with at least one pixel where opacity * G >= 1/255
    from splat_framework.render._composite import TileGrid, _chunk_pairs, tile_footprints
    from splat_framework.render._project import footprint

    g = torch.Generator().manual_seed(tile)
    n, width, height = 300, 71, 53
    dtype = torch.float32
    means2d = torch.rand(n, 2, generator=g) * torch.tensor([width + 30.0, height + 30.0]) - 15
    ang = torch.rand(n, generator=g) * math.pi
    s1 = torch.exp(torch.randn(n, generator=g) * 0.8 + 1.0)
    s2 = s1 * torch.exp(-torch.rand(n, generator=g) * 2.5)  # up to ~12:1 anisotropy
    c, s = torch.cos(ang), torch.sin(ang)
    cxx = c * c * s1**2 + s * s * s2**2 + 0.3
    cyy = s * s * s1**2 + c * c * s2**2 + 0.3
    cxy = c * s * (s1**2 - s2**2)
    cov2d = torch.stack([cxx, cxy, cyy], 1)
    opac = torch.rand(n, generator=g)
    valid = torch.ones(n, dtype=torch.bool)
    ext_x, ext_y, ok, qmax = footprint(cov2d, opac, valid)
    grid = TileGrid(tile, (width + tile - 1) // tile, (height + tile - 1) // tile, width, height)
    fp = tile_footprints(means2d, ext_x, ext_y, ok, torch.rand(n, generator=g), cov2d, qmax, grid)
    gid, count, _ = _chunk_pairs(fp, torch.arange(fp.ids.numel()), grid,
                                 torch.zeros(grid.n_tiles, dtype=torch.bool))
    tiles = torch.repeat_interleave(torch.arange(grid.n_tiles), count)
    listed = torch.zeros(n, grid.n_tiles, dtype=torch.bool)
    listed[gid, tiles] = True

    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype),
                            indexing="ij")
    pix = torch.stack([xs, ys], -1).reshape(-1, 2) + 0.5
    det = cxx * cyy - cxy**2
    conic = torch.stack([cyy / det, -cxy / det, cxx / det], 1)
    d = pix[:, None, :] - means2d[None]
    q = conic[:, 0] * d[..., 0] ** 2 + 2 * conic[:, 1] * d[..., 0] * d[..., 1] + conic[:, 2] * d[..., 1] ** 2
    contributes = opac * torch.exp(-0.5 * q) >= 1.0 / 255.0  # [HW, N]
    pix_tile = ((pix[:, 1] // tile) * grid.ntx + pix[:, 0] // tile).long()
    need = torch.zeros(n, grid.n_tiles, dtype=torch.bool)
    pi, gi = torch.nonzero(contributes, as_tuple=True)
    need[gi, pix_tile[pi]] = True
    assert need.sum() > 500
    missing = need & ~listed
    assert not missing.any(), f"{int(missing.sum())} contributing (Gaussian, tile) pairs missing"
    # and the listing is reasonably tight
    assert listed.sum() < 1.6 * need.sum()
    # the whole first chunk binned with the footprints' sizes (no host read): the same lists, then
    # unused room up to the rectangles' area, counted in no tile
    room, count_w, offset_w = _chunk_pairs(fp, torch.arange(fp.ids.numel()), grid,
                                           torch.zeros(grid.n_tiles, dtype=torch.bool), whole=True)
    assert room.numel() == fp.area > gid.numel() and torch.equal(count_w, count)
    assert torch.equal(room[: gid.numel()], gid) and torch.equal(offset_w, torch.cumsum(count, 0) - count)


def test_all_culled_and_inference_mode():
    viewmat, K = make_camera(16, 12)
    means = torch.tensor([[0.0, 0.0, -10.0], [0.0, 0.0, -20.0]], requires_grad=True)
    args = (torch.tensor([[1.0, 0, 0, 0]] * 2), torch.full((2, 3), 0.1), torch.full((2,), 0.5),
            torch.rand(2, 3))
    viewmat = torch.eye(4)
    out = rasterize(means, *args, viewmat, K, 16, 12, background=torch.ones(3))
    assert (out.rgb == 1).all() and not out.meta["visible"].any()
    assert (out.meta["radii"] == 0).all()
    out.rgb.sum().backward()
    assert (means.grad == 0).all()
    with torch.inference_mode():
        out = rasterize(means.detach(), *args, viewmat, K, 16, 12)
    assert out.rgb.shape == (12, 16, 3)


@pytest.mark.slow  # compiles with torch.compile
def test_compiled_kernels_match_eager_in_a_training_step(monkeypatch, tmp_path):
    """torch.compile'd compositing (what training runs use on CUDA, and on a CPU where the native
    kernels cannot be built) gives the eager forward and gradients; any compile failure falls back
    to eager, so this also runs without a compiler."""
    from splat_framework.render import _kernels
    from splat_framework.render.precompiled import Precompiled, supported

    width, height = 40, 30
    viewmat, K = make_camera(width, height)
    params = [p.requires_grad_() for p in random_scene(120, 17, dtype=torch.float32)]

    def fwd_bwd(settings=None):
        for p in params:
            p.grad = None
        out = rasterize(*params, viewmat, K, width, height, settings=settings)
        (out.rgb.square().sum() + out.depth.sum() + out.alpha.sum()).backward()
        return [out.rgb.detach(), out.depth.detach()] + [p.grad.clone() for p in params]

    eager = fwd_bwd()
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    # one thread count throughout (the automatic one follows the machine's load, and each count has
    # its own compiled graph: see test_a_saved_kernel_graph_is_keyed_by_what_its_code_is_built_for)
    monkeypatch.setenv("SPLAT_THREADS", str(torch.get_num_threads()))
    # the torch.compile'd kernels, not the native ones
    compiled = RenderSettings(rasterizer="torch", compile=True, cache_dir=tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(2):  # the second call runs the cached kernels
            for a, b in zip(fwd_bwd(compiled), eager):
                torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
        saved = sorted(p.name.split("-")[0] for p in (tmp_path / "precompiled").glob("*.bin"))
        # a new process: the kernels come from the saved graphs, nothing is traced again
        monkeypatch.setattr(_kernels, "_KERNELS", {})
        monkeypatch.setattr(Precompiled, "_compile", lambda self, args: pytest.fail("traced again"))
        for a, b in zip(fwd_bwd(compiled), eager):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    fell_back = [str(w.message) for w in caught if "unavailable" in str(w.message) or "could not compile" in str(w.message)]
    if shutil.which("c++") or shutil.which("g++"):  # with a compiler, the compiled kernels really ran
        assert not fell_back, fell_back
        if supported():
            assert saved == ["bwd", "fwd"]


def test_a_saved_kernel_graph_is_keyed_by_what_its_code_is_built_for(tmp_path):
    """Inductor's CPU code is built for one thread count and the graph's guards check it (and grad
    mode): graphs for other counts are other files, so a run at 1 thread never replaces, nor is
    refused by, the graph of a run at 2."""
    from splat_framework.render.precompiled import Precompiled

    kernel = Precompiled("fwd", None, lambda args: (args[0].shape[1],), tmp_path, None)
    args = (torch.zeros(3, 8),)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = kernel.stem_for(args)
        torch.set_num_threads(2)
        two = kernel.stem_for(args)
    finally:
        torch.set_num_threads(threads)
    with torch.no_grad():
        no_grad = kernel.stem_for(args)
    assert len({one, two, no_grad}) == 3
    assert kernel.stem_for((torch.zeros(5, 8),)) == kernel.stem_for(args)  # a varying size: the same graph
    assert kernel.stem_for((torch.zeros(3, 4),)) != kernel.stem_for(args)  # a specialised size: another


def test_a_torch_that_cannot_save_compiled_graphs_compiles_each_process_without_a_warning(monkeypatch, tmp_path):
    """torch 2.11 (seen on a CUDA machine) has the load API but no ``aot_compile`` on a compiled
    function: the kernels are then plain ``torch.compile`` ones, shown as "compiling ... for this
    process", with no warning that saved kernels are unavailable (there were two per run)."""
    import warnings

    from splat_framework.render import _kernels
    from splat_framework.render.precompiled import Precompiled

    def plain(x):
        return x

    monkeypatch.setattr(_kernels.torch, "compile", lambda fn, **kw: plain)  # a compiled function without aot_compile
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kernel = _kernels._compiled("fwd", lambda x: x, lambda args: (), "forward", tmp_path)
    assert kernel is plain and not isinstance(kernel, Precompiled)
    monkeypatch.setattr(_kernels.torch, "compile", lambda fn, **kw: type("F", (), {"aot_compile": 1, "__call__": plain})())
    assert isinstance(_kernels._compiled("fwd", lambda x: x, lambda args: (), "forward", tmp_path), Precompiled)

"""The native projection and photometric loss (render/native/project.cpp, loss.cpp) against their
torch references: the same values and gradients (float64 and float32) for plain colours and every
SH degree, culled Gaussians included; float64 gradchecks; a whole render against the brute-force
reference; the same bits for any thread count; and nothing traced by torch.compile in a training
step, whatever the SH degree or the number of Gaussians."""

from __future__ import annotations

import math

import pytest
import test_rasterizer as ref
import torch

from splat_framework import losses
from splat_framework.render import RenderSettings, _project, rasterize
from splat_framework.render._project import ProjectFn, native_cfg, project_and_shade


@pytest.fixture
def native(native_module, monkeypatch):
    """Every render (projection and compositing) and photometric loss of the test runs on the native
    kernels, as in a training run on a CPU."""
    monkeypatch.setattr(_project, "native_projection",
                        lambda device, settings: native_module if device.type == "cpu" else None)
    monkeypatch.setattr("splat_framework.render.backend.native_for", lambda device, settings: native_module)
    monkeypatch.setattr("splat_framework.render.backend.choose", lambda device, settings: "native")
    monkeypatch.setattr(losses, "_native_loss", lambda pred, gt, settings: native_module)
    return native_module


NATIVE = RenderSettings(rasterizer="native", compile=True)
"""What a training run on a CPU renders and takes its loss with."""


def _camera(dtype):
    a = 0.2
    viewmat = torch.eye(4, dtype=dtype)
    viewmat[:3, :3] = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]], dtype=dtype)
    viewmat[:3, 3] = torch.tensor([0.1, -0.2, 3.0], dtype=dtype)
    K = torch.tensor([[50.0, 0, 21], [0, 55, 14], [0, 0, 1]], dtype=dtype)
    return viewmat, K


def _scene(n, seed, dtype, sh_k):
    """Gaussians around the camera's view, some behind the near plane or past the far one, some
    far off-screen (the Jacobian's clamp), one flat (zero scales: only the eps2d dilation)."""
    means, quats, scales, _, colors = ref.random_scene(n, seed, dtype=dtype, sh_k=sh_k, spread=2.5)
    # camera z of these (the camera turns 0.2 rad about y, 3 units back): -2.0, 0.02, 42.2 and 3.4,
    # i.e. behind the camera, before the near plane, past the far one, and valid but far to the side
    means[:4] = torch.tensor([[0.0, 0.0, -5.1], [0.0, 0.0, -3.04], [0.0, 0.0, 40.0], [8.0, 0.0, 2.0]], dtype=dtype)
    scales[4] = 0.0
    return means, quats, scales, colors


CASES = [(None, None), (16, 3), (16, 0), (16, 1), (9, 2), (4, None), (16, None)]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("sh_k,degree", CASES)
def test_native_projection_matches_torch(native, sh_k, degree, dtype):
    viewmat, K = _camera(dtype)
    cfg = (42, 28, 0.05, 30.0, 0.3, degree)
    inputs = _scene(300, 3, dtype, sh_k)
    leaves = [t.clone().requires_grad_() for t in inputs]
    want = project_and_shade(*leaves, viewmat, K, *cfg)
    got = native.project_forward(*inputs, viewmat, K, *native_cfg(inputs[3], cfg))
    assert torch.equal(got[4], want[4])
    assert 3 <= int((~got[4]).sum()) < 300  # culled ones are in the test, and most are not
    tol = {} if dtype == torch.float64 else dict(rtol=2e-5, atol=2e-5)
    for a, b in zip(got, want):
        if a.dtype != torch.bool:
            torch.testing.assert_close(a, b.detach(), **tol)
    g = torch.Generator().manual_seed(7)
    grads = [torch.randn(o.shape, generator=g, dtype=dtype) for o in want if o.dtype != torch.bool]
    outs = [o for o in want if o.dtype != torch.bool]
    expected = torch.autograd.grad(outs, leaves, grads, allow_unused=True)
    computed = native.project_backward(*inputs, viewmat, K, *native_cfg(inputs[3], cfg), *grads)
    for name, a, b in zip(("means", "quats", "scales", "colors"), computed, expected):
        b = torch.zeros_like(a) if b is None else b
        scale = b.abs().max().clamp_min(1e-6)
        assert ((a - b).abs().max() / scale) < (1e-10 if dtype == torch.float64 else 1e-4), name


@pytest.mark.parametrize("sh_k,degree", [(None, None), (16, 3), (9, 1)])
def test_native_projection_gradcheck(native, sh_k, degree):
    viewmat, K = _camera(torch.float64)
    means, quats, scales, colors = (t.requires_grad_() for t in _scene(12, 5, torch.float64, sh_k))
    cfg = (42, 28, 0.05, 30.0, 0.3, degree)

    def f(m, q, s, c):
        out = ProjectFn.apply(m, q, s, c, viewmat, K, cfg, NATIVE)
        return tuple(o for o in out if o.dtype != torch.bool)

    assert torch.autograd.gradcheck(f, (means, quats, scales, colors), eps=1e-6, atol=1e-6)


@pytest.mark.parametrize("sh_k,degree", [(None, None), (16, 2)])
def test_a_render_with_the_native_projection_matches_bruteforce(native, sh_k, degree):
    # the whole rasterizer with the native projection; the pose is a constant
    width, height, dtype = 37, 29, torch.float64
    viewmat, K = ref.make_camera(width, height, dtype=dtype)
    params = [p.requires_grad_() for p in ref.random_scene(40, 11, dtype=dtype, sh_k=sh_k)]
    wr = torch.randn(height, width, 3, generator=torch.Generator().manual_seed(1), dtype=dtype)
    out = rasterize(*params, viewmat, K, width, height, sh_degree=degree, settings=NATIVE)
    grads = torch.autograd.grad((out.rgb * wr).sum() + out.depth.sum(), params)
    rgb, depth, alpha = ref.reference_render(*params, viewmat, K, width, height, sh_degree=degree)
    assert alpha.max() > 0.5
    torch.testing.assert_close(out.rgb, rgb, atol=1e-4, rtol=0)
    ref_grads = torch.autograd.grad((rgb * wr).sum() + depth.sum(), params)
    for a, b in zip(grads, ref_grads):
        assert (a - b).abs().max() / b.abs().max().clamp_min(1e-3) < 1e-6


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_native_photometric_loss_matches_torch(native, dtype):
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(37, 45, 3, generator=g, dtype=dtype, requires_grad=True)
    gt = torch.rand(37, 45, 3, generator=g, dtype=dtype)
    gt[:5, :5] = pred.detach()[:5, :5]  # equal pixels: the L1's zero subgradient
    want = losses._photometric(pred, gt, 0.2)
    (want_grad,) = torch.autograd.grad(want, pred)
    got = losses.photometric_loss(pred, gt, 0.2, settings=NATIVE)
    assert got.grad_fn is not None and "Native" in type(got.grad_fn).__name__
    (grad,) = torch.autograd.grad(got * 3.0, pred)
    tol = {} if dtype == torch.float64 else dict(rtol=1e-5, atol=1e-8)
    torch.testing.assert_close(got, want.detach(), **tol)
    torch.testing.assert_close(grad, 3.0 * want_grad, **tol)


def test_native_photometric_loss_gradcheck(native):
    g = torch.Generator().manual_seed(1)
    pred = torch.rand(13, 17, 3, generator=g, dtype=torch.float64, requires_grad=True)
    gt = torch.rand(13, 17, 3, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: losses.photometric_loss(p, gt, 0.3, settings=NATIVE), (pred,))


def test_native_projection_and_loss_give_the_same_bits_on_one_thread_and_two(native):
    # no sum crosses Gaussians, and the loss adds its rows in order: a run's numbers do not depend
    # on how many threads the load left it
    viewmat, K = _camera(torch.float32)
    inputs = _scene(5000, 2, torch.float32, 16)
    pred = torch.rand(120, 160, 3, generator=torch.Generator().manual_seed(3))
    gt = torch.rand(120, 160, 3, generator=torch.Generator().manual_seed(4))
    cfg = native_cfg(inputs[3], (160, 120, 0.05, 30.0, 0.3, 3))
    before, results = torch.get_num_threads(), []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            fwd = native.project_forward(*inputs, viewmat, K, *cfg)
            grads = [torch.ones_like(o) for o in fwd if o.dtype != torch.bool]
            bwd = native.project_backward(*inputs, viewmat, K, *cfg, *grads)
            loss, stats = native.photometric_forward(pred, gt, losses._gaussian_1d(11, 1.5, pred), 0.2)
            dl = native.photometric_backward(pred, gt, losses._gaussian_1d(11, 1.5, pred), 0.2, stats, torch.ones(()))
            results.append([*fwd, *bwd, loss, dl])
    finally:
        torch.set_num_threads(before)
    for a, b in zip(*results):
        assert torch.equal(a, b)


def test_a_training_step_traces_nothing_whatever_the_sh_degree_or_size(native, monkeypatch):
    # 3DGS raises its SH degree mid-run and densification changes the count: nothing may be
    # compiled for either (a trace costs tens of seconds on 2 cores, once per process and thread count)
    from torch._dynamo.utils import counters

    frames_before = sum(counters["frames"].values())
    width, height = 24, 18
    viewmat, K = ref.make_camera(width, height)
    gt = torch.rand(height, width, 3)
    for n, degree in ((30, 0), (45, 1), (60, 3)):
        means, quats, scales, opacities, colors = (p.requires_grad_() for p in ref.random_scene(n, n, torch.float32, 16))
        out = rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree=degree,
                        settings=NATIVE)
        losses.photometric_loss(out.rgb, gt, settings=NATIVE).backward()
        assert means.grad.abs().sum() > 0
    assert sum(counters["frames"].values()) == frames_before

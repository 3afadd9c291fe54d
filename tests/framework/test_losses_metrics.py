"""Losses (L1, 3DGS SSIM, photometric) and metrics (PSNR, SSIM, LPIPS with VGG and AlexNet, AVG)."""

from __future__ import annotations

import math

import pytest
import torch

from splat_framework.evaluation import metrics
from splat_framework.evaluation.metrics import LPIPSMetric, avg_metric, evaluate_images, psnr, ssim_metric
from splat_framework.losses import l1_loss, photometric_loss, ssim, ssim_map


def naive_ssim(x: torch.Tensor, y: torch.Tensor, window: int = 11, sigma: float = 1.5) -> float:
    """Direct loops, zero padding outside the image (3DGS reference semantics)."""
    h, w, c = x.shape
    r = window // 2
    g = [math.exp(-((i - r) ** 2) / (2 * sigma**2)) for i in range(window)]
    s = sum(g)
    g = [v / s for v in g]
    x, y = x.double().tolist(), y.double().tolist()
    total = 0.0
    for ch in range(c):
        for i in range(h):
            for j in range(w):
                m1 = m2 = e11 = e22 = e12 = 0.0
                for di in range(-r, r + 1):
                    for dj in range(-r, r + 1):
                        ii, jj = i + di, j + dj
                        if 0 <= ii < h and 0 <= jj < w:
                            wt = g[di + r] * g[dj + r]
                            a, b = x[ii][jj][ch], y[ii][jj][ch]
                            m1 += wt * a
                            m2 += wt * b
                            e11 += wt * a * a
                            e22 += wt * b * b
                            e12 += wt * a * b
                s1, s2, s12 = e11 - m1 * m1, e22 - m2 * m2, e12 - m1 * m2
                c1, c2 = 0.01**2, 0.03**2
                total += ((2 * m1 * m2 + c1) * (2 * s12 + c2)) / ((m1 * m1 + m2 * m2 + c1) * (s1 + s2 + c2))
    return total / (h * w * c)


def images(seed=0, h=16, w=20, noise=0.1):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, 3, generator=g)
    b = (a + noise * torch.randn(h, w, 3, generator=g)).clamp(0, 1)
    return a, b


# ------------------------------------------------------------------ losses
def test_l1_and_mask():
    a = torch.zeros(4, 4, 3)
    b = torch.zeros(4, 4, 3)
    b[:2] = 1.0
    assert l1_loss(a, b).item() == pytest.approx(0.5)
    mask = torch.zeros(4, 4, 1, dtype=torch.bool)
    mask[2:] = True
    assert l1_loss(a, b, mask).item() == 0.0
    assert l1_loss(a, b, ~mask[..., 0]).item() == pytest.approx(1.0)


def test_ssim_identical_and_noise_monotone():
    a, _ = images()
    assert ssim(a, a).item() == pytest.approx(1.0, abs=1e-6)
    vals = [ssim(a, images(noise=n)[1]).item() for n in (0.02, 0.1, 0.3)]
    assert vals[0] > vals[1] > vals[2]


def test_ssim_matches_naive():
    a, b = images(h=9, w=13, noise=0.2)
    assert ssim(a.double(), b.double()).item() == pytest.approx(naive_ssim(a, b), abs=1e-9)
    assert ssim(a, b).item() == pytest.approx(naive_ssim(a, b), abs=1e-5)


def test_ssim_batched_and_grad():
    a, b = images()
    a2, b2 = images(seed=1)
    batch = ssim(torch.stack([a, a2]), torch.stack([b, b2]))
    assert batch.item() == pytest.approx((ssim(a, b).item() + ssim(a2, b2).item()) / 2, abs=1e-6)
    assert ssim_map(a, b).shape == (1, 16, 20, 3)
    p = a.clone().requires_grad_(True)
    photometric_loss(p, b).backward()
    assert p.grad is not None and torch.isfinite(p.grad).all()


def test_photometric_loss_formula():
    a, b = images()
    lam = 0.2
    expect = (1 - lam) * (a - b).abs().mean() + lam * (1 - ssim(a, b))
    assert photometric_loss(a, b, lam).item() == pytest.approx(expect.item(), rel=1e-6)
    assert photometric_loss(a, a).item() == pytest.approx(0.0, abs=1e-6)
    mask = torch.ones(16, 20, 1)
    assert photometric_loss(a, b, lam, mask).item() == pytest.approx(expect.item(), rel=1e-5)


# ------------------------------------------------------------------ metrics
def test_psnr_identical_is_inf_and_known_mse():
    a, _ = images()
    assert psnr(a, a) == math.inf
    b = (a + 0.1).clamp(max=10)  # MSE exactly 0.01
    assert psnr(a, b) == pytest.approx(20.0, abs=1e-4)


def test_masked_psnr_ignores_background():
    a = torch.full((8, 8, 3), 0.5)
    b = a.clone()
    b[:, 4:] = 0.0  # background differs wildly
    b[:, :4] += 0.1  # foreground MSE 0.01
    mask = torch.zeros(8, 8, 1, dtype=torch.bool)
    mask[:, :4] = True
    assert psnr(a, b, mask) == pytest.approx(20.0, abs=1e-4)
    assert psnr(a, b) < 20.0
    with pytest.raises(ValueError):
        psnr(a, b, torch.zeros(8, 8, 1))


def test_dtu_protocol_on_a_hand_made_pair():
    """DNGaussian / SCGaussian DTU metrics: PSNR over mask == 1 only, soft edge left out; SSIM on white composites."""
    gt = torch.full((6, 8, 3), 0.5)
    pred = gt.clone()
    mask = torch.zeros(6, 8, 1)
    mask[:, :3] = 1.0  # 18 object pixels, error 0.1 each -> MSE 0.01 -> 20 dB
    mask[:, 3] = 0.5  # soft edge: a huge error there must not count
    pred[:, :3] += 0.1
    pred[:, 3:] = 1.0
    assert psnr(pred, gt, mask) == pytest.approx(20.0, abs=1e-5)
    # by hand: composite x * m + (1 - m) on the edge column gives 1.0 vs 0.75
    p_w, g_w = pred * mask + (1 - mask), gt * mask + (1 - mask)
    assert float(g_w[0, 3, 0]) == pytest.approx(0.75) and float(p_w[0, 3, 0]) == pytest.approx(1.0)
    assert ssim_metric(pred, gt, mask) == pytest.approx(ssim_metric(p_w, g_w), abs=1e-7)


def test_load_mask_keeps_soft_edges(tmp_path):
    import cv2
    import numpy as np

    from splat_framework.data.images import load_mask

    m = np.zeros((4, 4), np.uint8)
    m[:, :2] = 255
    m[:, 2] = 128
    cv2.imwrite(str(tmp_path / "m.png"), m)
    out = load_mask(tmp_path / "m.png", (4, 4))
    assert out.dtype == np.float32 and out.shape == (4, 4)
    assert (out[:, :2] == 1.0).all() and (out[:, 3] == 0.0).all()
    assert np.allclose(out[:, 2], 128 / 255, atol=1e-6)


def test_masked_ssim_composites_white():
    a, b = images()
    mask = torch.zeros(16, 20, 1)
    mask[4:12, 5:15] = 1
    b2 = b.clone()
    b2[mask[..., 0] == 0] = torch.rand(int((mask == 0).sum()), 3)  # background noise ignored
    assert ssim_metric(a, b, mask) == pytest.approx(ssim_metric(a, b2, mask), abs=1e-7)
    assert ssim_metric(a, a, mask) == pytest.approx(1.0, abs=1e-6)
    assert ssim_metric(a, b) == pytest.approx(ssim(a, b).item(), abs=1e-7)


def test_avg_metric_formula():
    # psnr 20 -> mse 0.01; ssim 0.96 -> sqrt(0.04) = 0.2; lpips 0.5 -> geometric mean (0.001)^(1/3) = 0.1
    assert avg_metric(20.0, 0.96, 0.5) == pytest.approx(0.1)
    assert avg_metric(20.0, 0.96, None) is None
    assert avg_metric(math.inf, 1.0, 0.0) == 0.0


def _real_lpips() -> str | None:
    """Why the real ``lpips`` package cannot run here (None when it can): not installed, or
    torchvision built for another torch (a CUDA wheel beside a CPU torch fails to import)."""
    try:
        import lpips  # noqa: F401
    except ModuleNotFoundError as e:
        return f"the lpips extra is not installed (pip install -e '.[lpips]'): {e}"
    except Exception as e:  # noqa: BLE001
        return f"the lpips extra cannot be imported here ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})"
    return None


def _fake_lpips_install(monkeypatch, tmp_path):
    """``lpips`` and ``torchvision`` installed as far as the availability check sees (find_spec, the
    linear weights, the import), and an empty torch hub cache under ``tmp_path / "hub"``."""
    import sys
    import types

    real = metrics.importlib.util.find_spec
    pkg = tmp_path / "lpips"
    (pkg / "weights" / "v0.1").mkdir(parents=True)
    for net in metrics.BACKBONE_FILES:
        (pkg / "weights" / "v0.1" / f"{net}.pth").write_bytes(b"")

    class Spec:
        origin = str(pkg / "__init__.py")

    monkeypatch.setattr(
        metrics.importlib.util, "find_spec", lambda n: Spec() if n in ("lpips", "torchvision") else real(n)
    )
    monkeypatch.setitem(sys.modules, "lpips", types.ModuleType("lpips"))  # imports as installed, runs nothing
    monkeypatch.setattr(metrics.torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    return tmp_path / "hub" / "checkpoints"


def test_lpips_availability_reported():
    for net in metrics.BACKBONE_FILES:
        ok, why = LPIPSMetric.available(net)
        if ok:
            a, b = images(h=64, w=64)
            m = LPIPSMetric(net)
            assert m.compute(a, a) == pytest.approx(0.0, abs=1e-4)
            assert m.compute(a, b) > m.compute(a, a)
        else:
            assert why and "\n" not in why
            with pytest.raises(RuntimeError, match="LPIPS unavailable"):
                LPIPSMetric(net).compute(*images())
    out = evaluate_images(*images(), lpips={})
    assert out["lpips"] is None and out["lpips_alex"] is None and out["avg"] is None


def test_lpips_unavailable_without_backbone_says_which_file_where(monkeypatch, tmp_path):
    """Even with both packages installed, a missing backbone file means unavailable (no download); the
    one line names the file and the folder it was looked for in, for each backbone."""
    checkpoints = _fake_lpips_install(monkeypatch, tmp_path)
    usable, note = metrics.lpips_metrics()
    assert usable == {} and note == (f"torchvision's VGG16 and AlexNet weights not found in {checkpoints} "
                                     "(vgg16-397923af.pth, alexnet-owt-7be5be79.pth; no download is attempted)")
    checkpoints.mkdir(parents=True)
    (checkpoints / metrics.BACKBONE_FILES["vgg"][1]).write_bytes(b"")
    usable, note = metrics.lpips_metrics()
    assert set(usable) == {"lpips"} and usable["lpips"].net_name == "vgg"
    assert note == f"torchvision's AlexNet weights not found in {checkpoints} (alexnet-owt-7be5be79.pth; no download is attempted)"
    (checkpoints / metrics.BACKBONE_FILES["alex"][1]).write_bytes(b"")
    assert metrics.lpips_metrics()[1] is None and LPIPSMetric.available("alex") == (True, "")


def test_lpips_missing_package_is_one_line_for_both_backbones(monkeypatch):
    real = metrics.importlib.util.find_spec
    monkeypatch.setattr(metrics.importlib.util, "find_spec", lambda n: None if n == "lpips" else real(n))
    usable, note = metrics.lpips_metrics()
    assert usable == {} and note == "package 'lpips' is not installed (the project's extra 'lpips' installs it)"


def test_lpips_computed_with_locally_made_backbone_weights(monkeypatch, tmp_path):
    """The real lpips package with torchvision backbones whose weights were made here (random, saved
    where torchvision looks for its ImageNet weights): both LPIPS metrics and AVG are computed, and
    nothing is downloaded. Proves the plumbing where the real weights cannot be had."""
    why = _real_lpips()
    if why:
        pytest.skip(why)
    import torchvision

    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    checkpoints = tmp_path / "hub" / "checkpoints"
    checkpoints.mkdir(parents=True)
    torch.manual_seed(0)
    torch.save(torchvision.models.vgg16().state_dict(), checkpoints / metrics.BACKBONE_FILES["vgg"][1])
    torch.save(torchvision.models.alexnet().state_dict(), checkpoints / metrics.BACKBONE_FILES["alex"][1])
    usable, note = metrics.lpips_metrics()
    assert set(usable) == set(metrics.LPIPS_NETS) and note is None
    a, b = images(h=64, w=64)
    for m in usable.values():
        assert m.compute(a, a) == pytest.approx(0.0, abs=1e-5)
        assert m.compute(a, b) > 1e-4
    out = evaluate_images(a, b, lpips=usable)
    assert out["lpips"] > 0 and out["lpips_alex"] > 0 and out["lpips"] != out["lpips_alex"]
    assert out["avg"] == pytest.approx(avg_metric(out["psnr"], out["ssim"], out["lpips"]))


def test_lpips_with_the_real_weights():
    """Both LPIPS metrics with torchvision's ImageNet weights, where this machine has them (the extra
    installed and the weights in the torch hub cache; nothing is downloaded)."""
    why = _real_lpips()
    if why:
        pytest.skip(why)
    usable, note = metrics.lpips_metrics()
    if note:
        pytest.skip(f"LPIPS weights not on this machine: {note}")
    a, b = images(h=64, w=64)
    for m in usable.values():
        assert m.compute(a, a) == pytest.approx(0.0, abs=1e-5)
        assert 0.0 < m.compute(a, b) < 1.0


def test_evaluate_images_keys():
    a, b = images()
    out = evaluate_images(a, b)
    assert set(out) == {"psnr", "ssim", "lpips", "lpips_alex", "avg", "st_lpips"} == set(metrics.IMAGE_METRICS)
    assert out["lpips"] is None and out["lpips_alex"] is None and out["avg"] is None and out["st_lpips"] is None
    assert out["psnr"] == pytest.approx(psnr(a, b)) and out["ssim"] == pytest.approx(ssim_metric(a, b))


def test_depth_smoothness_known_values_and_edges():
    """A constant depth costs 0; a one-pixel step in depth costs |step| / mean depth per crossing
    pair, divided by the covered pairs; a colour edge at the same place discounts it by
    exp(-gamma * colour step); uncovered pixels (alpha <= 0.5) take no part."""
    from splat_framework.losses import depth_smoothness

    h, w = 4, 5
    alpha = torch.ones(h, w, 1)
    image = torch.full((h, w, 3), 0.5)
    flat = torch.full((h, w, 1), 2.0)
    assert float(depth_smoothness(flat, image, alpha)) == 0.0
    step = flat.clone()
    step[:, 3:] = 3.0  # one vertical edge: h crossing pairs along the rows
    mean = float(step.mean())
    pairs = h * (w - 1) + (h - 1) * w
    expected = h * 1.0 / mean / pairs
    assert float(depth_smoothness(step, image, alpha, gamma=10.0)) == pytest.approx(expected, rel=1e-6)
    edged = image.clone()
    edged[:, 3:] = 0.9  # the photo has an edge where the depth jumps
    assert float(depth_smoothness(step, edged, alpha, gamma=10.0)) == pytest.approx(expected * math.exp(-4.0), rel=1e-5)
    # scale invariance: the same scene twice as far costs the same
    assert float(depth_smoothness(3.0 * step, image, alpha)) == pytest.approx(expected, rel=1e-6)
    # the step lies in empty space: no covered pair crosses it
    hollow = alpha.clone()
    hollow[:, 3] = 0.0
    assert float(depth_smoothness(step, image, hollow)) == 0.0
    assert float(depth_smoothness(step, image, torch.zeros(h, w, 1))) == 0.0


def test_depth_smoothness_gradient_flattens_depth():
    """Descending its gradient flattens the depth (Adam, 50 steps: less than half the starting
    value). No finite-difference check: the mean depth it divides by is detached on purpose."""
    from splat_framework.losses import depth_smoothness

    g = torch.Generator().manual_seed(0)
    depth = (1.0 + torch.rand(6, 7, 1, generator=g, dtype=torch.float64)).requires_grad_(True)
    image = torch.rand(6, 7, 3, generator=g, dtype=torch.float64)
    alpha = torch.ones(6, 7, 1, dtype=torch.float64)
    first = float(depth_smoothness(depth, image, alpha))
    opt = torch.optim.Adam([depth], lr=0.05)
    for _ in range(50):
        opt.zero_grad()
        depth_smoothness(depth, image, alpha).backward()
        opt.step()
    assert float(depth_smoothness(depth, image, alpha).detach()) < 0.5 * first


def test_scale_anisotropy_known_values_and_gradient():
    """A Gaussian within the ratio costs 0; one with scales (1, 1, 20) and ratio 10 costs 10, and
    the mean is over all rows; the gradient shrinks the largest scale and grows the smallest,
    never touching the middle one; an empty model costs 0 with a graph."""
    from splat_framework.losses import scale_anisotropy

    log_scales = torch.log(torch.tensor([[1.0, 2.0, 5.0], [1.0, 1.0, 20.0]], dtype=torch.float64)).requires_grad_(True)
    loss = scale_anisotropy(log_scales, 10.0)
    assert float(loss) == pytest.approx(10.0 / 2, rel=1e-9)
    loss.backward()
    g = log_scales.grad
    assert torch.all(g[0] == 0)
    assert g[1, 2] > 0 and g[1, 0] + g[1, 1] < 0 and float(g[1, 2]) == pytest.approx(20.0 / 2, rel=1e-9)
    empty = torch.zeros(0, 3, requires_grad=True)
    out = scale_anisotropy(empty, 10.0)
    assert float(out) == 0.0 and out.requires_grad


def test_where_the_native_loss_cannot_run_the_loss_is_eager_and_nothing_is_traced(monkeypatch):
    """While kernels are compiled (training runs) and the native loss cannot run (CUDA, no
    toolchain), the loss runs eagerly: compiling it would cost a minute in every process to save
    about a millisecond a step (an H200's numbers, docs/rasterizer.md#on-cuda). (The native loss
    has its own tests: render/test_projection.py.)"""
    from torch._dynamo.utils import counters

    from splat_framework import losses
    from splat_framework.render import RenderSettings

    a, b = images()

    def loss_and_grad(settings=None):
        pred = a.clone().requires_grad_()
        loss = photometric_loss(pred, b, 0.2, settings=settings)
        loss.backward()
        return loss.detach(), pred.grad

    eager = loss_and_grad()
    calls = []
    monkeypatch.setattr(losses, "_native_loss", lambda pred, gt, settings: calls.append(settings))
    frames = counters["stats"]["unique_graphs"]
    for got, want in zip(loss_and_grad(RenderSettings(compile=True)), eager):
        assert torch.equal(got, want)
    assert calls == [RenderSettings(compile=True)]  # the native loss was asked for
    assert counters["stats"]["unique_graphs"] == frames

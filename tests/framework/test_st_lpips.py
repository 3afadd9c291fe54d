"""ST-LPIPS from the stlpips-pytorch wheel's weights, in an architecture of this project (no torchvision)."""

import sys

import pytest
import torch

from splat_framework.evaluation.metrics import IMAGE_METRICS, STLPIPSMetric, evaluate_images
from splat_framework.evaluation.st_lpips import STLPIPS, weights_path

needs_weights = pytest.mark.skipif(weights_path("alex") is None, reason="stlpips-pytorch is not installed")


def pair(h=64, w=80):
    """[1, 3, H, W] smooth image a; b: a with a bright square; c: a shifted by one pixel."""
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None]
    a = torch.stack([0.5 + 0.4 * torch.sin(x / 5 + y / 9), 0.5 + 0.4 * torch.cos(x / 7 - y / 4), (x + y) / (h + w)])
    b = a.clone()
    b[:, 20:40, 30:50] = 0.9
    c = torch.roll(a, 1, dims=2)
    return a[None].float(), b[None].float(), c[None].float()


#: d(a, b), d(a, c) by the package's own implementation (stlpips_pytorch.stlpips.LPIPS(net=NET,
#: variant="shift_tolerant")(x, y, normalize=True), version 0.0.2, torchvision present), on pair().
REFERENCE = {"alex": (0.09885545819997787, 0.007503826171159744), "vgg": (0.12611304223537445, 0.028685113415122032)}


@needs_weights
@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_matches_the_reference_implementation(net):
    a, b, c = pair()
    m = STLPIPS(net)
    with torch.no_grad():
        d_ab, d_ac, d_aa = float(m(a, b)), float(m(a, c)), float(m(a, a))
    assert (d_ab, d_ac) == pytest.approx(REFERENCE[net], rel=1e-5)
    assert d_aa == 0.0 and d_ac < d_ab / 3  # a one-pixel shift costs little: the point of ST-LPIPS


@needs_weights
def test_metric_never_imports_the_package_and_masks_like_ssim():
    a, b, _ = pair()
    hwc_a, hwc_b = a[0].permute(1, 2, 0), b[0].permute(1, 2, 0)
    metric = STLPIPSMetric()
    assert metric.compute(hwc_a, hwc_b) == pytest.approx(REFERENCE["alex"][0], rel=1e-5)
    mask = torch.ones(64, 80)
    mask[20:40, 30:50] = 0  # the changed square lies outside the object: on white in both images
    assert metric.compute(hwc_a, hwc_b, mask) < 1e-6
    out = evaluate_images(hwc_a, hwc_b, st_lpips=metric)
    assert tuple(out) == IMAGE_METRICS and out["lpips"] is None and out["st_lpips"] > 0
    assert "stlpips_pytorch" not in sys.modules  # its modules import torchvision and IPython


def test_missing_weights_say_which_package(tmp_path, monkeypatch):
    import splat_framework.evaluation.st_lpips as st

    monkeypatch.setattr(st.importlib.util, "find_spec", lambda name: None)
    assert st.weights_path("alex") is None
    assert STLPIPSMetric.available() == (False, "package 'stlpips-pytorch' is not installed")
    with pytest.raises(FileNotFoundError, match=r"^ST-LPIPS weights not found \(pip install stlpips-pytorch\)$"):
        STLPIPS("alex")


def test_sweep_tables_carry_every_image_metric():
    from splat_framework.sweep.grid import METRICS
    from splat_framework.sweep.results import COLUMNS

    assert METRICS[: len(IMAGE_METRICS)] == IMAGE_METRICS  # then the score before a test-pose fit, when one ran
    assert METRICS[len(IMAGE_METRICS):] == ("psnr_before_pose_fit",)
    assert ("ST-LPIPS ↓", "st_lpips", ".3f") in COLUMNS

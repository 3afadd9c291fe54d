"""Evaluation metrics: PSNR, SSIM, LPIPS (VGG and AlexNet), ST-LPIPS (AlexNet) and the RegNeRF AVG score.

Images are [H, W, 3] (or [B, H, W, 3]) in [0, 1]; masks [H, W] / [H, W, 1],
bool or float in [0, 1] (DTU protocol: 1 = object, fractions on the object's edge).

The masked (DTU) protocol is that of DNGaussian's ``metrics_dtu.py`` and
SCGaussian's ``metrics.py`` (github.com/Fictionarry/DNGaussian,
github.com/prstrive/SCGaussian), which both follow RegNeRF: PSNR is the MSE
over the object pixels only (mask exactly 1, so soft edge pixels are left
out); SSIM and LPIPS see the full image with both prediction and ground truth
composited onto white with the (soft) mask, ``x * m + (1 - m)``.

PSNR of identical images is ``math.inf`` (MSE 0), not a clipped constant, so
it never silently enters a table as a plausible number; ``avg_metric`` turns
it into an MSE of 0 (AVG 0).

LPIPS is reported with both backbones papers use (:data:`LPIPS_NETS`): ``lpips`` with VGG (the
LLFF papers', SCGaussian's and RegNeRF's; AVG uses it) and ``lpips_alex`` with AlexNet. It never
downloads anything: ``LPIPSMetric.available(net)`` checks that the ``lpips`` and ``torchvision``
packages are installed (the project's extra ``lpips``) and that both weight files (lpips' linear
layers, shipped inside the package, and torchvision's ImageNet backbone in the torch hub cache,
:data:`BACKBONE_FILES`) exist on disk, then that the packages import, before anything is built.
ST-LPIPS (``splat_framework.evaluation.st_lpips``, weights from the ``stlpips-pytorch`` wheel, a
dependency) is reported beside them whenever its weights are installed, under its own name: its
values are not comparable with LPIPS values in papers.
"""

from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path
from typing import Any, Mapping

import torch
from torch import Tensor

from splat_framework.losses import mask_bhw1, ssim

LPIPS_NETS = {"lpips": "vgg", "lpips_alex": "alex"}
"""The LPIPS metrics reported: metric key -> lpips' backbone (``lpips.LPIPS(net=...)``)."""
BACKBONE_FILES = {"vgg": ("VGG16", "vgg16-397923af.pth"), "alex": ("AlexNet", "alexnet-owt-7be5be79.pth")}
"""Each backbone's name and the file of its torchvision ImageNet weights (``VGG16_Weights`` /
``AlexNet_Weights.IMAGENET1K_V1``), looked for in ``<torch hub dir>/checkpoints``."""
IMAGE_METRICS = ("psnr", "ssim", *LPIPS_NETS, "avg", "st_lpips")
"""The image-quality keys of :func:`evaluate_images`, in table order."""


def _composite_white(pred: Tensor, gt: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    m = mask_bhw1(mask, pred)
    if pred.dim() == 3:
        m = m[0]
    return pred * m + (1 - m), gt * m + (1 - m)


@torch.no_grad()
def psnr_tensor(pred: Tensor, gt: Tensor) -> Tensor:
    """0-dim float64 PSNR in dB of images in [0, 1], on their device, inf when MSE is 0: no host read
    (a training step's log, read when shown)."""
    return -10.0 * torch.log10(((pred.double() - gt.double()) ** 2).mean())


@torch.no_grad()
def psnr(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
    """PSNR in dB for images in [0, 1]; with ``mask``, MSE over the pixels where mask == 1 only. inf when MSE is 0."""
    if mask is None:
        return float(psnr_tensor(pred, gt))
    pred, gt = pred.double(), gt.double()
    m = (mask_bhw1(mask, pred) >= 1.0).to(pred.dtype)  # object pixels, as the reference's `mask == 1.`
    se = ((pred - gt) ** 2).reshape(m.shape[0], *pred.shape[-3:]) * m
    denom = m.sum() * pred.shape[-1]
    if denom <= 0:
        raise ValueError("psnr: mask selects no pixels")
    mse = float(se.sum() / denom)
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


@torch.no_grad()
def ssim_metric(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
    """SSIM as in training; with ``mask``, both images get a white background first."""
    if mask is not None:
        pred, gt = _composite_white(pred, gt, mask)
    return float(ssim(pred.float(), gt.float()))


class LPIPSMetric:
    """LPIPS with one backbone (``net``: "vgg", the 3DGS/RegNeRF evaluation choice, or "alex"), if available offline."""

    def __init__(self, net: str = "vgg", device: torch.device | str | None = None) -> None:
        self.net_name = net
        self.device = device
        self._net: Any = None

    @staticmethod
    def available(net: str = "vgg") -> tuple[bool, str]:
        """(True, "") when LPIPS with backbone ``net`` can be built without any download, else
        (False, one line saying why: the package missing, or the weight file and where it was looked for)."""
        if net not in BACKBONE_FILES:
            return False, f"unknown LPIPS backbone {net!r} (one of {', '.join(BACKBONE_FILES)})"
        for pkg in ("lpips", "torchvision"):
            if importlib.util.find_spec(pkg) is None:
                return False, f"package {pkg!r} is not installed (the project's extra 'lpips' installs it)"
        lin = Path(importlib.util.find_spec("lpips").origin).parent / "weights" / "v0.1" / f"{net}.pth"
        if not lin.is_file():
            return False, f"lpips' linear weights not found at {lin}"
        if not (Path(torch.hub.get_dir()) / "checkpoints" / BACKBONE_FILES[net][1]).is_file():
            return False, _missing_backbones([net])
        try:
            import lpips  # noqa: F401, PLC0415  (heavy, optional: imports torchvision)
        except Exception as e:  # noqa: BLE001 - e.g. a torchvision built for another torch
            msg = str(e).splitlines()[0] if str(e) else ""
            return False, f"package 'lpips' cannot be imported ({type(e).__name__}: {msg})"
        return True, ""

    def _build(self, device: torch.device) -> Any:
        if self._net is None:
            ok, why = self.available(self.net_name)
            if not ok:
                raise RuntimeError(f"LPIPS unavailable: {why}")
            import lpips  # noqa: PLC0415  (heavy, optional)

            with warnings.catch_warnings():  # lpips 0.1.4 asks torchvision for `pretrained=True`: two lines a backbone
                warnings.filterwarnings("ignore", message=r".*('pretrained'|for 'weights') .*deprecated", category=UserWarning)
                self._net = lpips.LPIPS(net=self.net_name, verbose=False).eval()
        return self._net.to(device)

    @torch.no_grad()
    def compute(self, pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
        """LPIPS distance (lower is better); with ``mask``, white background as for SSIM.

        Raises RuntimeError with the reason when LPIPS is unavailable.
        """
        net = self._build(pred.device if self.device is None else torch.device(self.device))
        return float(net(*_network_inputs(pred, gt, mask, net), normalize=True).mean())


def lpips_metrics(device: torch.device | str | None = None) -> tuple[dict[str, LPIPSMetric], str | None]:
    """The LPIPS metrics of :data:`LPIPS_NETS` that can be computed here ({metric key: metric}), and
    one line saying why the others cannot (None when all can): their common reason, or each
    key's own."""
    usable, missing = {}, {}
    for key, net in LPIPS_NETS.items():
        ok, why = LPIPSMetric.available(net)
        if ok:
            usable[key] = LPIPSMetric(net, device)
        else:
            missing[key] = why
    if not missing:
        return usable, None
    nets = [LPIPS_NETS[k] for k in missing]
    if all(why == _missing_backbones([LPIPS_NETS[k]]) for k, why in missing.items()):
        return usable, _missing_backbones(nets)
    reasons = set(missing.values())
    return usable, reasons.pop() if len(reasons) == 1 else "; ".join(f"{k}: {why}" for k, why in missing.items())


def _missing_backbones(nets: list[str]) -> str:
    """One line: torchvision's weights of these backbones are not in the torch hub cache, naming the files and the folder."""
    folder = Path(torch.hub.get_dir()) / "checkpoints"
    names = " and ".join(BACKBONE_FILES[n][0] for n in nets)
    files = ", ".join(BACKBONE_FILES[n][1] for n in nets)
    return f"torchvision's {names} weights not found in {folder} ({files}; no download is attempted)"


def _network_inputs(pred: Tensor, gt: Tensor, mask: Tensor | None, net: torch.nn.Module) -> tuple[Tensor, Tensor]:
    """[B, 3, H, W] float pair on ``net``'s device; with ``mask``, on white as for SSIM."""
    dev = next(net.parameters()).device
    pred, gt = pred.to(dev), gt.to(dev)
    if mask is not None:
        pred, gt = _composite_white(pred, gt, mask.to(dev))
    x = pred.float().reshape(-1, *pred.shape[-3:]).permute(0, 3, 1, 2)
    y = gt.float().reshape(-1, *gt.shape[-3:]).permute(0, 3, 1, 2)
    return x, y


class STLPIPSMetric:
    """ST-LPIPS with the AlexNet trunk (the ST-LPIPS default; VGG costs 3.6x more on a CPU), from
    the ``stlpips-pytorch`` wheel's weights, never downloaded."""

    net_name = "alex"

    def __init__(self, device: torch.device | str | None = None) -> None:
        self.device = device
        self._net: Any = None

    @classmethod
    def available(cls) -> tuple[bool, str]:
        """(True, "") when the weight file is installed, else (False, reason)."""
        from .st_lpips import PACKAGE, weights_path

        if weights_path(cls.net_name) is None:
            return False, f"package {PACKAGE!r} is not installed"
        return True, ""

    @torch.no_grad()
    def compute(self, pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
        """ST-LPIPS distance (lower is better); with ``mask``, white background as for SSIM."""
        if self._net is None:
            from .st_lpips import STLPIPS

            self._net = STLPIPS(self.net_name)
        net = self._net.to(pred.device if self.device is None else torch.device(self.device))
        return float(net(*_network_inputs(pred, gt, mask, net)).mean())


def avg_metric(psnr: float, ssim: float, lpips: float | None) -> float | None:
    """RegNeRF AVG: geometric mean of (MSE = 10^(-PSNR/10), sqrt(1 - SSIM), LPIPS); None without LPIPS."""
    if lpips is None:
        return None
    mse = 10.0 ** (-psnr / 10.0)
    dssim = math.sqrt(max(1.0 - ssim, 0.0))
    vals = (mse, dssim, lpips)
    if min(vals) <= 0.0:
        return 0.0
    return math.exp(sum(math.log(v) for v in vals) / 3.0)


def evaluate_images(
    pred: Tensor,
    gt: Tensor,
    mask: Tensor | None = None,
    lpips: Mapping[str, LPIPSMetric] | None = None,
    st_lpips: STLPIPSMetric | None = None,
) -> dict[str, float | None]:
    """Every key of :data:`IMAGE_METRICS`: an LPIPS key is None unless ``lpips`` (metric key ->
    metric, as :func:`lpips_metrics` gives) holds it, avg is None without ``lpips["lpips"]`` (VGG),
    st_lpips is None when ST-LPIPS is not given."""
    p = psnr(pred, gt, mask)
    s = ssim_metric(pred, gt, mask)
    lpips = lpips or {}
    lp = {key: lpips[key].compute(pred, gt, mask) if key in lpips else None for key in LPIPS_NETS}
    st = st_lpips.compute(pred, gt, mask) if st_lpips is not None else None
    return {"psnr": p, "ssim": s, **lp, "avg": avg_metric(p, s, lp["lpips"]), "st_lpips": st}


DEPTH_KEYS = ("depth_abs_rel", "depth_within_5pct", "depth_coverage")
"""Geometry metrics of :func:`depth_metrics` (None where the dataset has no GT depth)."""


def depth_metrics(depth: Tensor, alpha: Tensor, gt_depth: Tensor | None, min_alpha: float = 0.5) -> dict:
    """Error of a rendered expected depth against ground truth (camera z).

    Evaluated over the pixels with ``alpha > min_alpha`` and GT depth > 0.

    Returns:
        depth_abs_rel: mean |d - gt| / gt;
        depth_within_5pct: fraction of those pixels with |d - gt| / gt < 0.05;
        depth_coverage: fraction of the GT-valid pixels that were evaluated
        (rendered alpha above ``min_alpha``).
        All None when there is no GT; the first two None when no pixel qualifies.
    """
    if gt_depth is None:
        return dict.fromkeys(DEPTH_KEYS)
    gt = gt_depth[..., 0].float()
    has_gt = gt > 0
    sel = has_gt & (alpha[..., 0] > min_alpha)
    n_gt = int(has_gt.sum())
    out = {"depth_coverage": float(sel.sum()) / n_gt if n_gt else None}
    if not bool(sel.any()):
        return {"depth_abs_rel": None, "depth_within_5pct": None, **out}
    rel = (depth[..., 0].float()[sel] - gt[sel]).abs() / gt[sel]
    return {"depth_abs_rel": float(rel.mean()), "depth_within_5pct": float((rel < 0.05).float().mean()), **out}

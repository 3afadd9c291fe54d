"""ST-LPIPS (shift-tolerant LPIPS, Ghildyal & Liu, ECCV 2022) from the weights of ``stlpips-pytorch``.

The PyPI package ``stlpips-pytorch`` (BSD-2) ships the whole network (backbone,
blur filters and linear calibration layers) inside its wheel, so this metric
needs no download. Its own modules import torchvision, IPython and torchsummary,
which this project does not depend on, so the package is never imported: its
weight files are located with ``importlib.util.find_spec`` and loaded into the
architecture written here (the package's ``shift_tolerant`` variants of AlexNet
and VGG16: stride-1 convolution / max-pooling followed by anti-aliasing blur
downsampling with reflection padding).

The distance is LPIPS's: inputs in [-1, 1] through a fixed scaling layer, five
feature maps, each unit-normalised over channels, squared differences weighted
by a learned 1x1 convolution, averaged over pixels and summed over layers.

Values are **not** comparable with LPIPS values in papers (another network);
tables call the column ``ST-LPIPS``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.nn import functional as F

__all__ = ["STLPIPS", "weights_path"]

PACKAGE = "stlpips-pytorch"
_CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}


def weights_path(net: str) -> Path | None:
    """The installed package's weight file for ``net`` ("alex" or "vgg"), or None (never imports it)."""
    spec = importlib.util.find_spec("stlpips_pytorch")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "vST0.0" / f"{net}_shift_tolerant.pth"
    return path if path.is_file() else None


class _BlurDown(nn.Module):
    """Anti-aliased downsampling: reflection pad 2, depthwise [1 2 1]^T [1 2 1] / 16 blur, stride 2."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        a = torch.tensor([1.0, 2.0, 1.0])
        self.register_buffer("filt", (a[:, None] * a[None, :] / 16.0).expand(channels, 1, 3, 3).clone())

    def forward(self, x: Tensor) -> Tensor:
        return F.conv2d(F.pad(x, (2, 2, 2, 2), mode="reflect"), self.filt, stride=2, groups=x.shape[1])


def _alex_slices() -> list[nn.Sequential]:
    """AlexNet's five LPIPS slices, shift-tolerant (module indices as in the weight file)."""
    def seq(start: int, *mods: nn.Module) -> nn.Sequential:
        s = nn.Sequential()
        for i, m in enumerate(mods):
            s.add_module(str(start + i), m)
        return s

    relu = lambda: nn.ReLU(inplace=True)  # noqa: E731
    pool = lambda: nn.MaxPool2d(kernel_size=3, stride=1)  # noqa: E731
    return [
        seq(0, nn.Conv2d(3, 64, 11, stride=1, padding=2), _BlurDown(64), relu()),
        seq(3, pool(), _BlurDown(64), nn.Conv2d(64, 192, 5, padding=2), relu()),
        seq(7, pool(), _BlurDown(192), nn.Conv2d(192, 384, 3, padding=1), relu()),
        seq(11, nn.Conv2d(384, 256, 3, padding=1), relu()),
        seq(13, nn.Conv2d(256, 256, 3, padding=1), relu()),
    ]


def _vgg_slices() -> list[nn.Sequential]:
    """VGG16's five LPIPS slices (up to relu1_2 ... relu5_3), shift-tolerant: every 2x2 max-pool
    has stride 1 and is followed by blur downsampling."""
    layers: list[nn.Module] = []
    cuts = []
    c_in = 3
    for v in (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512):
        if v == "M":
            cuts.append(len(layers))
            layers += [nn.MaxPool2d(kernel_size=2, stride=1), _BlurDown(c_in)]
        else:
            layers += [nn.Conv2d(c_in, v, 3, padding=1), nn.ReLU(inplace=True)]
            c_in = v
    bounds = [0, *cuts, len(layers)]
    slices = []
    for lo, hi in zip(bounds, bounds[1:]):
        s = nn.Sequential()
        for i in range(lo, hi):
            s.add_module(str(i), layers[i])
        slices.append(s)
    return slices


class _Lin(nn.Module):
    """LPIPS's per-layer weights: a 1x1 convolution to one channel, no bias."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.model = nn.Sequential()
        self.model.add_module("1", nn.Conv2d(channels, 1, 1, bias=False))

    def forward(self, x: Tensor) -> Tensor:
        return self.model(x)


class _Trunk(nn.Module):
    def __init__(self, slices: list[nn.Sequential]) -> None:
        super().__init__()
        for i, s in enumerate(slices, start=1):
            self.add_module(f"slice{i}", s)

    def forward(self, x: Tensor) -> list[Tensor]:
        out = []
        for s in self.children():
            x = s(x)
            out.append(x)
        return out


class STLPIPS(nn.Module):
    """ST-LPIPS distance between images in [0, 1] (lower is more similar).

    Args:
        net: "alex" (the ST-LPIPS default, cheap) or "vgg".
        weights: a weight file; default: the installed ``stlpips-pytorch`` package's.

    Raises:
        FileNotFoundError: one line naming the package, when there are no weights.
    """

    def __init__(self, net: str = "alex", weights: Path | None = None) -> None:
        super().__init__()
        if net not in _CHANNELS:
            raise ValueError(f"ST-LPIPS net must be one of {sorted(_CHANNELS)}, got {net!r}")
        path = Path(weights) if weights is not None else weights_path(net)
        if path is None or not path.is_file():
            raise FileNotFoundError(f"ST-LPIPS weights not found (pip install {PACKAGE})")
        self.register_buffer("shift", torch.zeros(1, 3, 1, 1))
        self.register_buffer("scale", torch.ones(1, 3, 1, 1))
        self.net = _Trunk(_alex_slices() if net == "alex" else _vgg_slices())
        self.lins = nn.ModuleList(_Lin(c) for c in _CHANNELS[net])
        state = torch.load(path, map_location="cpu", weights_only=True)
        state = {k.replace("scaling_layer.", "").replace("lin", "lins.", 1) if k.startswith(("scaling_layer.", "lin")) else k: v
                 for k, v in state.items()}
        self.load_state_dict(state, strict=True)
        self.requires_grad_(False)
        self.eval()

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        """[B] distances of [B, 3, H, W] images (or one [H, W, 3] pair, giving [1]) in [0, 1]."""
        a, b = (self._batch(x) for x in (a, b))
        fa = self.net((a * 2 - 1 - self.shift) / self.scale)
        fb = self.net((b * 2 - 1 - self.shift) / self.scale)
        total = 0.0
        for lin, xa, xb in zip(self.lins, fa, fb):
            na = xa / (xa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = xb / (xb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((na - nb) ** 2).mean(dim=(1, 2, 3))
        return total

    @staticmethod
    def _batch(x: Tensor) -> Tensor:
        if x.dim() == 3 and x.shape[-1] == 3:
            x = x.permute(2, 0, 1)[None]
        if x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(f"expected [B, 3, H, W] or [H, W, 3] images, got {tuple(x.shape)}")
        return x.float()

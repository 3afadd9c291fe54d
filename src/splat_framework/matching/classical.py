"""Classical matchers (OpenCV): SIFT with ratio and mutual checks, and dense DIS optical flow."""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .base import Pts, no_matches, texture, to_gray_u8, to_hwc
from .sampling import balanced_sample

if TYPE_CHECKING:  # pragma: no cover
    from ..config.matching import MatchConfig

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
            return no_matches()
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
        upscale: float = 1.0,
    ) -> None:
        if preset not in _DIS_PRESETS:
            raise ValueError(f"unknown DIS preset {preset!r}; choose one of {sorted(_DIS_PRESETS)}")
        self.preset = preset
        self.fb_threshold = float(fb_threshold)
        self.max_matches = int(max_matches)
        self.grid_cell = int(grid_cell)
        self.seed = int(seed)
        self.min_texture = float(min_texture)
        self.upscale = float(upscale)

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
            upscale=config.dense_upscale,
        )

    def flows(self, gray_a: np.ndarray, gray_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward (A->B) and backward (B->A) flow, [H, W, 2] float32 each (computed at ``upscale``
        times the size, then area-averaged back and divided by it)."""
        import cv2

        h, w = gray_a.shape
        if self.upscale > 1:
            gray_a, gray_b = (cv2.resize(g, None, fx=self.upscale, fy=self.upscale, interpolation=cv2.INTER_CUBIC)
                              for g in (gray_a, gray_b))
        dis = cv2.DISOpticalFlow_create(getattr(cv2, _DIS_PRESETS[self.preset]))
        f_ab = dis.calc(gray_a, gray_b, None)
        dis = cv2.DISOpticalFlow_create(getattr(cv2, _DIS_PRESETS[self.preset]))
        f_ba = dis.calc(gray_b, gray_a, None)
        if self.upscale > 1:
            f_ab, f_ba = (cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) / self.upscale for f in (f_ab, f_ba))
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
            h, w = to_hwc(img_a).shape[:2]
            idx = balanced_sample(pa, self.max_matches, w, h, self.grid_cell, self.seed)
            pa, pb = pa[idx], pb[idx]
        return pa, pb

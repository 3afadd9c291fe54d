"""What every matcher shares: the point type, the ``Matcher`` protocol and image conversions."""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

import numpy as np

Pts = np.ndarray  # [M, 2] float32 continuous pixel coordinates


class Matcher(Protocol):
    """A two-view matcher: ``match(a, b) -> (pts_a, pts_b)``, [M, 2] float32 (+0.5 convention)."""

    name: ClassVar[str]

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]: ...


def to_hwc(img: Any) -> np.ndarray:
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
    a = to_hwc(img)
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


def no_matches() -> tuple[Pts, Pts]:
    return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)


def inside_mask(pts: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """[M] bool: the pixel holding each continuous point [M, 2] is inside ``mask`` [H, W] and nonzero there."""
    h, w = mask.shape
    x, y = np.floor(pts[:, 0]).astype(np.int64), np.floor(pts[:, 1]).astype(np.int64)
    ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    ok[ok] = mask[y[ok], x[ok]] > 0
    return ok


class KnownMatches:
    """A matcher that returns one pair's matches computed earlier (by the posing of the photos,
    :mod:`splat_framework.sfm.pose_matches`), whatever the images."""

    name = "posing"

    def __init__(self, pts_a: np.ndarray, pts_b: np.ndarray) -> None:
        self.pts = (pts_a, pts_b)

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.pts

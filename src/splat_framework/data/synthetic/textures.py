"""Procedural textures for the synthetic scenes, and mip-mapped texture lookup.

A texture is built from seeded fractal value noise, checkers and stripes at
several scales, random discs and bars, and text drawn with ``cv2.putText``,
so that it has corners and blobs at many scales for feature matching. It is
stored as a mip pyramid (float32 [h, w, 3] levels in [0, 1]) and sampled
trilinearly with a level chosen from the pixel footprint, which keeps
distant surfaces free of aliasing without supersampling.
"""

from __future__ import annotations

import cv2
import numpy as np

_WORDS = [
    "SPLAT", "GAUSS", "RAY", "FERN", "LEGO", "NERF", "VIEW", "DEPTH", "MATCH", "POSE",
    "ALPHA", "SCENE", "CAMERA", "PIXEL", "FOCAL", "EPIPOLE", "TORCH", "OPENCV", "42", "2024",
    "A1", "B7", "Z9", "XYZ", "UV", "K-3", "N=8", "SIFT", "ORB", "PLY",
]
_FONTS = [cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN]


def value_noise(rng: np.random.Generator, h: int, w: int, cells: int = 4, octaves: int = 5) -> np.ndarray:
    """Fractal value noise [h, w] float32 in [0, 1] (bicubic-upsampled random lattices)."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        c = cells * 2**k
        gh = max(2, int(round(c * h / max(h, w))) + 1)
        gw = max(2, int(round(c * w / max(h, w))) + 1)
        grid = rng.random((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.5
    out /= total
    lo, hi = np.percentile(out, [1, 99])
    return np.clip((out - lo) / max(hi - lo, 1e-6), 0, 1)


def _c8(rng: np.random.Generator) -> tuple:
    return tuple(int(x) for x in np.round(_color(rng, 0.0, 1.0) * 255))


def _color(rng: np.random.Generator, lo: float = 0.1, hi: float = 0.95) -> np.ndarray:
    hsv = np.array([[[rng.uniform(0, 180), rng.uniform(90, 255), rng.uniform(lo * 255, hi * 255)]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32) / 255.0


def make_texture(rng: np.random.Generator, h: int, w: int, *, text: bool = True, tiles: float = 1.0) -> np.ndarray:
    """A rich seeded texture [h, w, 3] float32 in [0, 1].

    ``tiles``: how many "tiles" of detail span the long side; features shrink
    by this factor and their number grows with its square (for large surfaces).
    """
    density = tiles * tiles
    base_a, base_b, base_c = _color(rng), _color(rng), _color(rng)
    n1 = value_noise(rng, h, w, cells=int(rng.integers(2, 6) * tiles))[..., None]
    n2 = value_noise(rng, h, w, cells=int(rng.integers(8, 20) * tiles), octaves=3)[..., None]
    img = base_a * (1 - n1) + base_b * n1
    img = img * (0.75 + 0.5 * n2) + 0.0
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    # checker at a random scale, blended through a noise mask
    cs = float(rng.uniform(8, 40)) * max(h, w) / 256.0 / tiles
    chk = ((np.floor(xx / cs) + np.floor(yy / cs)) % 2)[..., None]
    mask = (value_noise(rng, h, w, cells=int(3 * tiles), octaves=2) > 0.55).astype(np.float32)[..., None]
    img = img * (1 - 0.6 * mask) + 0.6 * mask * (chk * base_c + (1 - chk) * (1 - base_c))
    # stripes at another angle and frequency
    ang = rng.uniform(0, np.pi)
    period = float(rng.uniform(6, 24)) * max(h, w) / 256.0 / tiles
    st = 0.5 + 0.5 * np.sin(2 * np.pi * (xx * np.cos(ang) + yy * np.sin(ang)) / period)
    smask = (value_noise(rng, h, w, cells=int(3 * tiles), octaves=2) > 0.6).astype(np.float32)[..., None]
    img = img * (1 - 0.5 * smask * st[..., None])
    img = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)  # cv2 drawing (putText) needs 8-bit
    scale = max(h, w) / 256.0 / tiles
    # discs and bars
    for _ in range(int(density * rng.integers(6, 14))):
        c = _c8(rng)
        if rng.random() < 0.5:
            cv2.circle(img, (int(rng.integers(0, w)), int(rng.integers(0, h))),
                       int(rng.uniform(3, 18) * scale), c, -1, cv2.LINE_AA)
        else:
            x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
            cv2.rectangle(img, (x0, y0), (x0 + int(rng.uniform(4, 40) * scale), y0 + int(rng.uniform(4, 40) * scale)),
                          c, -1, cv2.LINE_AA)
    for _ in range(int(density * rng.integers(3, 8))):
        c = _c8(rng)
        p0 = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ang, length = rng.uniform(0, 2 * np.pi), rng.uniform(20, 120) * scale
        p1 = (int(p0[0] + length * np.cos(ang)), int(p0[1] + length * np.sin(ang)))
        cv2.line(img, p0, p1, c, max(1, int(rng.uniform(1, 4) * scale)), cv2.LINE_AA)
    if text:
        for _ in range(int(density * rng.integers(4, 9))):
            word = _WORDS[int(rng.integers(len(_WORDS)))]
            font = _FONTS[int(rng.integers(len(_FONTS)))]
            fs = float(rng.uniform(0.5, 2.2)) * scale
            th = max(1, int(round(fs * rng.uniform(1.0, 2.5))))
            lum = img.mean() / 255.0
            c = (12, 12, 12) if lum > 0.45 else (248, 248, 230)
            if rng.random() < 0.4:
                c = _c8(rng)
            cv2.putText(img, word, (int(rng.integers(0, max(1, w - 40 * scale))), int(rng.integers(int(20 * scale), h))),
                        font, fs, c, th, cv2.LINE_AA)
    return img.astype(np.float32) / 255.0


def mip_pyramid(img: np.ndarray) -> list[np.ndarray]:
    """Mip levels (level 0 = ``img``), halving until the short side is < 8 texels.

    Each level is stored with a one-texel border (columns wrapped, since u
    wraps around spheres and cylinders; rows replicated), which
    :func:`sample` accounts for.
    """
    levels = [np.ascontiguousarray(img, dtype=np.float32)]
    while min(levels[-1].shape[:2]) >= 8:
        levels.append(cv2.pyrDown(levels[-1]))
    padded = []
    for lv in levels:
        lv = np.concatenate([lv[:, -1:], lv, lv[:, :1]], axis=1)
        padded.append(np.ascontiguousarray(np.concatenate([lv[:1], lv, lv[-1:]], axis=0)))
    return padded


_BLOCK = 4096  # cv2.remap needs maps narrower than SHRT_MAX


def _bilinear(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup in a padded level (texel centres at +0.5), wrapping in u and clamping in v."""
    h, w = tex.shape[0] - 2, tex.shape[1] - 2
    n = len(uv)
    rows = -(-n // _BLOCK)
    mx = np.zeros(rows * _BLOCK, np.float32)
    my = np.zeros(rows * _BLOCK, np.float32)
    mx[:n] = np.mod(uv[:, 0], 1.0) * w + 0.5  # + 1 (border) - 0.5 (texel centre)
    my[:n] = np.clip(uv[:, 1], 0.0, 1.0) * h + 0.5
    out = cv2.remap(tex, mx.reshape(rows, _BLOCK), my.reshape(rows, _BLOCK), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n]


def sample(pyramid: list[np.ndarray], uv: np.ndarray, lod: np.ndarray) -> np.ndarray:
    """Trilinear lookup: [n, 2] uv in [0, 1]^2, [n] level of detail (0 = finest) -> [n, 3]."""
    lod = np.clip(lod, 0, len(pyramid) - 1)
    lo = np.floor(lod).astype(np.int64)
    frac = (lod - lo).astype(np.float32)[:, None]
    out = np.zeros((len(uv), 3), np.float32)
    for level in np.unique(lo):
        sel = np.nonzero(lo == level)[0]
        a = _bilinear(pyramid[level], uv[sel])
        if level + 1 < len(pyramid):
            blend = np.nonzero(frac[sel, 0] > 0)[0]  # magnified texels (lod 0) need one level only
            if len(blend):
                b = _bilinear(pyramid[level + 1], uv[sel[blend]])
                f = frac[sel[blend]]
                a[blend] = a[blend] * (1 - f) + b * f
        out[sel] = a
    return out

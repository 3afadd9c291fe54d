"""Procedural textures for the synthetic scenes, and mip-mapped texture lookup.

A texture is built from seeded fractal value noise, checkers and stripes at
several scales, random discs and bars, and words drawn in a stroke font of
this module, so that it has corners and blobs at many scales for feature
matching. It is stored as a mip pyramid (float32 [h, w, 3] levels in [0, 1])
and sampled trilinearly with a level chosen from the pixel footprint, which
keeps distant surfaces free of aliasing without supersampling.

The pixels are the same with every OpenCV version: the colour conversion, the
upsampling of the noise, the pyramid, the lookup and the letters are this
module's numpy code, and OpenCV draws only anti-aliased discs, rectangles and
lines, whose rasterisation has not changed between its releases
(``tests/framework/data/test_synthetic.py`` holds the digest of the built-in
scene). OpenCV's ``putText`` and ``cvtColor(HSV2RGB)`` are not used: their
pixels differ between OpenCV 4.x, 5.0 and 5.1.
"""

from __future__ import annotations

import cv2
import numpy as np

_WORDS = [
    "SPLAT", "GAUSS", "RAY", "FERN", "LEGO", "NERF", "VIEW", "DEPTH", "MATCH", "POSE",
    "ALPHA", "SCENE", "CAMERA", "PIXEL", "FOCAL", "EPIPOLE", "TORCH", "OPENCV", "42", "2024",
    "A1", "B7", "Z9", "XYZ", "UV", "K-3", "N=8", "SIFT", "ORB", "PLY",
]

_P = [(0, 6), (0, 0), (3, 0), (4, 1), (4, 2), (3, 3), (0, 3)]  # the bowl of P and R
_O = [(1, 0), (3, 0), (4, 1), (4, 5), (3, 6), (1, 6), (0, 5), (0, 1), (1, 0)]
_GLYPHS: dict[str, list[list[tuple[float, float]]]] = {
    "A": [[(0, 6), (2, 0), (4, 6)], [(0.7, 4), (3.3, 4)]],
    "B": [[(0, 3), (3, 3), (4, 4), (4, 5), (3, 6), (0, 6), (0, 0), (3, 0), (4, 1), (4, 2), (3, 3)]],
    "C": [[(4, 1), (3, 0), (1, 0), (0, 1), (0, 5), (1, 6), (3, 6), (4, 5)]],
    "D": [[(0, 0), (0, 6), (2.5, 6), (4, 4.5), (4, 1.5), (2.5, 0), (0, 0)]],
    "E": [[(4, 0), (0, 0), (0, 6), (4, 6)], [(0, 3), (3, 3)]],
    "F": [[(4, 0), (0, 0), (0, 6)], [(0, 3), (3, 3)]],
    "G": [[(4, 1), (3, 0), (1, 0), (0, 1), (0, 5), (1, 6), (3, 6), (4, 5), (4, 3), (2, 3)]],
    "H": [[(0, 0), (0, 6)], [(4, 0), (4, 6)], [(0, 3), (4, 3)]],
    "I": [[(1, 0), (3, 0)], [(2, 0), (2, 6)], [(1, 6), (3, 6)]],
    "K": [[(0, 0), (0, 6)], [(4, 0), (0, 4)], [(1.3, 3), (4, 6)]],
    "L": [[(0, 0), (0, 6), (4, 6)]],
    "M": [[(0, 6), (0, 0), (2, 3), (4, 0), (4, 6)]],
    "N": [[(0, 6), (0, 0), (4, 6), (4, 0)]],
    "O": [_O],
    "P": [_P],
    "R": [_P, [(2, 3), (4, 6)]],
    "S": [[(4, 1), (3, 0), (1, 0), (0, 1), (0, 2), (1, 3), (3, 3), (4, 4), (4, 5), (3, 6), (1, 6), (0, 5)]],
    "T": [[(0, 0), (4, 0)], [(2, 0), (2, 6)]],
    "U": [[(0, 0), (0, 5), (1, 6), (3, 6), (4, 5), (4, 0)]],
    "V": [[(0, 0), (2, 6), (4, 0)]],
    "W": [[(0, 0), (1, 6), (2, 2), (3, 6), (4, 0)]],
    "X": [[(0, 0), (4, 6)], [(4, 0), (0, 6)]],
    "Y": [[(0, 0), (2, 3), (4, 0)], [(2, 3), (2, 6)]],
    "Z": [[(0, 0), (4, 0), (0, 6), (4, 6)]],
    "0": [_O, [(4, 1), (0, 5)]],
    "1": [[(1, 1), (2, 0), (2, 6)], [(1, 6), (3, 6)]],
    "2": [[(0, 1), (1, 0), (3, 0), (4, 1), (4, 2), (0, 6), (4, 6)]],
    "3": [[(0, 1), (1, 0), (3, 0), (4, 1), (4, 2), (3, 3), (4, 4), (4, 5), (3, 6), (1, 6), (0, 5)], [(1.5, 3), (3, 3)]],
    "4": [[(3, 6), (3, 0), (0, 4), (4, 4)]],
    "7": [[(0, 0), (4, 0), (1.5, 6)]],
    "8": [[(3, 3), (1, 3), (0, 4), (0, 5), (1, 6), (3, 6), (4, 5), (4, 4), (3, 3), (4, 2), (4, 1), (3, 0), (1, 0),
           (0, 1), (0, 2), (1, 3)]],
    "9": [[(4, 3), (1, 3), (0, 2), (0, 1), (1, 0), (3, 0), (4, 1), (4, 5), (3, 6), (1, 6), (0, 5)]],
    "-": [[(0.5, 3), (3.5, 3)]],
    "=": [[(0.5, 2), (3.5, 2)], [(0.5, 4), (3.5, 4)]],
}
"""Stroke letters: polylines on a 4 x 6 grid (x right, y down from the cap line to the baseline)."""

_STYLES = [(1.0, 0.0), (1.2, 0.0), (0.8, 0.0), (1.0, 0.25), (1.3, 0.2)]
"""Letter styles (width factor, slant): upright, wide, narrow, italic, wide italic."""

_CAP = 21.0
"""Cap height in pixels at size 1 (about that of OpenCV's Hershey fonts at fontScale 1)."""


def draw_text(img: np.ndarray, word: str, origin: tuple[int, int], size: float, color: tuple, thickness: int,
              style: int = 0) -> None:
    """Draw ``word`` in place on uint8 ``img`` [h, w, 3] with its baseline starting at ``origin`` (x, y).

    ``size`` scales the letters (cap height ``21 * size`` pixels); strokes are anti-aliased lines.
    """
    stretch, slant = _STYLES[style % len(_STYLES)]
    unit = _CAP * size / 6.0
    x0, base = origin
    for k, ch in enumerate(word):
        left = x0 + k * 5.5 * stretch * unit
        for stroke in _GLYPHS[ch]:
            pts = [(left + (gx * stretch + slant * (6 - gy)) * unit, base - (6 - gy) * unit) for gx, gy in stroke]
            for (ax, ay), (bx, by) in zip(pts[:-1], pts[1:]):
                cv2.line(img, (int(round(ax)), int(round(ay))), (int(round(bx)), int(round(by))), color, thickness,
                         cv2.LINE_AA)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """[..., 3] float HSV (hue in degrees [0, 360), saturation and value in [0, 1]) -> [..., 3] RGB in [0, 1]."""
    h, s, v = (hsv[..., i] for i in range(3))
    k = np.stack([(5 + h / 60) % 6, (3 + h / 60) % 6, (1 + h / 60) % 6], -1)
    return v[..., None] - v[..., None] * s[..., None] * np.clip(np.minimum(k, 4 - k), 0, 1)


def _cubic_weights(n_out: int, n_in: int) -> np.ndarray:
    """[n_out, n_in] bicubic resampling matrix (a = -0.75, pixel centres at +0.5, edges replicated)."""
    x = (np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5
    x0 = np.floor(x)
    m = np.zeros((n_out, n_in), np.float64)
    for tap in range(-1, 3):
        d = np.abs(x - (x0 + tap))
        a = -0.75
        w = np.where(d <= 1, ((a + 2) * d - (a + 3)) * d * d + 1, ((a * d - 5 * a) * d + 8 * a) * d - 4 * a)
        np.add.at(m, (np.arange(n_out), np.clip(x0 + tap, 0, n_in - 1).astype(np.int64)), w)
    return m


def resize_cubic(grid: np.ndarray, h: int, w: int) -> np.ndarray:
    """Bicubic resize of [gh, gw] float32 to [h, w] float32."""
    out = _cubic_weights(h, grid.shape[0]) @ grid.astype(np.float64) @ _cubic_weights(w, grid.shape[1]).T
    return out.astype(np.float32)


def pyr_down(img: np.ndarray) -> np.ndarray:
    """Blur [h, w, c] float32 with the 5-tap binomial kernel (mirrored edges) and keep every other texel."""
    k = np.array([1, 4, 6, 4, 1], np.float32) / 16
    p = np.pad(img, ((2, 2), (2, 2), (0, 0)), mode="reflect")
    rows = sum(k[i] * p[i:i + img.shape[0]:2] for i in range(5))
    return np.ascontiguousarray(sum(k[i] * rows[:, i:i + img.shape[1]:2] for i in range(5)), dtype=np.float32)


def value_noise(rng: np.random.Generator, h: int, w: int, cells: int = 4, octaves: int = 5) -> np.ndarray:
    """Fractal value noise [h, w] float32 in [0, 1] (bicubic-upsampled random lattices)."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        c = cells * 2**k
        gh = max(2, int(round(c * h / max(h, w))) + 1)
        gw = max(2, int(round(c * w / max(h, w))) + 1)
        grid = rng.random((gh, gw)).astype(np.float32)
        out += amp * resize_cubic(grid, h, w)
        total += amp
        amp *= 0.5
    out /= total
    lo, hi = np.percentile(out, [1, 99])
    return np.clip((out - lo) / max(hi - lo, 1e-6), 0, 1)


def _c8(rng: np.random.Generator) -> tuple:
    return tuple(int(x) for x in np.round(_color(rng, 0.0, 1.0) * 255))


def _color(rng: np.random.Generator, lo: float = 0.1, hi: float = 0.95) -> np.ndarray:
    """A random saturated colour [3] float32 in [0, 1], its value (brightness) in [lo, hi]."""
    hsv = np.array([rng.uniform(0, 180), rng.uniform(90, 255), rng.uniform(lo * 255, hi * 255)], np.uint8)
    return hsv_to_rgb(hsv.astype(np.float32) * np.array([2.0, 1 / 255, 1 / 255], np.float32)).astype(np.float32)


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
    img = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)  # cv2 drawing needs 8-bit
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
            style = int(rng.integers(len(_STYLES)))
            fs = float(rng.uniform(0.5, 2.2)) * scale
            th = max(1, int(round(fs * rng.uniform(1.0, 2.5))))
            lum = img.mean() / 255.0
            c = (12, 12, 12) if lum > 0.45 else (248, 248, 230)
            if rng.random() < 0.4:
                c = _c8(rng)
            draw_text(img, word, (int(rng.integers(0, max(1, w - 40 * scale))), int(rng.integers(int(20 * scale), h))),
                      fs, c, th, style)
    return img.astype(np.float32) / 255.0


def mip_pyramid(img: np.ndarray) -> list[np.ndarray]:
    """Mip levels (level 0 = ``img``), halving until the short side is < 8 texels.

    Each level is stored with a one-texel border (columns wrapped, since u
    wraps around spheres and cylinders; rows replicated), which
    :func:`sample` accounts for.
    """
    levels = [np.ascontiguousarray(img, dtype=np.float32)]
    while min(levels[-1].shape[:2]) >= 8:
        levels.append(pyr_down(levels[-1]))
    padded = []
    for lv in levels:
        lv = np.concatenate([lv[:, -1:], lv, lv[:, :1]], axis=1)
        padded.append(np.ascontiguousarray(np.concatenate([lv[:1], lv, lv[-1:]], axis=0)))
    return padded


def _bilinear(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup in a padded level (texel centres at +0.5), wrapping in u and clamping in v."""
    h, w = tex.shape[0] - 2, tex.shape[1] - 2
    x = np.mod(uv[:, 0], 1.0).astype(np.float32) * w + 0.5  # + 1 (border) - 0.5 (texel centre)
    y = np.clip(uv[:, 1], 0.0, 1.0).astype(np.float32) * h + 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    xa, xb = np.clip(x0, 0, w + 1).astype(np.int64), np.clip(x0 + 1, 0, w + 1).astype(np.int64)
    ya, yb = np.clip(y0, 0, h + 1).astype(np.int64), np.clip(y0 + 1, 0, h + 1).astype(np.int64)
    top = tex[ya, xa] * (1 - fx) + tex[ya, xb] * fx
    bottom = tex[yb, xa] * (1 - fx) + tex[yb, xb] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


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

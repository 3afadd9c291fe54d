"""Pictures of matches: the two views side by side with match lines."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import to_uint8_rgb


def draw_matches(
    img_a: np.ndarray,
    img_b: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    path: Path | str,
    max_lines: int = 200,
    seed: int = 0,
) -> Path:
    """Write (atomically) a side-by-side picture of the two images with (a random subset of) match lines."""
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
    from ..runtime.io import atomic_write_bytes

    path = Path(path)
    ok, encoded = cv2.imencode(path.suffix or ".png", canvas)
    if not ok:
        raise OSError(f"could not encode {path}")
    atomic_write_bytes(path, encoded.tobytes())  # never a half-written picture
    return path

"""Paper-style qualitative figures assembled from finished runs' test-view renders.

``comparison_figure`` reads only PNGs that :func:`splat_framework.evaluation.held_out.evaluate`
wrote into ``<run>/renders`` (``<view>_render.png``, ``<view>_gt.png``); it
loads no model and no dataset, so it is cheap to call from a sweep.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError

__all__ = ["comparison_figure", "run_views"]

_SUFFIX = "_render.png"


def run_views(run_dir: Path) -> list[str]:
    """Names of the test views rendered in ``run_dir/renders`` (sorted)."""
    d = Path(run_dir) / "renders"
    return sorted(p.name[: -len(_SUFFIX)] for p in d.glob(f"*{_SUFFIX}")) if d.is_dir() else []


def _read_rgb(path: Path) -> np.ndarray | None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else np.ascontiguousarray(img[..., ::-1])


def _gt_image(runs: list[Path], view: str) -> np.ndarray | None:
    """The view's ground truth: ``<view>_gt.png`` of any run, else the first panel of its grid."""
    for run in runs:
        img = _read_rgb(run / "renders" / f"{view}_gt.png")
        if img is not None:
            return img
    for run in runs:
        grid = _read_rgb(run / "renders" / f"{view}_grid.png")
        if grid is not None:
            return np.ascontiguousarray(grid[:, : grid.shape[1] // 4])
    return None


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, thick: int) -> None:
    import cv2

    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick, cv2.LINE_AA)


def comparison_figure(
    rows: list[tuple[str, Path]],
    out: Path,
    views: list[str] | None = None,
    max_views: int = 6,
    min_height: int = 160,
    gap: int = 4,
) -> Path:
    """Qualitative comparison: ground truth on top, one row per method below, one column per test view.

    Args:
        rows: (label, run folder) per method, top to bottom; each run folder
            holds ``renders/<view>_render.png`` (written by evaluation).
        out: PNG to write (atomically).
        views: test-view names to show (default: the views the first run
            rendered, at most ``max_views``, evenly spread).
        max_views: cap on the default number of columns.
        min_height: tiles smaller than this are enlarged by an integer factor
            (nearest neighbour) so that tiny scenes stay readable.
        gap: white pixels between tiles.

    A view a run did not render is shown as a grey tile. Raises DataError when
    ``rows`` is empty or the first run has no renders.
    """
    import cv2

    from .pictures import write_png

    if not rows:
        raise DataError("comparison figure: no runs given")
    runs = [Path(r) for _, r in rows]
    if views is None:
        views = run_views(runs[0])
        if not views:
            raise DataError(f"{runs[0] / 'renders'}: no *{_SUFFIX} test renders")
        if len(views) > max_views:
            pick = np.linspace(0, len(views) - 1, max_views).round().astype(int)
            views = [views[i] for i in pick]
    grid_rows: list[tuple[str, list[np.ndarray | None]]] = [("GT", [_gt_image(runs, v) for v in views])]
    for label, run in rows:
        grid_rows.append((label, [_read_rgb(Path(run) / "renders" / f"{v}{_SUFFIX}") for v in views]))
    sizes = [img.shape[:2] for _, imgs in grid_rows for img in imgs if img is not None]
    if not sizes:
        raise DataError(f"comparison figure: none of the views {views} was rendered")
    h, w = sizes[0]
    factor = max(1, int(np.ceil(min_height / h)))
    th, tw = h * factor, w * factor

    def tile(img: np.ndarray | None) -> np.ndarray:
        if img is None:
            return np.full((th, tw, 3), 160, np.uint8)
        if img.shape[:2] != (th, tw):
            interp = cv2.INTER_NEAREST if img.shape[:2] == (h, w) else cv2.INTER_AREA
            img = cv2.resize(img, (tw, th), interpolation=interp)
        return img

    scale = min(max(th / 300.0, 0.45), 1.2)
    thick = 1 if scale < 0.9 else 2
    label_w = max(cv2.getTextSize(lbl, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] for lbl, _ in grid_rows) + 2 * gap + 8
    head_h = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][1] * 2 + gap
    n_cols = len(views)
    H = head_h + len(grid_rows) * (th + gap)
    W = label_w + n_cols * (tw + gap)
    canvas = np.full((H, W, 3), 255, np.uint8)
    for c, v in enumerate(views):
        x0 = label_w + c * (tw + gap)
        (vw, _), _ = cv2.getTextSize(v, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        _text(canvas, v, (x0 + max((tw - vw) // 2, 0), head_h - gap - 2), scale, thick)
    for r, (label, imgs) in enumerate(grid_rows):
        y0 = head_h + r * (th + gap)
        (_, lh), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        _text(canvas, label, (gap, y0 + (th + lh) // 2), scale, thick)
        for c, img in enumerate(imgs):
            x0 = label_w + c * (tw + gap)
            canvas[y0 : y0 + th, x0 : x0 + tw] = tile(img)
    out = Path(out)
    write_png(out, canvas)
    return out

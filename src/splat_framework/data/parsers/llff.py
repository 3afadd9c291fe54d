"""LLFF forward-facing scenes (``poses_bounds.npy`` + ``images*/``).

``poses_bounds.npy`` is [N, 17]: per image a 3x5 matrix (rotation columns in
LLFF's "down, right, back" order, camera centre, [H, W, focal] at full
resolution) followed by the near and far scene bounds. Poses are used as
stored (no recentring or rescaling), converted to OpenCV axes:
``[right, down, forward] = [col1, col0, -col2]``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..scene import DataError, SceneData
from ..splits import Views, llff_split
from .common import (
    build_scene,
    check_same_size,
    choose_image_dir,
    decoded_size,
    find_images,
    image_folders,
    make_camera,
    pixel_ratios,
)


def load_poses_bounds(path: Path) -> np.ndarray:
    """[N, 17] float64 array from ``poses_bounds.npy``, validated for shape and finiteness."""
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - every read failure is bad input
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise DataError(f"{path}: cannot read .npy file ({msg})") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu":
        kind = getattr(arr, "dtype", type(arr))
        raise DataError(f"{path}: expected a float array, got {kind}")
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] < 1:
        raise DataError(f"{path}: expected shape [N, 17], got {list(arr.shape)}")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise DataError(f"{path}: non-finite values (nan/inf) in row {int(np.argmax(bad))}")
    return arr


def load_llff(root: Path, *, views: Views = "all", downscale: float | None = None) -> SceneData:
    pb_path = root / "poses_bounds.npy"
    arr = load_poses_bounds(pb_path)
    n = arr.shape[0]
    poses = arr[:, :15].reshape(n, 3, 5)
    bounds = arr[:, 15:17]

    default = 8.0 if 8 in image_folders(root) else None
    folder, image_scale, _ = choose_image_dir(root, downscale, default)
    paths = find_images(folder)
    if len(paths) != n:
        raise DataError(f"{pb_path}: {n} poses but {len(paths)} images in {folder.name}/")
    stored = check_same_size(paths)
    w, h = decoded_size(stored, image_scale)

    depth_dir = root / "depths"
    depth_paths = None
    if depth_dir.is_dir():
        depth_paths = [depth_dir / f"{p.stem}.npy" for p in paths]
        for d in depth_paths:
            if not d.is_file():
                raise DataError(f"{d}: depth map missing (depths/ must hold one <image stem>.npy per image)")

    cameras = []
    for i, p in enumerate(paths):
        where = f"{pb_path}: row {i} ({p.name})"
        H, W, f = poses[i, :, 4]
        if not (H > 0 and W > 0):
            raise DataError(f"{where}: image size H={H:g}, W={W:g} must be positive")
        if not f > 0:
            raise DataError(f"{where}: degenerate pose, focal {f:g} must be positive")
        sx, _ = pixel_ratios((w, h), (W, H), where, "poses give")
        rot = poses[i, :, :3]
        R = np.stack([rot[:, 1], rot[:, 0], -rot[:, 2]], axis=1)
        near, far = float(bounds[i, 0]), float(bounds[i, 1])
        cameras.append(
            make_camera(
                R, poses[i, :, 3], f * sx, f * sx, w / 2.0, h / 2.0, w, h, near, far, p.stem, where
            )
        )

    train, test = llff_split(n, views)
    return build_scene(
        root,
        "llff",
        cameras,
        paths,
        train,
        test,
        image_scale=image_scale,
        white_background=False,
        depth_paths=depth_paths,
    )

"""DTU scenes in the IDR/NeuS layout: ``images_4/``, ``mask_4/``, ``cameras_sphere.npz``.

``world_mat_i`` is the 3x4 (stored 4x4) projection K[R|t] for the ORIGINAL
1600x1200 pixels; ``scale_mat_i`` maps the unit sphere around the object to
world coordinates. We decompose ``P = world_mat @ scale_mat`` so that the scene
lives in the normalised frame (object inside the unit sphere). IDR's K comes
from an OpenCV-style calibration with integer pixel centres, so 0.5 is added
to (cx, cy) at full resolution before K is scaled to the stored image size.
near/far = distance of the camera centre from the origin -/+ 1 (near >= 0.05).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..scene import DataError, SceneData
from ..splits import Views, dtu_split
from .common import (
    build_scene,
    check_same_size,
    choose_image_dir,
    decoded_size,
    find_images,
    image_folders,
    make_camera,
)

FULL_W, FULL_H = 1600, 1200
MIN_NEAR = 0.05


def decompose_projection(P: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P [3, 4] -> (K [3, 3] with K[2, 2] = 1 and positive focals, R world-to-camera, centre C)."""
    import cv2

    P = np.asarray(P, dtype=np.float64)
    M = P[:, :3]
    det = np.linalg.det(M)
    if not (np.isfinite(P).all() and abs(det) > 1e-12 * max(1.0, np.abs(M).max() ** 3)):
        raise DataError(f"{where}: degenerate projection matrix (singular or non-finite)")
    P = P * np.sign(det)  # so that K R has a positive determinant
    try:
        K, R, _t, *_ = cv2.decomposeProjectionMatrix(P)
    except cv2.error:
        raise DataError(f"{where}: cannot decompose projection matrix") from None
    K = K / K[2, 2]
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    C = -np.linalg.solve(M * np.sign(det), P[:, 3])
    return K, R, C


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:  # noqa: BLE001 - any read failure is bad input
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise DataError(f"{path}: cannot read .npz file ({msg})") from None


def _mat(cams: dict, key: str, path: Path, default: np.ndarray | None = None) -> np.ndarray:
    if key not in cams:
        if default is not None:
            return default
        raise DataError(f"{path}: missing '{key}'")
    m = cams[key]
    if m.dtype.kind not in "fiu" or m.shape not in ((4, 4), (3, 4)):
        raise DataError(f"{path}: '{key}' must be a 4x4 numeric matrix, got {m.dtype} {list(m.shape)}")
    m = m.astype(np.float64)
    if not np.isfinite(m).all():
        raise DataError(f"{path}: '{key}' has non-finite values")
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    return m


def load_dtu(root: Path, *, views: Views = "all", downscale: float | None = None) -> SceneData:
    cam_path = root / "cameras_sphere.npz"
    cams = _load_npz(cam_path)

    default = 4.0 if 4 in image_folders(root) else None
    folder, image_scale, factor = choose_image_dir(root, downscale, default)
    paths = find_images(folder)
    n = len(paths)
    stored = check_same_size(paths)
    w, h = decoded_size(stored, image_scale)

    mask_paths = None
    masks = image_folders(root, "mask")
    if masks:
        usable = [g for g in masks if g <= factor + 1e-9] or list(masks)
        mfolder = masks[max(usable)]
        mask_paths = find_images(mfolder)
        if len(mask_paths) != n:
            raise DataError(f"{mfolder}: {len(mask_paths)} masks but {n} images in {folder.name}/")
    else:
        warnings.warn(f"{root}: no mask folder; DTU metrics will not be masked", stacklevel=3)

    sx, sy = w / FULL_W, h / FULL_H
    cameras = []
    for i, p in enumerate(paths):
        where = f"{cam_path}: camera {i} ({p.name})"
        world = _mat(cams, f"world_mat_{i}", cam_path)
        scale = _mat(cams, f"scale_mat_{i}", cam_path, default=np.eye(4))
        K, R_w2c, C = decompose_projection((world @ scale)[:3, :4], where)
        fx, fy = K[0, 0] * sx, K[1, 1] * sy
        cx, cy = (K[0, 2] + 0.5) * sx, (K[1, 2] + 0.5) * sy
        dist = float(np.linalg.norm(C))
        near, far = max(dist - 1.0, MIN_NEAR), dist + 1.0
        cameras.append(make_camera(R_w2c.T, C, fx, fy, cx, cy, w, h, near, far, p.stem, where))

    train, test = dtu_split(n, views)
    return build_scene(
        root,
        "dtu",
        cameras,
        paths,
        train,
        test,
        image_scale=image_scale,
        white_background=False,
        mask_paths=mask_paths,
        masked_metrics=mask_paths is not None,
        dark_backdrop=True,
        content_box=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)),
    )

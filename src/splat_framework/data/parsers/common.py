"""Helpers shared by the dataset parsers: validation, camera construction,
image-folder choice and the scene extent."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ...cameras import Camera
from ..images import list_images, read_image_size, scaled_size
from ..scene import DataError, SceneData
from ..undistort import Lens, LensModel, Undistortion, undistortion

ROTATION_TOL = 2e-3
DEFAULT_BOUNDS = (0.01, 100.0)
"""near/far of a camera whose scene gives no depth range to go by."""


def check_downscale(downscale: float | None, where: Path) -> float | None:
    if downscale is None:
        return None
    try:
        f = float(downscale)
    except (TypeError, ValueError):
        raise DataError(f"{where}: --downscale must be a number, got {downscale!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise DataError(f"{where}: --downscale must be a positive number, got {downscale!r}")
    return f


def image_folders(root: Path, prefix: str = "images") -> dict[int, Path]:
    """Existing ``{prefix}`` (factor 1) and ``{prefix}_G`` folders, by factor G."""
    found: dict[int, Path] = {}
    if (root / prefix).is_dir():
        found[1] = root / prefix
    pat = re.compile(rf"^{re.escape(prefix)}_(\d+)$")
    if root.is_dir():
        for p in root.iterdir():
            m = pat.match(p.name)
            if m and p.is_dir() and int(m.group(1)) > 0:
                found.setdefault(int(m.group(1)), p)
    return found


def choose_image_dir(
    root: Path, downscale: float | None, default: float | None, prefix: str = "images"
) -> tuple[Path, float, float]:
    """Pick the image folder for a downscale factor F relative to full resolution.

    Uses ``{prefix}_F`` when it exists; otherwise the folder with the largest
    factor G <= F (``{prefix}`` counts as G = 1), resized on load by G / F.

    Returns:
        (folder, image_scale, F)
    """
    folders = image_folders(root, prefix)
    if not folders:
        raise DataError(f"{root}: no '{prefix}/' or '{prefix}_N/' image folder")
    f = check_downscale(downscale, root)
    if f is None:
        f = default if default is not None else (1.0 if 1 in folders else float(min(folders)))
    usable = [g for g in folders if g <= f + 1e-9]
    if not usable:
        names = ", ".join(sorted(p.name for p in folders.values()))
        raise DataError(
            f"{root}: downscale {f:g} needs '{prefix}/' or '{prefix}_N/' with N <= {f:g} (found {names})"
        )
    g = max(usable)
    check_decoded_size(folders[g], g, f)
    return folders[g], g / f, f


def check_decoded_size(folder: Path, stored: float, downscale: float) -> None:
    """One line naming ``--downscale`` when it would decode ``folder``'s images (stored at factor
    ``stored``) to less than one pixel a side (the first image's header tells their size)."""
    images = list_images(folder)
    if not images or downscale <= stored:
        return
    w, h = read_image_size(images[0])
    if min(w, h) * stored / downscale < 1:
        raise DataError(f"--downscale {downscale:g}: {images[0]} ({w}x{h}) would be decoded to less than one pixel; "
                        f"at most {min(w, h) * stored:g} for this dataset")


def check_same_size(paths: Sequence[Path]) -> tuple[int, int]:
    """Stored (width, height) shared by all images (header reads only)."""
    if not paths:
        raise DataError("no images")
    first = read_image_size(paths[0])
    for p in paths[1:]:
        s = read_image_size(p)
        if s != first:
            raise DataError(
                f"{p}: image size {s[0]}x{s[1]} differs from {paths[0].name} ({first[0]}x{first[1]}); mixed image sizes"
            )
    return first


def find_images(folder: Path) -> list[Path]:
    """The images of ``folder`` sorted by plain name: LLFF's ``poses_bounds.npy`` rows and DTU's
    ``world_mat_i`` follow that order (the reference code sorts names so), so natural order would
    pair photos with other photos' poses where names are not zero-padded."""
    paths = list_images(folder, natural=False)
    if not paths:
        raise DataError(f"{folder}: no image files in folder")
    return paths


def pixel_ratios(decoded: tuple[int, int], stated: tuple[float, float], where: str, stated_by: str) -> tuple[float, float]:
    """(sx, sy): decoded image pixels per pixel of the camera size a dataset states; a DataError
    naming ``where`` when the two aspect ratios differ by more than 2 % (``stated_by``: who states
    the size, e.g. "poses give")."""
    (w, h), (W, H) = decoded, stated
    sx, sy = w / W, h / H
    if abs(sx - sy) > 0.02 * max(sx, sy):
        raise DataError(f"{where}: image is {w}x{h} but {stated_by} {W:g}x{H:g} (aspect ratios differ)")
    return sx, sy


def check_finite(a: np.ndarray, where: str) -> None:
    if not np.isfinite(a).all():
        raise DataError(f"{where}: non-finite values (nan/inf)")


def clean_rotation(R: np.ndarray, where: str) -> np.ndarray:
    """Check that ``R`` is a proper rotation (orthonormal, det +1) and re-orthonormalise it."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise DataError(f"{where}: rotation is not a finite 3x3 matrix")
    with np.errstate(all="ignore"):
        err = np.abs(R.T @ R - np.eye(3)).max()
    if not err < ROTATION_TOL:
        raise DataError(f"{where}: degenerate pose, rotation is not orthonormal (|R^T R - I| = {err:.3g})")
    if np.linalg.det(R) < 0:
        raise DataError(f"{where}: degenerate pose, rotation is a reflection (det < 0)")
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def check_intrinsics(fx: float, fy: float, cx: float, cy: float, width: int, height: int, where: str) -> None:
    """A DataError naming ``where`` unless the intrinsics are finite, the focal lengths positive and
    the size not empty."""
    if not np.isfinite(np.array([fx, fy, cx, cy], dtype=np.float64)).all():
        raise DataError(f"{where}: non-finite intrinsics")
    if not (fx > 1e-6 * width and fy > 1e-6 * height):
        raise DataError(f"{where}: focal length must be positive and non-degenerate (fx={fx:g}, fy={fy:g})")
    if width < 1 or height < 1:
        raise DataError(f"{where}: image size {width}x{height} is empty")


def pinhole_intrinsics(
    fx: float, fy: float, cx: float, cy: float, size: tuple[int, int], model: LensModel | None,
    coeffs: Sequence[float], where: str,
) -> tuple[tuple[float, float, float, float, int, int], Undistortion | None]:
    """((fx, fy, cx, cy, width, height), undistortion) of the pinhole camera whose images are decoded
    at ``size`` with the stated intrinsics (decoded pixels): as stated where the lens is a pinhole one
    (``model`` None, or "perspective" with every coefficient 0), else those of the undistorted image
    (:func:`~splat_framework.data.undistort.undistortion`; ``coeffs`` in OpenCV's order)."""
    if model is None or (model == "perspective" and not any(coeffs)):
        return (fx, fy, cx, cy, *size), None
    check_intrinsics(fx, fy, cx, cy, *size, where)
    u = undistortion(Lens(model, float(fx), float(fy), float(cx), float(cy), tuple(map(float, coeffs)), size), where)
    return (u.fx, u.fy, u.cx, u.cy, *u.size), u


def make_camera(
    R_c2w: np.ndarray,
    center: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    near: float,
    far: float,
    name: str,
    where: str,
) -> Camera:
    """Build an OpenCV-convention Camera from a camera-to-world rotation and centre.

    ``cx, cy`` must already be in the +0.5 pixel-centre convention.
    """
    R = clean_rotation(R_c2w, where)
    c = np.asarray(center, dtype=np.float64).reshape(3)
    if not np.isfinite(c).all():
        raise DataError(f"{where}: camera centre is not finite")
    check_intrinsics(fx, fy, cx, cy, width, height, where)
    if not (math.isfinite(near) and math.isfinite(far) and near > 0 and far > near):
        raise DataError(f"{where}: invalid near/far bounds ({near:g}, {far:g}); need 0 < near < far")
    w2c = np.eye(4)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ c
    if not (np.abs(w2c).max() < 1e30 and max(abs(fx), abs(fy), abs(cx), abs(cy), far) < 1e30):
        raise DataError(f"{where}: pose or intrinsics out of range (|value| >= 1e30)")
    K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float32)
    return Camera(
        K=K,
        world_to_cam=torch.from_numpy(w2c).to(torch.float32),
        width=int(width),
        height=int(height),
        near=float(near),
        far=float(far),
        name=name,
    )


def decoded_size(stored: tuple[int, int], image_scale: float) -> tuple[int, int]:
    return scaled_size(stored[0], stored[1], image_scale)


def scene_extent(cameras: Sequence[Camera], indices: Sequence[int]) -> tuple[tuple[float, float, float], float]:
    """3DGS's ``cameras_extent`` over the given (training) cameras.

    centre = mean camera centre; radius = 1.1 * max distance of a centre from
    it. A single camera (radius 0) falls back to 1.1 * its mean near bound
    (or 1.0).
    """
    idx = list(indices) or list(range(len(cameras)))
    centers = np.stack([cameras[i].center.double().numpy() for i in idx])
    mean = centers.mean(axis=0)
    radius = 1.1 * float(np.linalg.norm(centers - mean, axis=1).max())
    if not (radius > 1e-6 and math.isfinite(radius)):
        near = float(np.mean([cameras[i].near for i in idx]))
        radius = 1.1 * near if near > 1e-6 and math.isfinite(near) else 1.0
    return (float(mean[0]), float(mean[1]), float(mean[2])), radius


def build_scene(root, format: str, cameras, image_paths, train: list[int], test: list[int], **fields) -> SceneData:
    """The SceneData every parser returns, with the scene extent derived from the training cameras."""
    center, radius = scene_extent(cameras, train)
    return SceneData(
        root=root, format=format, cameras=cameras, image_paths=image_paths,
        train_indices=train, test_indices=test, scene_center=center, scene_radius=radius, **fields,
    )

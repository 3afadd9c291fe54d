"""nerfstudio / instant-ngp scenes: one ``transforms.json`` beside the images.

Its ``frames`` hold ``file_path`` (relative to the folder) and ``transform_matrix``
(camera-to-world in OpenGL axes, read as Blender's: :mod:`.blender`). The intrinsics are
``fl_x``, ``fl_y``, ``cx``, ``cy`` in pixels of a ``w`` x ``h`` image (nerfstudio copies them from
COLMAP, whose pixel centres are at +0.5 like ours, so the principal point is used as stored), each
read from the frame where the frame has it (nerfstudio's per-frame intrinsics, e.g. several
cameras of one size), else from the top level; or ``camera_angle_x`` (and ``camera_angle_y``) with
the principal point at the centre. Lens distortion is removed as the images are decoded
(:mod:`~..undistort`): the coefficients ``k1``, ``k2``, ``k3``, ``p1``, ``p2`` (at the top level or
in a frame) of a perspective ``camera_model``, and ``k1`` ... ``k4`` of ``OPENCV_FISHEYE`` (or
instant-ngp's ``is_fisheye``), all four required; panoramic cameras are refused. Frames are taken in natural order of their paths and
split as a COLMAP scene is (:func:`~..splits.own_scene_split`: every 8th held out); images
are decoded at full resolution unless ``--downscale`` says otherwise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataparsers import TRANSFORMS
from ..images import natural_key
from ..scene import DataError, SceneData
from ..splits import Views, own_scene_split
from .blender import (
    camera_angle,
    focal_length,
    frame_image,
    frame_name,
    number,
    opencv_camera_to_world,
    read_json_object,
    transform_frames,
)
from .common import (
    DEFAULT_BOUNDS,
    build_scene,
    check_downscale,
    check_same_size,
    clean_rotation,
    decoded_size,
    make_camera,
    pinhole_intrinsics,
    pixel_ratios,
)

PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
"""nerfstudio's ``camera_model`` values of perspective lenses (OpenCV's model: k1, k2, k3, p1, p2)."""
FISHEYE_MODEL = "OPENCV_FISHEYE"
"""nerfstudio's ``camera_model`` of a fisheye lens (OpenCV's model: k1, k2, k3, k4)."""
DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
LENS_KEYS = {"perspective": ("k1", "k2", "p1", "p2", "k3"), "fisheye": ("k1", "k2", "k3", "k4")}
"""The keys of each lens model's coefficients, in OpenCV's order."""
PER_FRAME = ("fl_x", "fl_y", "cx", "cy", "w", "h", *DISTORTION)
"""The keys a frame may give for itself (as nerfstudio's parser reads them), over the top level's."""
MIN_CONVERGENCE = 1e-3
"""Least mean squared sine between the optical axes and their common direction for them to meet
in a point the cameras look at (below it they are parallel: a forward-facing capture)."""


def load_transforms(root: Path, *, views: Views = "all", downscale: float | None = None) -> SceneData:
    """Parse the ``transforms.json`` scene in folder ``root`` (see the module docstring)."""
    path = root / TRANSFORMS
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    meta = read_json_object(path)
    entries = sorted(zip(transform_frames(meta, path), meta["frames"]), key=lambda e: natural_key(e[0][0]))
    frames = [frame for frame, _ in entries]
    own = [{k: raw[k] for k in PER_FRAME if k in raw} for _, raw in entries]  # each frame's own intrinsics
    f = check_downscale(downscale, root)
    image_scale = 1.0 / (1.0 if f is None else f)
    paths = [frame_image(root, fp, path) for fp, _ in frames]
    stored = check_same_size(paths)
    w, h = decoded_size(stored, image_scale)
    names = [f"{path}: frame {fp!r}" for fp, _ in frames]  # how errors name each frame
    model = _lens_model(meta, path)
    c2ws = [opencv_camera_to_world(m) for _, m in frames]
    for c2w, where in zip(c2ws, names):  # a zero or NaN rotation: one line, before the bounds use its axis
        clean_rotation(c2w[:3, :3], where)
    near, far = _depth_bounds(c2ws)
    per_frame = any(own)  # else the intrinsics are global: an error about them names the file
    cameras, undistort = [], []
    for values, c2w, name, where in zip(own, c2ws, _camera_names(paths, root), names):
        stated_by = where if per_frame else str(path)
        fx, fy, cx, cy, width, height = _intrinsics({**meta, **values}, stated_by, stored)
        sx, sy = pixel_ratios((w, h), (width, height), stated_by, "its w, h give")
        pinhole, u = pinhole_intrinsics(fx * sx, fy * sy, cx * sx, cy * sy, (w, h), model,
                                        _coefficients({**meta, **values}, model, stated_by), stated_by)
        cameras.append(make_camera(c2w[:3, :3], c2w[:3, 3], *pinhole, near, far, name, where))
        undistort.append(u)
    train, test = own_scene_split(len(cameras), views)
    return build_scene(root, "transforms", cameras, paths, train, test, image_scale=image_scale,
                       undistort=undistort if any(undistort) else None)


def _intrinsics(meta: dict, path: str, stored: tuple[int, int]) -> tuple[float, float, float, float, float, float]:
    """(fx, fy, cx, cy, width, height) of a camera as ``meta`` (the top level with one frame's own
    keys over it; ``path`` names it in errors) states it: from ``fl_x`` (``fl_y``, ``cx``, ``cy``,
    ``w``, ``h`` default to ``fl_x``, the centre and the stored image size), else from
    ``camera_angle_x`` (``camera_angle_y``) over the stored size."""

    def value(key: str, default: float) -> float:
        return number(meta[key], f"{path}: {key}") if key in meta else default

    if "fl_x" in meta:
        width, height = value("w", stored[0]), value("h", stored[1])
        if not (width > 0 and height > 0):
            raise DataError(f"{path}: image size w={width:g}, h={height:g} must be positive")
        fx = value("fl_x", 0.0)
        return fx, value("fl_y", fx), value("cx", width / 2), value("cy", height / 2), width, height
    angle_x = camera_angle(meta, path)
    if angle_x is None:
        raise DataError(f"{path}: no intrinsics (fl_x, fl_y, cx, cy, w, h at the top level or in the frame, "
                        "or camera_angle_x)")
    width, height = stored
    fx = focal_length(width, angle_x)
    angle_y = camera_angle(meta, path, "camera_angle_y")
    fy = fx if angle_y is None else focal_length(height, angle_y)
    return fx, fy, width / 2, height / 2, width, height


def _lens_model(meta: dict, path: Path) -> str:
    """"perspective" or "fisheye": the lens model of ``camera_model`` (or instant-ngp's ``is_fisheye``);
    a DataError for a panoramic one."""
    model = meta.get("camera_model", "PINHOLE")
    if model == FISHEYE_MODEL or meta.get("is_fisheye") is True:
        return "fisheye"
    if model not in PERSPECTIVE_MODELS:
        raise DataError(f"{path}: camera_model {model!r} is not supported "
                        f"(use {', '.join(PERSPECTIVE_MODELS)} or {FISHEYE_MODEL})")
    return "perspective"


def _coefficients(meta: dict, model: str, where: str) -> tuple[float, ...]:
    """The distortion coefficients of one camera (``meta``: the top level with its frame's keys over
    it; ``where`` names it in errors) in OpenCV's order for lens ``model``: a perspective lens's
    missing ones are 0; a fisheye lens needs all four, and neither takes the other's coefficients."""
    keys = LENS_KEYS[model]
    values = {k: number(meta[k], f"{where}: {k}") for k in DISTORTION if k in meta}
    foreign = [k for k in DISTORTION if k not in keys and values.get(k, 0.0) != 0.0]
    if foreign:
        kind, lens = (("perspective", "a fisheye lens") if model == "fisheye" else
                      ("fisheye", f"a perspective lens (camera_model {meta.get('camera_model', 'PINHOLE')})"))
        many = len(foreign) > 1
        raise DataError(f"{where}: {', '.join(foreign)} {'are' if many else 'is a'} {kind} coefficient{'s' if many else ''}; "
                        f"{lens} has none")
    missing = [k for k in keys if k not in values]
    if model == "fisheye" and missing:
        raise DataError(f"{where}: a fisheye lens needs k1, k2, k3 and k4 (missing {', '.join(missing)})")
    return tuple(values.get(k, 0.0) for k in keys)


def _depth_bounds(c2ws: list[np.ndarray]) -> tuple[float, float]:
    """near/far of every camera, which transforms.json does not record: around the point the
    cameras look at (the least-squares point nearest to every optical axis), seen at depths z,
    near = z_min / 2 and far = 1.5 z_max (Blender's 2 and 6 at radius 4); where the axes do not
    meet in front of every camera (parallel axes: a forward-facing capture), :data:`DEFAULT_BOUNDS`."""
    centers = np.stack([m[:3, 3] for m in c2ws])
    axes = np.stack([m[:3, 2] / np.linalg.norm(m[:3, 2]) for m in c2ws])  # OpenCV: the camera looks down +z
    projectors = np.eye(3) - axes[:, :, None] * axes[:, None, :]
    a = projectors.sum(0)
    if np.linalg.eigvalsh(a)[0] < MIN_CONVERGENCE * len(c2ws):
        return DEFAULT_BOUNDS
    target = np.linalg.solve(a, np.einsum("nij,nj->i", projectors, centers))
    z = ((target - centers) * axes).sum(1)
    if not (z > 0).all():
        return DEFAULT_BOUNDS
    return 0.5 * float(z.min()), 1.5 * float(z.max())


def _camera_names(paths: list[Path], root: Path) -> list[str]:
    """The images' stems, or, where two share one, their paths relative to ``root`` joined by "_"."""
    stems = [p.stem for p in paths]
    if len(set(stems)) == len(stems):
        return stems
    return [frame_name(p, root) for p in paths]

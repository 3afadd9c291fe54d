"""NeRF-synthetic ("Blender") scenes: ``transforms_{train,test,val}.json`` (val: validation views).

Camera-to-world matrices are OpenGL (x right, y up, looking down -z) and are
converted with ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``. Focal length comes
from ``camera_angle_x`` and the stored image width; images are RGBA,
composited on white, and downscaled x2 by default (400x400 for 800x800).
near/far are the standard NeRF bounds 2 and 6.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from ..images import IMAGE_SUFFIXES, check_image_file
from ..scene import DataError, SceneData
from ..splits import BLENDER_TEST_EVERY, Views, blender_split
from .common import build_scene, check_downscale, check_same_size, decoded_size, make_camera

NEAR, FAR = 2.0, 6.0
FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def read_json_object(path: Path) -> dict:
    """The top-level JSON object of ``path`` (a one-line DataError naming the file otherwise)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not UTF-8 text") from None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise DataError(f"{path}: malformed JSON ({e.msg} at line {e.lineno})") from None
    except RecursionError:
        raise DataError(f"{path}: malformed JSON (nested too deeply)") from None
    if not isinstance(meta, dict):
        raise DataError(f"{path}: expected a JSON object at the top level")
    return meta


def number(value: object, where: str) -> float:
    """``value`` as a finite float (a DataError naming ``where`` otherwise)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(f"{where}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise DataError(f"{where}: non-finite value {v}")
    return v


def _matrix(value: object, where: str) -> np.ndarray:
    if not isinstance(value, list):
        raise DataError(f"{where}: transform_matrix must be a 4x4 list of numbers")
    rows = []
    for r in value:
        if not isinstance(r, list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in r):
            raise DataError(f"{where}: transform_matrix must be a 4x4 list of numbers")
        rows.append(r)
    if len(rows) not in (3, 4) or any(len(r) != 4 for r in rows):
        lens = sorted({len(r) for r in rows})
        raise DataError(f"{where}: transform_matrix must be 4x4, got {len(rows)} rows of length {lens}")
    m = np.eye(4)
    m[: len(rows)] = np.array(rows, dtype=np.float64)
    if not np.isfinite(m).all():
        raise DataError(f"{where}: transform_matrix has non-finite values")
    if len(rows) == 4 and not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise DataError(f"{where}: transform_matrix last row must be [0, 0, 0, 1]")
    return m


def camera_angle(meta: dict, path: Path, key: str = "camera_angle_x") -> float | None:
    """The field of view ``key`` of transforms file ``path`` (radians, in (0, pi)); None when absent."""
    if key not in meta:
        return None
    angle = number(meta[key], f"{path}: {key}")
    if not 0.0 < angle < math.pi:
        raise DataError(f"{path}: {key} must be in (0, pi) radians, got {angle:g}")
    return angle


def transform_frames(meta: dict, path: Path) -> list[tuple[str, np.ndarray]]:
    """The frames of transforms file ``path`` (NeRF's, instant-ngp's, nerfstudio's) whose object is
    ``meta``: (file_path, 4x4 camera-to-world matrix in OpenGL axes) each."""
    frames = meta.get("frames")
    if frames is None:
        raise DataError(f"{path}: missing key 'frames'")
    if not isinstance(frames, list):
        raise DataError(f"{path}: 'frames' must be a list")
    if not frames:
        raise DataError(f"{path}: 'frames' is empty")
    out = []
    for i, fr in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(fr, dict):
            raise DataError(f"{where}: expected an object")
        for key in ("file_path", "transform_matrix"):
            if key not in fr:
                raise DataError(f"{where}: missing key '{key}'")
        fp = fr["file_path"]
        if not isinstance(fp, str) or not fp.strip():
            raise DataError(f"{where}: file_path must be a non-empty string")
        out.append((fp, _matrix(fr["transform_matrix"], where)))
    return out


def _frames(root: Path, split: str, required: bool) -> tuple[Path, float | None, list[tuple[str, np.ndarray]]]:
    path = root / f"transforms_{split}.json"
    if not path.is_file():
        if required:
            raise DataError(f"{path}: file not found")
        return path, None, []
    meta = read_json_object(path)
    angle = camera_angle(meta, path)
    return path, angle, transform_frames(meta, path)


def frame_image(root: Path, file_path: str, listed_in: Path) -> Path:
    """The image file a frame's ``file_path`` names (relative to ``root``; Blender's lack the
    ``.png``); a DataError naming the transforms file ``listed_in`` when it does not exist."""
    rel = file_path.strip()
    while rel.startswith("./"):
        rel = rel[2:]
    p = root / rel
    if p.suffix.lower() not in IMAGE_SUFFIXES:
        p = p.with_name(p.name + ".png")
    check_image_file(p, f"file_path {file_path!r} in {listed_in.name}")
    return p


def relative_image(p: Path, root: Path) -> Path:
    """Image path ``p`` relative to the dataset folder ``root`` (its name alone when outside it)."""
    try:
        return p.relative_to(root)
    except ValueError:  # absolute file_path outside the dataset folder
        return Path(p.name)


def frame_name(p: Path, root: Path) -> str:
    """The camera name of image ``p``: its path relative to ``root``, without suffix, "/" as "_"."""
    return relative_image(p, root).with_suffix("").as_posix().replace("/", "_")


def focal_length(pixels: float, angle: float) -> float:
    """The focal length, in pixels, of a field of view ``angle`` (radians) across ``pixels``."""
    return 0.5 * pixels / math.tan(0.5 * angle)


def opencv_camera_to_world(m: np.ndarray) -> np.ndarray:
    """A transforms file's camera-to-world matrix (OpenGL axes) in OpenCV axes."""
    return m @ FLIP_YZ


def load_blender(root: Path, *, views: Views = "all", downscale: float | None = None) -> SceneData:
    f = check_downscale(downscale, root)
    factor = 2.0 if f is None else f
    image_scale = 1.0 / factor

    train_json, angle_tr, train_frames = _frames(root, "train", required=True)
    test_json, angle_te, test_frames = _frames(root, "test", required=False)
    val_json, angle_va, val_frames = _frames(root, "val", required=False)
    if not test_frames:
        warnings.warn(f"{test_json}: not found; the scene has no test views", stacklevel=3)
    if angle_tr is None:
        raise DataError(f"{train_json}: missing key 'camera_angle_x'")

    entries = [(train_json, angle_tr, fp, m, "train") for fp, m in train_frames]
    entries += [(test_json, angle_te if angle_te is not None else angle_tr, fp, m, "test") for fp, m in test_frames]
    entries += [(val_json, angle_va if angle_va is not None else angle_tr, fp, m, "val") for fp, m in val_frames]

    paths = [frame_image(root, fp, js) for js, _, fp, _, _ in entries]
    stored = check_same_size(paths)
    w, h = decoded_size(stored, image_scale)

    depth_root = root / "depths"
    depth_paths = None
    if depth_root.is_dir():
        depth_paths = [depth_root / relative_image(p, root).with_suffix(".npy") for p in paths]
        for d in depth_paths:
            if not d.is_file():
                raise DataError(f"{d}: depth map missing (depths/ must mirror every image path)")

    cameras = []
    for i, ((js, angle, fp, m, _split), p) in enumerate(zip(entries, paths)):
        where = f"{js}: frame {fp!r}"
        focal_full = focal_length(stored[0], angle)
        fx = focal_full * (w / stored[0])
        fy = focal_full * (h / stored[1])
        c2w = opencv_camera_to_world(m)
        cameras.append(make_camera(c2w[:3, :3], c2w[:3, 3], fx, fy, w / 2.0, h / 2.0, w, h, NEAR, FAR,
                                   frame_name(p, root), where))

    n_train, n_test = len(train_frames), len(test_frames)
    train_pool = list(range(n_train))
    test_pool = list(range(n_train, n_train + n_test))
    train, test = blender_split(train_pool, test_pool, views)
    trained = set(train)
    val_pool = list(range(n_train + n_test, len(entries))) or [i for i in train_pool if i not in trained]
    return build_scene(
        root,
        "blender",
        cameras,
        paths,
        train,
        test,
        val_indices=val_pool[::BLENDER_TEST_EVERY],
        image_scale=image_scale,
        white_background=True,
        depth_paths=depth_paths,
        content_box=((-1.3, -1.3, -1.3), (1.3, 1.3, 1.3)),
        extras={"train_pool": train_pool, "test_pool": test_pool},
    )

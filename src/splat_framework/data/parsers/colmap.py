"""COLMAP sparse models (``sparse/0/``, ``sparse/`` or nerfstudio's ``colmap/sparse/0/``), binary or text.

Camera models: SIMPLE_PINHOLE and PINHOLE; the perspective SIMPLE_RADIAL, RADIAL, OPENCV and
FULL_OPENCV and the fisheye OPENCV_FISHEYE, SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE, SIMPLE_FISHEYE
and FISHEYE, whose distortion is removed as the images are decoded (:mod:`~..undistort`: each is
OpenCV's perspective or fisheye model with some coefficients 0); the others (FOV, the thin-prism,
division and EUCM models) are refused. COLMAP already puts pixel centres at +0.5 (the upper-left
pixel's centre is (0.5, 0.5)), which is our convention, so principal points are used
as stored. COLMAP poses are world-to-camera in OpenCV axes.

near/far per camera = 0.1% / 99.9% percentiles of the depths of the 3D points
that image observes (falling back to all points in front of it, then to the
global percentiles). The sparse points are returned in ``extras`` as
``points3d`` [P, 3] float32 and ``points3d_rgb`` [P, 3] uint8.
"""

from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataparsers import find_sparse_dir
from ..images import check_image_file, natural_key
from ..scene import DataError, SceneData
from ..splits import Views, own_scene_split
from .common import (
    DEFAULT_BOUNDS,
    build_scene,
    check_finite,
    check_same_size,
    choose_image_dir,
    decoded_size,
    make_camera,
    pinhole_intrinsics,
    pixel_ratios,
)

# id -> (name, number of params)
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
    12: ("SIMPLE_DIVISION", 4),
    13: ("DIVISION", 5),
    14: ("SIMPLE_FISHEYE", 3),
    15: ("FISHEYE", 4),
    16: ("EUCM", 6),
}
MODEL_PARAMS = {name: n for name, n in CAMERA_MODELS.values()}
LENSES = {
    # model: (lens model, which params give fx, fy, cx, cy, and OpenCV's coefficients: a param index or 0.0)
    "SIMPLE_PINHOLE": (None, (0, 0, 1, 2), ()),
    "PINHOLE": (None, (0, 1, 2, 3), ()),
    "SIMPLE_RADIAL": ("perspective", (0, 0, 1, 2), (3, 0.0, 0.0, 0.0, 0.0)),
    "RADIAL": ("perspective", (0, 0, 1, 2), (3, 4, 0.0, 0.0, 0.0)),
    "OPENCV": ("perspective", (0, 1, 2, 3), (4, 5, 6, 7, 0.0)),
    "FULL_OPENCV": ("perspective", (0, 1, 2, 3), (4, 5, 6, 7, 8, 9, 10, 11)),
    "OPENCV_FISHEYE": ("fisheye", (0, 1, 2, 3), (4, 5, 6, 7)),
    "SIMPLE_RADIAL_FISHEYE": ("fisheye", (0, 0, 1, 2), (3, 0.0, 0.0, 0.0)),
    "RADIAL_FISHEYE": ("fisheye", (0, 0, 1, 2), (3, 4, 0.0, 0.0)),
    "SIMPLE_FISHEYE": ("fisheye", (0, 0, 1, 2), (0.0, 0.0, 0.0, 0.0)),
    "FISHEYE": ("fisheye", (0, 1, 2, 3), (0.0, 0.0, 0.0, 0.0)),
}
"""How each supported COLMAP model reads as a pinhole camera and an OpenCV lens (COLMAP's
fisheye models are OpenCV's Kannala-Brandt one with fewer terms; SIMPLE_FISHEYE and FISHEYE are
equidistant: all four 0)."""
SUPPORTED = tuple(LENSES)
MIN_POINTS_PER_IMAGE = 16


@dataclass
class ColmapCamera:
    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    id: int
    qvec: np.ndarray  # w, x, y, z (world-to-camera)
    tvec: np.ndarray
    camera_id: int
    name: str
    point3d_ids: np.ndarray  # observed point ids (>= 0 only)


# ------------------------------------------------------------------ binary
class _Reader:
    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
        self.pos = 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise DataError(f"{self.path}: truncated binary file")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def read_array(self, dtype: str, count: int) -> np.ndarray:
        dt = np.dtype(dtype)
        size = dt.itemsize * count
        if count < 0 or self.pos + size > len(self.data):
            raise DataError(f"{self.path}: truncated binary file")
        out = np.frombuffer(self.data, dtype=dt, count=count, offset=self.pos)
        self.pos += size
        return out

    def read_cstr(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise DataError(f"{self.path}: truncated binary file (unterminated name)")
        s = self.data[self.pos : end]
        self.pos = end + 1
        try:
            return s.decode("utf-8")
        except UnicodeDecodeError:
            raise DataError(f"{self.path}: image name is not UTF-8") from None

    def count(self, what: str) -> int:
        (n,) = self.read("Q")
        if n > len(self.data):
            raise DataError(f"{self.path}: implausible {what} count {n}")
        return n


def read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(path)
    cams = {}
    for _ in range(r.count("camera")):
        cid, model_id, w, h = r.read("iiQQ")
        if model_id not in CAMERA_MODELS:
            raise DataError(f"{path}: camera {cid}: unknown camera model id {model_id}")
        name, n = CAMERA_MODELS[model_id]
        cams[cid] = ColmapCamera(cid, name, int(w), int(h), np.array(r.read("d" * n), dtype=np.float64))
    return cams


def read_images_bin(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(path)
    images = {}
    for _ in range(r.count("image")):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = r.read("idddddddi")
        name = r.read_cstr()
        n2d = r.count("point")
        pts = r.read_array(np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]), n2d)
        ids = pts["id"].astype(np.int64)
        images[iid] = ColmapImage(iid, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cid, name, ids[ids >= 0])
    return images


def read_points3d_bin(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = _Reader(path)
    n = r.count("point")
    ids = np.empty(n, np.int64)
    xyz = np.empty((n, 3), np.float64)
    rgb = np.empty((n, 3), np.uint8)
    for k in range(n):
        pid, x, y, z, cr, cg, cb, _err = r.read("QdddBBBd")
        (tl,) = r.read("Q")
        r.read_array("<i4", 2 * tl)
        ids[k] = pid
        xyz[k] = (x, y, z)
        rgb[k] = (cr, cg, cb)
    return ids, xyz, rgb


# -------------------------------------------------------------------- text
def _text_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not UTF-8 text") from None


def _parse(path: Path, lineno: int, fn, tokens: list[str]):
    try:
        return [fn(t) for t in tokens]
    except ValueError:
        raise DataError(f"{path}: line {lineno}: malformed values {' '.join(tokens)[:80]!r}") from None


def read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    cams = {}
    for i, line in enumerate(_text_lines(path), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 4:
            raise DataError(f"{path}: line {i}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
        cid, w, h = _parse(path, i, int, [tok[0], tok[2], tok[3]])
        model = tok[1]
        if model not in MODEL_PARAMS:
            raise DataError(f"{path}: line {i}: unknown camera model {model!r}")
        params = np.array(_parse(path, i, float, tok[4:]), dtype=np.float64)
        if len(params) != MODEL_PARAMS[model]:
            raise DataError(f"{path}: line {i}: {model} needs {MODEL_PARAMS[model]} params, got {len(params)}")
        cams[cid] = ColmapCamera(cid, model, w, h, params)
    return cams


def read_images_txt(path: Path) -> dict[int, ColmapImage]:
    lines = _text_lines(path)
    images = {}
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line or line.startswith("#"):
            continue
        tok = line.split(maxsplit=9)
        if len(tok) < 10:
            raise DataError(f"{path}: line {i}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        (iid,) = _parse(path, i, int, tok[:1])
        q = np.array(_parse(path, i, float, tok[1:5]))
        t = np.array(_parse(path, i, float, tok[5:8]))
        (cid,) = _parse(path, i, int, tok[8:9])
        name = tok[9].strip()
        pts_line = lines[i] if i < len(lines) else ""
        i += 1
        pt = pts_line.split()
        if len(pt) % 3:
            raise DataError(f"{path}: line {i}: POINTS2D must be triples 'X Y POINT3D_ID'")
        ids = np.array(_parse(path, i, int, pt[2::3]), dtype=np.int64)
        images[iid] = ColmapImage(iid, q, t, cid, name, ids[ids >= 0])
    return images


def read_points3d_txt(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ids, xyz, rgb = [], [], []
    for i, line in enumerate(_text_lines(path), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 8:
            raise DataError(f"{path}: line {i}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK...'")
        ids.append(_parse(path, i, int, tok[:1])[0])
        xyz.append(_parse(path, i, float, tok[1:4]))
        rgb.append(_parse(path, i, int, tok[4:7]))
    return (
        np.array(ids, dtype=np.int64),
        np.array(xyz, dtype=np.float64).reshape(-1, 3),
        np.clip(np.array(rgb, dtype=np.int64).reshape(-1, 3), 0, 255).astype(np.uint8),
    )


def read_model(sparse: Path):
    """(cameras, images, (point ids, xyz, rgb) or None), preferring binary files."""
    if (sparse / "cameras.bin").is_file():
        cams = read_cameras_bin(sparse / "cameras.bin")
        img_path = sparse / "images.bin"
        if not img_path.is_file():
            raise DataError(f"{img_path}: file not found")
        images = read_images_bin(img_path)
        pts_path = sparse / "points3D.bin"
        points = read_points3d_bin(pts_path) if pts_path.is_file() else None
    else:
        cams = read_cameras_txt(sparse / "cameras.txt")
        img_path = sparse / "images.txt"
        if not img_path.is_file():
            raise DataError(f"{img_path}: file not found")
        images = read_images_txt(img_path)
        pts_path = sparse / "points3D.txt"
        points = read_points3d_txt(pts_path) if pts_path.is_file() else None
    return cams, images, points, img_path, pts_path


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
            [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
            [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
        ]
    )


def _percentile_bounds(z: np.ndarray) -> tuple[float, float] | None:
    z = z[z > 1e-9]
    if len(z) < MIN_POINTS_PER_IMAGE:
        return None
    near, far = np.percentile(z, [0.1, 99.9])
    if not (np.isfinite(near) and np.isfinite(far) and far > near > 0):
        return None
    return float(near), float(far)


def load_colmap(root: Path, *, views: Views = "all", downscale: float | None = None) -> SceneData:
    sparse = find_sparse_dir(root)
    if sparse is None:
        raise DataError(f"{root}: no COLMAP model (sparse/0/, sparse/ or colmap/sparse/0/ with cameras.bin or .txt)")
    cams, images, points, img_file, pts_file = read_model(sparse)
    cam_file = sparse / ("cameras.bin" if (sparse / "cameras.bin").is_file() else "cameras.txt")
    if not images:
        raise DataError(f"{img_file}: no registered images")

    folder, image_scale, _ = choose_image_dir(root, downscale, None)
    entries = sorted(images.values(), key=lambda im: natural_key(im.name))  # 9 before 18: the split follows this order
    paths = [folder / im.name for im in entries]
    for p in paths:
        check_image_file(p, f"listed in {img_file.name}")
    stored = check_same_size(paths)
    w, h = decoded_size(stored, image_scale)

    if points is not None:
        pids, xyz, rgb = points
        check_finite(xyz, f"{pts_file}")
        order = np.argsort(pids, kind="stable")
        sorted_ids = pids[order]
    else:
        warnings.warn(f"{pts_file}: not found; near/far fall back to defaults and no sparse points", stacklevel=3)
        xyz = np.zeros((0, 3))
        rgb = np.zeros((0, 3), np.uint8)
        order = sorted_ids = np.zeros(0, np.int64)

    poses = []
    for im in entries:
        where = f"{img_file}: image {im.name!r}"
        if im.camera_id not in cams:
            raise DataError(f"{where}: refers to camera {im.camera_id}, missing from {cam_file.name}")
        cam = cams[im.camera_id]
        if cam.model not in SUPPORTED:
            raise DataError(
                f"{cam_file}: camera {cam.id}: model {cam.model} is not supported "
                f"(use {', '.join(SUPPORTED)}; undistort with COLMAP's image_undistorter first)"
            )
        if not np.isfinite(cam.params).all():
            raise DataError(f"{cam_file}: camera {cam.id}: non-finite parameters ({' '.join(f'{p:g}' for p in cam.params)})")
        if not np.isfinite(im.qvec).all() or not np.isfinite(im.tvec).all():
            raise DataError(f"{where}: non-finite pose")
        qn = np.linalg.norm(im.qvec)
        if not 0.5 < qn < 2.0:
            raise DataError(f"{where}: degenerate pose, quaternion norm {qn:g}")
        R = qvec_to_rotmat(im.qvec)
        poses.append((R, im.tvec.astype(np.float64), cam))

    # global depth bounds over all points in front of any camera
    all_z = [(xyz @ R.T + t)[:, 2] for R, t, _ in poses] if len(xyz) else []
    glob = _percentile_bounds(np.concatenate(all_z)) if all_z else None
    if glob is None:
        glob = DEFAULT_BOUNDS
        if len(xyz):
            warnings.warn(f"{pts_file}: too few points in front of the cameras; near/far default to 0.01/100", stacklevel=3)

    cameras, undistort = [], []
    for (R, t, cam), im, p, z_all in zip(poses, entries, paths, all_z or [None] * len(poses)):
        where = f"{img_file}: image {im.name!r}"
        bounds = None
        if len(sorted_ids) and len(im.point3d_ids):
            pos = np.clip(np.searchsorted(sorted_ids, im.point3d_ids), 0, len(sorted_ids) - 1)
            rows = order[pos[sorted_ids[pos] == im.point3d_ids]]
            if len(rows):
                bounds = _percentile_bounds((xyz[rows] @ R.T + t)[:, 2])
        if bounds is None and z_all is not None:
            bounds = _percentile_bounds(z_all)
        near, far = bounds or glob
        if cam.width < 1 or cam.height < 1:
            raise DataError(f"{cam_file}: camera {cam.id}: invalid size {cam.width}x{cam.height}")
        sx, sy = pixel_ratios((w, h), (cam.width, cam.height), str(p), f"{cam_file.name} camera {cam.id} is")
        lens, (fx, fy, cx, cy), coeffs = _lens(cam)
        pinhole, u = pinhole_intrinsics(fx * sx, fy * sy, cx * sx, cy * sy, (w, h), lens, coeffs,
                                        f"{cam_file}: camera {cam.id}")
        center = -R.T @ t
        cameras.append(
            make_camera(
                R.T, center, *pinhole, near, far, Path(im.name).with_suffix("").as_posix().replace("/", "_"), where,
            )
        )
        undistort.append(u)

    train, test = own_scene_split(len(cameras), views)
    return build_scene(
        root,
        "colmap",
        cameras,
        paths,
        train,
        test,
        image_scale=image_scale,
        undistort=undistort if any(undistort) else None,
        extras={"points3d": xyz.astype(np.float32), "points3d_rgb": rgb},
    )


def _lens(cam: ColmapCamera) -> tuple[str | None, tuple[float, float, float, float], tuple[float, ...]]:
    """(lens model or None for a pinhole, (fx, fy, cx, cy), OpenCV's coefficients) of a supported camera."""
    lens, (ifx, ify, icx, icy), coeffs = LENSES[cam.model]
    p = cam.params
    return lens, (p[ifx], p[ify], p[icx], p[icy]), tuple(float(p[c]) if isinstance(c, int) else c for c in coeffs)

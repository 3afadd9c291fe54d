"""Parsers on tiny datasets written into tmp_path (LLFF, Blender, DTU, COLMAP).

The ``make_*`` builders are also imported by the other data tests.
"""

from __future__ import annotations

import json
import math
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from splat_framework.data import DataError, load_scene
from splat_framework.data.parsers import detect_format
from splat_framework.data.parsers.dtu import decompose_projection

# ---------------------------------------------------------------- builders


def look_at(eye, target, up) -> torch.Tensor:
    """[4, 4] float64 OpenCV world-to-camera with ``up`` appearing upwards in the image.

    (Local on purpose: the tests must not share a bug with the code under test.)
    """
    eye, target, up = (torch.as_tensor(a, dtype=torch.float64) for a in (eye, target, up))
    fwd = (target - eye) / (target - eye).norm()
    right = torch.linalg.cross(fwd, up)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    R = torch.stack([right, down, fwd])
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def write_png(path: Path, w: int, h: int, *, seed: int = 0, rgba: bool = False) -> np.ndarray:
    """Write a random 8-bit PNG; returns the array as stored (BGR[A])."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    arr = rng.integers(0, 256, size=(h, w, 4 if rgba else 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), arr)
    return arr


def llff_row(R_cv: np.ndarray, center, H: float, W: float, focal: float, near: float, far: float) -> np.ndarray:
    """One poses_bounds row from an OpenCV camera-to-world rotation."""
    right, down, fwd = R_cv[:, 0], R_cv[:, 1], R_cv[:, 2]
    m = np.zeros((3, 5))
    m[:, 0], m[:, 1], m[:, 2] = down, right, -fwd
    m[:, 3] = center
    m[:, 4] = [H, W, focal]
    return np.concatenate([m.reshape(-1), [near, far]])


def make_llff(
    root: Path,
    n: int = 10,
    *,
    w: int = 16,
    h: int = 12,
    full_factor: int = 8,
    folder: str = "images_8",
    focal_full: float = 100.0,
    depths: bool = False,
) -> Path:
    """Forward-facing LLFF scene: cameras on a line at z=0 looking down +z."""
    rows = []
    for i in range(n):
        rows.append(
            llff_row(np.eye(3), [0.1 * i, 0.0, 0.0], h * full_factor, w * full_factor, focal_full, 1.0 + 0.1 * i, 10.0)
        )
        write_png(root / folder / f"img{i:03d}.png", w, h, seed=i)
        if depths:
            (root / "depths").mkdir(parents=True, exist_ok=True)
            np.save(root / "depths" / f"img{i:03d}.npy", np.full((h, w), 5.0, np.float32))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return root


def gl_c2w_looking_at_origin(eye) -> np.ndarray:
    w2c_cv = look_at(torch.tensor(eye, dtype=torch.float64), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0]))
    c2w_cv = torch.linalg.inv(w2c_cv).numpy()
    return c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV -> OpenGL (its own inverse)


def make_blender(root: Path, n_train: int = 10, n_test: int = 16, *, size: int = 8, angle: float = 0.7) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    for split, n in (("train", n_train), ("test", n_test)):
        frames = []
        for i in range(n):
            a = 2 * math.pi * i / n + (0.1 if split == "test" else 0.0)
            eye = [4.0 * math.cos(a), 4.0 * math.sin(a), 1.0]
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": gl_c2w_looking_at_origin(eye).tolist()})
            write_png(root / split / f"r_{i}.png", size, size, seed=i, rgba=True)
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))
    return root


DTU_K = np.array([[2800.0, 0.0, 799.5], [0.0, 2790.0, 599.5], [0.0, 0.0, 1.0]])
DTU_SCALE = np.array([[200.0, 0, 0, 10.0], [0, 200.0, 0, -20.0], [0, 0, 200.0, 600.0], [0, 0, 0, 1]])


def dtu_eye(i: int) -> np.ndarray:
    a = 2 * math.pi * i / 49
    return np.array([3.0 * math.cos(a), 3.0 * math.sin(a), -1.0 - 0.01 * i])


def make_dtu(root: Path, n: int = 49, *, w: int = 16, h: int = 12, masks: bool = True) -> Path:
    """DTU layout whose normalised-space cameras look at the origin from ``dtu_eye(i)``."""
    mats = {}
    for i in range(n):
        w2c = look_at(torch.tensor(dtu_eye(i)), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0])).numpy()
        # world_mat @ scale_mat = K [R|t] (normalised) -> world_mat = K[R|t] @ inv(scale_mat)
        P = DTU_K @ w2c[:3]
        world = np.eye(4)
        world[:3] = P @ np.linalg.inv(DTU_SCALE)
        mats[f"world_mat_{i}"] = world * 3.7  # projective scale must not matter
        mats[f"scale_mat_{i}"] = DTU_SCALE
        write_png(root / "images_4" / f"{i:06d}.png", w, h, seed=i)
        if masks:
            m = np.zeros((h, w, 3), np.uint8)
            m[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4] = 255
            (root / "mask_4").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / "mask_4" / f"{i:03d}.png"), m)
    np.savez(root / "cameras_sphere.npz", **mats)
    return root


def _qvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> COLMAP (w, x, y, z) quaternion (no scipy needed)."""
    K = np.array(
        [
            [R[0, 0] - R[1, 1] - R[2, 2], 0, 0, 0],
            [R[1, 0] + R[0, 1], R[1, 1] - R[0, 0] - R[2, 2], 0, 0],
            [R[2, 0] + R[0, 2], R[2, 1] + R[1, 2], R[2, 2] - R[0, 0] - R[1, 1], 0],
            [R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], R[0, 0] + R[1, 1] + R[2, 2]],
        ]
    ) / 3.0
    vals, vecs = np.linalg.eigh(K)
    q = vecs[[3, 0, 1, 2], np.argmax(vals)]
    return -q if q[0] < 0 else q


COLMAP_MODELS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4}


def colmap_scene(n_images: int = 9, n_points: int = 200, seed: int = 0):
    """Cameras on a line looking down +z at random points with z in [4, 8]."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-1, 1, n_points), rng.uniform(-1, 1, n_points), rng.uniform(4, 8, n_points)])
    images = []
    for i in range(n_images):
        eye = np.array([0.2 * i - 0.8, 0.05 * i, 0.0])
        w2c = look_at(torch.tensor(eye), torch.tensor([0.0, 0.0, 6.0]), torch.tensor([0.0, -1.0, 0.0])).numpy()
        images.append((i + 1, w2c[:3, :3], w2c[:3, 3], f"frame_{i:02d}.png"))
    return pts, images


def make_colmap(
    root: Path,
    *,
    binary: bool,
    model: str = "PINHOLE",
    w: int = 16,
    h: int = 12,
    cam_w: int = 32,
    cam_h: int = 24,
    n_images: int = 9,
    sparse_sub: str = "sparse/0",
) -> Path:
    """Tiny COLMAP model (camera at 2x the stored image size) in text or binary form."""
    params = {
        "SIMPLE_PINHOLE": [30.0, 16.0, 12.0],
        "PINHOLE": [30.0, 31.0, 16.0, 12.0],
        "SIMPLE_RADIAL": [30.0, 16.0, 12.0, 0.01],
        "OPENCV": [30.0, 31.0, 16.0, 12.0, 0.01, 0.0, 0.0, 0.0],
    }[model]
    pts, images = colmap_scene(n_images)
    sparse = root / sparse_sub
    sparse.mkdir(parents=True, exist_ok=True)
    for _, _, _, name in images:
        write_png(root / "images" / name, w, h)
    # every image observes every point
    if binary:
        with open(sparse / "cameras.bin", "wb") as f:
            f.write(struct.pack("<Q", 1))
            f.write(struct.pack("<iiQQ", 1, COLMAP_MODELS[model], cam_w, cam_h))
            f.write(struct.pack("<" + "d" * len(params), *params))
        with open(sparse / "images.bin", "wb") as f:
            f.write(struct.pack("<Q", len(images)))
            for iid, R, t, name in images:
                f.write(struct.pack("<i", iid))
                f.write(struct.pack("<4d", *_qvec(R)))
                f.write(struct.pack("<3d", *t))
                f.write(struct.pack("<i", 1))
                f.write(name.encode() + b"\x00")
                f.write(struct.pack("<Q", len(pts)))
                for k in range(len(pts)):
                    f.write(struct.pack("<ddq", 1.0, 2.0, k + 1))
        with open(sparse / "points3D.bin", "wb") as f:
            f.write(struct.pack("<Q", len(pts)))
            for k, p in enumerate(pts):
                f.write(struct.pack("<Q3d3Bd", k + 1, *p, 10, 20, 30, 0.5))
                f.write(struct.pack("<Q", len(images)))
                for iid, *_ in images:
                    f.write(struct.pack("<ii", iid, k))
    else:
        (sparse / "cameras.txt").write_text(
            "# Camera list\n" + f"1 {model} {cam_w} {cam_h} " + " ".join(map(str, params)) + "\n"
        )
        lines = ["# Image list", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"]
        for iid, R, t, name in images:
            q = _qvec(R)
            lines.append(" ".join(map(str, [iid, *q, *t, 1, name])))
            lines.append(" ".join(f"1.0 2.0 {k + 1}" for k in range(len(pts))))
        (sparse / "images.txt").write_text("\n".join(lines) + "\n")
        plines = ["# 3D point list"]
        for k, p in enumerate(pts):
            track = " ".join(f"{iid} {k}" for iid, *_ in images)
            plines.append(f"{k + 1} {p[0]} {p[1]} {p[2]} 10 20 30 0.5 {track}")
        (sparse / "points3D.txt").write_text("\n".join(plines) + "\n")
    return root


# ------------------------------------------------------------------- tests


def assert_rigid(cam):
    R = cam.world_to_cam[:3, :3].double()
    assert torch.allclose(R.T @ R, torch.eye(3, dtype=torch.float64), atol=1e-5)
    assert torch.linalg.det(R) > 0.99


def test_detect_format(tmp_path):
    assert detect_format(make_llff(tmp_path / "l", 3)) == "llff"
    assert detect_format(make_blender(tmp_path / "b", 2, 2)) == "blender"
    assert detect_format(make_dtu(tmp_path / "d", 3)) == "dtu"
    assert detect_format(make_colmap(tmp_path / "c", binary=False)) == "colmap"
    assert detect_format(make_colmap(tmp_path / "c2", binary=True, sparse_sub="sparse")) == "colmap"


def test_llff_cameras(tmp_path):
    root = make_llff(tmp_path / "scene", 10, depths=True)
    scene = load_scene(root)
    assert scene.format == "llff"
    assert scene.image_scale == 1.0  # images_8 used as stored
    assert [p.name for p in scene.image_paths] == [f"img{i:03d}.png" for i in range(10)]
    cam = scene.cameras[3]
    assert (cam.width, cam.height) == (16, 12)
    assert cam.K[0, 0].item() == pytest.approx(100.0 / 8)
    assert cam.K[1, 1].item() == pytest.approx(100.0 / 8)
    assert cam.K[0, 2].item() == pytest.approx(8.0) and cam.K[1, 2].item() == pytest.approx(6.0)
    assert (cam.near, cam.far) == (pytest.approx(1.3), pytest.approx(10.0))
    assert torch.allclose(cam.world_to_cam[:3, :3], torch.eye(3), atol=1e-6)
    assert torch.allclose(cam.center, torch.tensor([0.3, 0.0, 0.0]), atol=1e-6)
    # a point straight ahead projects to the image centre, in front of the camera
    uv, z = cam.project(torch.tensor([[0.3, 0.0, 5.0]]))
    assert torch.allclose(uv, torch.tensor([[8.0, 6.0]]), atol=1e-4) and z.item() == pytest.approx(5.0)
    assert scene.depth_paths is not None and scene.depth_paths[0].name == "img000.npy"
    assert scene.test_indices == [0, 8]
    assert scene.train_indices == [1, 2, 3, 4, 5, 6, 7, 9]


def test_llff_axis_conversion_rotated(tmp_path):
    """A rotated LLFF pose maps to the right OpenCV world-to-camera rotation."""
    ang = 0.4
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]])
    row = llff_row(R, [1.0, 2.0, 3.0], 96, 128, 100.0, 1.0, 9.0)
    root = tmp_path / "s"
    write_png(root / "images_8" / "a.png", 16, 12)
    np.save(root / "poses_bounds.npy", row[None])
    cam = load_scene(root).cameras[0]
    assert torch.allclose(cam.world_to_cam[:3, :3].double(), torch.from_numpy(R.T), atol=1e-6)
    fwd = torch.from_numpy(R[:, 2]).float()
    uv, z = cam.project((torch.tensor([1.0, 2.0, 3.0]) + 4 * fwd)[None])
    assert torch.allclose(uv, torch.tensor([[8.0, 6.0]]), atol=1e-4) and z.item() == pytest.approx(4.0, rel=1e-5)


def test_llff_downscale_resizes_full_images(tmp_path):
    root = make_llff(tmp_path / "s", 4, w=32, h=24, full_factor=1, folder="images", focal_full=40.0)
    scene = load_scene(root, downscale=2)
    assert scene.image_scale == 0.5
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (16, 12)
    assert cam.K[0, 0].item() == pytest.approx(20.0)
    # images/ only and no downscale -> full size
    assert load_scene(root).cameras[0].width == 32


def test_llff_prefers_images_f_folder(tmp_path):
    root = make_llff(tmp_path / "s", 3, w=16, h=12, full_factor=8, folder="images_8")
    make_llff(root, 3, w=32, h=24, full_factor=4, folder="images_4")
    s4 = load_scene(root, downscale=4)
    assert s4.image_paths[0].parent.name == "images_4" and s4.cameras[0].width == 32 and s4.image_scale == 1.0
    s8 = load_scene(root)
    assert s8.image_paths[0].parent.name == "images_8" and s8.cameras[0].width == 16
    s16 = load_scene(root, downscale=16)  # images_8 resized by 1/2
    assert s16.image_paths[0].parent.name == "images_8" and s16.image_scale == 0.5 and s16.cameras[0].width == 8


def test_blender_cameras(tmp_path):
    root = make_blender(tmp_path / "lego", 10, 16, size=8, angle=0.7)
    scene = load_scene(root)
    assert scene.format == "blender" and scene.white_background
    assert len(scene.cameras) == 26
    assert scene.image_scale == 0.5
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (4, 4)
    focal = 0.5 * 8 / math.tan(0.35) * 0.5
    assert cam.K[0, 0].item() == pytest.approx(focal, rel=1e-5)
    assert (cam.near, cam.far) == (2.0, 6.0)
    assert scene.content_box == ((-1.3, -1.3, -1.3), (1.3, 1.3, 1.3))  # the 3DGS reference's random-init cube
    assert scene.train_indices == list(range(10))
    assert scene.test_indices == [10, 18]  # every 8th test frame
    assert scene.cameras[10].name == "test_r_0" and scene.cameras[0].name == "train_r_0"
    for c in scene.cameras:
        assert_rigid(c)
        uv, z = c.project(torch.zeros(1, 3))  # every camera looks at the origin
        assert torch.allclose(uv, torch.tensor([[2.0, 2.0]]), atol=1e-4)
        assert z.item() == pytest.approx(math.sqrt(17.0), rel=1e-5)
    # world "up" (+z) appears upwards in the image (smaller v)
    uv, _ = scene.cameras[0].project(torch.tensor([[0.0, 0.0, 0.5]]))
    assert uv[0, 1] < 2.0
    assert load_scene(root, downscale=1).cameras[0].width == 8


def test_blender_depth_paths(tmp_path):
    root = make_blender(tmp_path / "b", 2, 2)
    for split in ("train", "test"):
        for i in range(2):
            (root / "depths" / split).mkdir(parents=True, exist_ok=True)
            np.save(root / "depths" / split / f"r_{i}.npy", np.ones((8, 8), np.float32))
    scene = load_scene(root)
    assert scene.depth_paths[3] == root / "depths" / "test" / "r_1.npy"


def test_dtu_cameras(tmp_path):
    root = make_dtu(tmp_path / "scan", 49)
    scene = load_scene(root, views=3)
    assert scene.format == "dtu" and scene.masked_metrics
    assert scene.content_box == ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))  # cameras are in the unit-sphere frame
    assert scene.train_indices == [25, 22, 28]
    assert len(scene.test_indices) == 25
    assert len(scene.mask_paths) == 49 and scene.mask_paths[0].name == "000.png"
    cam = scene.cameras[5]
    assert (cam.width, cam.height) == (16, 12)
    s = 16 / 1600
    assert cam.K[0, 0].item() == pytest.approx(2800 * s, rel=1e-5)
    assert cam.K[1, 1].item() == pytest.approx(2790 * s, rel=1e-5)
    assert cam.K[0, 2].item() == pytest.approx(800.0 * s, rel=1e-5)  # (799.5 + 0.5) * s
    assert cam.K[1, 2].item() == pytest.approx(600.0 * s, rel=1e-5)
    assert torch.allclose(cam.center.double(), torch.from_numpy(dtu_eye(5)), atol=1e-4)
    d = float(np.linalg.norm(dtu_eye(5)))
    assert cam.near == pytest.approx(d - 1, rel=1e-5) and cam.far == pytest.approx(d + 1, rel=1e-5)
    for c in scene.cameras:
        assert_rigid(c)
        uv, z = c.project(torch.zeros(1, 3))
        assert torch.allclose(uv, torch.tensor([[8.0, 6.0]]), atol=1e-3) and z.item() > 0


def test_decompose_projection_sign_invariant():
    w2c = look_at(torch.tensor([1.0, 2.0, -3.0]), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0])).numpy()
    P = DTU_K @ w2c[:3]
    for scale in (1.0, -2.5):
        K, R, C = decompose_projection(P * scale, "test")
        assert np.allclose(K, DTU_K, atol=1e-6)
        assert np.allclose(R, w2c[:3, :3], atol=1e-8)
        assert np.allclose(C, [1.0, 2.0, -3.0], atol=1e-8)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL"])
def test_colmap_text_and_binary(tmp_path, binary, model):
    root = make_colmap(tmp_path / "c", binary=binary, model=model)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        scene = load_scene(root)
    radial_warnings = [w for w in rec if "SIMPLE_RADIAL" in str(w.message)]
    assert len(radial_warnings) == (1 if model == "SIMPLE_RADIAL" else 0)
    if radial_warnings:
        assert "cameras." in str(radial_warnings[0].message)
    assert scene.format == "colmap"
    assert [p.name for p in scene.image_paths] == [f"frame_{i:02d}.png" for i in range(9)]
    _, images = colmap_scene(9)
    cam = scene.cameras[4]
    assert (cam.width, cam.height) == (16, 12)  # camera is 32x24, images are half that
    fy = 31.0 if model == "PINHOLE" else 30.0
    assert cam.K[0, 0].item() == pytest.approx(15.0) and cam.K[1, 1].item() == pytest.approx(fy / 2)
    assert cam.K[0, 2].item() == pytest.approx(8.0) and cam.K[1, 2].item() == pytest.approx(6.0)
    _, R, t, _ = images[4]
    assert np.allclose(cam.world_to_cam[:3, :3].numpy(), R, atol=1e-5)
    assert np.allclose(cam.world_to_cam[:3, 3].numpy(), t, atol=1e-5)
    for c in scene.cameras:  # every camera looks at (0, 0, 6)
        uv, z = c.project(torch.tensor([[0.0, 0.0, 6.0]]))
        assert torch.allclose(uv, torch.tensor([[8.0, 6.0]]), atol=1e-3) and z.item() > 0
    # near/far bracket the true point depths
    pts = scene.extras["points3d"]
    assert pts.shape == (200, 3) and scene.extras["points3d_rgb"][0].tolist() == [10, 20, 30]
    z = (pts @ R.T + t)[:, 2]
    assert z.min() - 1e-3 <= cam.near <= np.percentile(z, 1) and np.percentile(z, 99) <= cam.far <= z.max() + 1e-3
    assert scene.test_indices == [0, 8]


def test_colmap_text_and_binary_agree(tmp_path):
    a = load_scene(make_colmap(tmp_path / "t", binary=False))
    b = load_scene(make_colmap(tmp_path / "b", binary=True))
    for ca, cb in zip(a.cameras, b.cameras):
        assert torch.allclose(ca.K, cb.K) and torch.allclose(ca.world_to_cam, cb.world_to_cam, atol=1e-6)
        assert ca.near == pytest.approx(cb.near) and ca.far == pytest.approx(cb.far)


@pytest.mark.parametrize("binary", [False, True])
def test_colmap_unsupported_model(tmp_path, binary):
    root = make_colmap(tmp_path / "c", binary=binary, model="OPENCV")
    with pytest.raises(DataError, match="OPENCV"):
        load_scene(root)


def test_scene_extent(tmp_path):
    scene = load_scene(make_llff(tmp_path / "s", 10), views="all")
    centers = np.stack([scene.cameras[i].center.numpy() for i in scene.train_indices])
    mean = centers.mean(0)
    assert np.allclose(scene.scene_center, mean, atol=1e-6)
    assert scene.scene_radius == pytest.approx(1.1 * np.linalg.norm(centers - mean, axis=1).max(), rel=1e-5)
    one = load_scene(make_llff(tmp_path / "s1", 10), views=1)
    assert one.scene_radius > 0  # single camera -> near-based fallback


@pytest.mark.slow
@pytest.mark.parametrize("name", ["forward-tiny", "object-tiny"])
def test_matches_synthetic_generator_cameras(tmp_path, name):
    """Parsed cameras equal the exact cameras the built-in generator wrote (cameras.json)."""
    synthetic = pytest.importorskip("splat_framework.data.synthetic")
    root = synthetic.ensure_scene(name, cache_dir=tmp_path)
    scene = load_scene(root, downscale=1)
    exact = {v["image"]: v for v in json.loads((root / "cameras.json").read_text())["views"]}
    assert scene.depth_paths is not None
    for cam, path in zip(scene.cameras, scene.image_paths):
        v = exact[path.relative_to(root).as_posix()]
        assert (cam.width, cam.height) == (v["width"], v["height"])
        assert torch.allclose(cam.K, torch.tensor(v["K"], dtype=torch.float32), atol=1e-4)
        assert torch.allclose(cam.world_to_cam, torch.tensor(v["world_to_cam"], dtype=torch.float32), atol=1e-5)
        if scene.format == "llff":
            assert cam.near == pytest.approx(v["near"]) and cam.far == pytest.approx(v["far"])

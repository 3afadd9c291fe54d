"""Parsers on tiny datasets written into tmp_path (LLFF, Blender, DTU, COLMAP; builders in ``support``)."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import torch

from splat_framework.data import DataError, load_scene
from splat_framework.data.parsers import detect_format
from splat_framework.data.parsers.dtu import decompose_projection
from support import (
    DTU_K,
    colmap_scene,
    dtu_eye,
    llff_row,
    look_at,
    make_blender,
    make_colmap,
    make_dtu,
    make_llff,
    write_png,
)

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
@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_PINHOLE"])
def test_colmap_text_and_binary(tmp_path, binary, model):
    root = make_colmap(tmp_path / "c", binary=binary, model=model)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = load_scene(root)
    assert scene.format == "colmap" and scene.undistort is None
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
    root = make_colmap(tmp_path / "c", binary=binary, model="FOV")
    with pytest.raises(DataError, match=r"cameras\.(txt|bin): camera 1: model FOV is not supported"):
        load_scene(root)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("model", ["SIMPLE_RADIAL", "OPENCV"])
def test_colmap_distorted_cameras_load_undistorted_from_text_and_binary(tmp_path, binary, model):
    """A distorted camera (its images and intrinsics undistorted: tests/framework/data/test_distortion.py)
    reads the same from either file, with no warning."""
    root = make_colmap(tmp_path / "c", binary=binary, model=model)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = load_scene(root)
    u = scene.undistort[4]
    assert u.lens.model == "perspective" and u.lens.coeffs[0] == 0.01 and u.lens.size == (16, 12)
    assert u.lens.fx == pytest.approx(15.0) and (u.lens.cx, u.lens.cy) == (8.0, 6.0)  # the camera is 2x the images
    cam = scene.cameras[4]
    assert (cam.width, cam.height) == u.size and cam.K[0, 0].item() == pytest.approx(u.fx)


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


def _corrupt_pose(fmt: str, root, value: float):
    """Make one camera's rotation all ``value`` (0: singular; nan: not finite) in a ``fmt`` scene."""
    from support import make_blender, make_colmap, make_dtu, make_llff

    if fmt == "llff":
        make_llff(root)
        rows = np.load(root / "poses_bounds.npy")
        m = rows[3, :15].reshape(3, 5)
        m[:, :3] = value
        rows[3, :15] = m.reshape(-1)
        np.save(root / "poses_bounds.npy", rows)
        return root / "poses_bounds.npy"
    if fmt == "blender":
        make_blender(root)
        path = root / "transforms_train.json"
        meta = json.loads(path.read_text())
        for row in meta["frames"][2]["transform_matrix"][:3]:
            row[:3] = [value] * 3
        path.write_text(json.dumps(meta))  # NaN as JSON's NaN, as Python writes it
        return path
    if fmt == "dtu":
        make_dtu(root, n=12)
        mats = dict(np.load(root / "cameras_sphere.npz"))
        mats["world_mat_2"][:3, :3] = value
        np.savez(root / "cameras_sphere.npz", **mats)
        return root / "cameras_sphere.npz"
    make_colmap(root, binary=False)
    path = root / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    first = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    fields = lines[first].split()
    fields[1:5] = [repr(float(value))] * 4
    lines[first] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.bad_input("a camera whose rotation is all zeros or not finite, in each format (LLFF, Blender, DTU, COLMAP)",
                       "exit 2, one line naming the file and the pose")
@pytest.mark.parametrize("value", [0.0, float("nan")], ids=["zero", "nan"])
@pytest.mark.parametrize("fmt", ["llff", "blender", "dtu", "colmap"])
def test_a_zero_or_non_finite_rotation_is_one_line_naming_the_file(tmp_path, fmt, value):
    path = _corrupt_pose(fmt, tmp_path / fmt, value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy's own about the NaN; the error is what is checked
        with pytest.raises(DataError) as e:
            load_scene(tmp_path / fmt)
    message = str(e.value)
    assert "\n" not in message and path.name in message, message

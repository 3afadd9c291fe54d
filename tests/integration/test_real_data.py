"""The real scenes in ../shared/data (or $SPLAT_DATA) under the paper protocols.

Skipped with a reason when the data folder is absent (a user's machine).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from splat_framework.data import DataManager, load_scene
from support import DATA

pytestmark = pytest.mark.integration


def scene_dir(rel: str) -> Path:
    p = DATA / rel
    if not p.is_dir():
        pytest.skip(f"real dataset {rel} not found under {DATA} (set SPLAT_DATA to the shared data folder)")
    return p


def rigid(cam) -> bool:
    R = cam.world_to_cam[:3, :3].double()
    return torch.allclose(R.T @ R, torch.eye(3, dtype=torch.float64), atol=1e-5) and torch.linalg.det(R) > 0.99


def test_fern():
    scene = load_scene(scene_dir("llff/fern"), views=3)
    assert scene.format == "llff" and len(scene.cameras) == 20
    assert scene.image_paths[0].parent.name == "images_8" and scene.image_scale == 1.0
    assert scene.train_indices == [1, 10, 19] and scene.test_indices == [0, 8, 16]
    for cam in scene.cameras:
        assert (cam.width, cam.height) == (504, 378)
        assert rigid(cam)
        assert cam.K[0, 2].item() == 252.0 and cam.K[1, 2].item() == 189.0
        assert 0 < cam.near < cam.far
    # focal from poses_bounds at 4032 wide, scaled by 504 / 4032
    f_full = float(np.load(scene.root / "poses_bounds.npy")[0, 14])
    assert scene.cameras[0].K[0, 0].item() == pytest.approx(f_full / 8, rel=1e-5)
    # forward-facing: all cameras look roughly the same way; the scene centre
    # (midway between the bounds) projects inside every image
    fwd = torch.stack([c.world_to_cam[2, :3] for c in scene.cameras])
    assert (fwd @ fwd.mean(0)).min() > 0.9 * fwd.mean(0).norm() ** 2
    c0 = scene.cameras[0]
    target = c0.center + c0.world_to_cam[2, :3] * (c0.near + c0.far) / 4
    for cam in scene.cameras:
        uv, z = cam.project(target[None])
        assert z.item() > 0 and 0 < uv[0, 0] < cam.width and 0 < uv[0, 1] < cam.height
    hi = load_scene(scene.root, views=3, downscale=4)
    assert (hi.cameras[0].width, hi.cameras[0].height) == (1008, 756)
    assert hi.cameras[0].K[0, 0].item() == pytest.approx(f_full / 4, rel=1e-5)


def test_lego():
    scene = load_scene(scene_dir("blender/lego"), views=8)
    assert scene.format == "blender" and scene.white_background and scene.image_scale == 0.5
    assert len(scene.cameras) == 300
    assert scene.train_indices == [2, 16, 26, 55, 73, 76, 86, 93]
    assert scene.test_indices == list(range(100, 300, 8)) and len(scene.test_indices) == 25
    for cam in scene.cameras:
        assert (cam.width, cam.height) == (400, 400)
        assert cam.K[0, 0].item() == pytest.approx(1111.1 / 2, rel=1e-4)
        assert (cam.near, cam.far) == (2.0, 6.0)
        assert rigid(cam)
        # the object at the origin is in front, near the image centre, within the bounds
        uv, z = cam.project(torch.zeros(1, 3))
        assert 2.0 < z.item() < 6.0
        assert (uv - 200).abs().max() < 40
    dm = DataManager(scene)
    cam, batch = dm.next_train(0)
    img = batch["image"]
    assert img.shape == (400, 400, 3)
    assert float(img[:5, :5].min()) > 0.99  # background composited on white
    assert float(img[180:220, 180:220].mean()) < 0.9  # the object is there


def test_scan37():
    scene = load_scene(scene_dir("dtu/scan37"), views=3)
    assert scene.format == "dtu" and scene.masked_metrics and len(scene.cameras) == 49
    assert scene.train_indices == [25, 22, 28]
    assert scene.test_indices == [1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45, 46, 47]
    for cam in scene.cameras:
        assert (cam.width, cam.height) == (400, 300)
        assert rigid(cam)
        assert 600 < cam.K[0, 0].item() < 800  # ~2892 / 4
        uv, z = cam.project(torch.zeros(1, 3))
        assert 0 < uv[0, 0] < 400 and 0 < uv[0, 1] < 300, cam.name
        assert cam.near < z.item() < cam.far
        assert cam.near >= 0.05 and cam.far > cam.near + 1.0
    dm = DataManager(scene)
    _, batch = dm.next_train(0)
    m = batch["mask"]
    assert m.shape == (300, 400, 1) and 0.05 < float(m.mean()) < 0.95
    # the object's mask covers the projection of the sphere centre
    cam = dm.cameras[batch["index"]]
    uv, _ = cam.project(torch.zeros(1, 3))
    u, v = int(uv[0, 0]), int(uv[0, 1])
    assert m[v - 5 : v + 5, u - 5 : u + 5].mean() > 0.5
    assert len(dm.eval_views()) == 25
    assert math.isfinite(scene.scene_radius) and scene.scene_radius > 0

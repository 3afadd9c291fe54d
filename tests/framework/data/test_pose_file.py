"""Training cameras from a pose file, and pose files estimated from the training photos alone."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from splat_framework.cameras import pose_differences
from splat_framework.data import apply_pose_file, load_scene
from splat_framework.data.pose_file import pose_file_payload
from splat_framework.data.synthetic import ensure_scene
from splat_framework.errors import DataError


@pytest.fixture(scope="module")
def scene():
    return load_scene(ensure_scene("forward"), views=3)


def w2c(cameras) -> np.ndarray:
    return np.stack([c.world_to_cam.double().numpy() for c in cameras])


def shifted_payload(scene, half: bool = False, focal=lambda position: 1.1) -> dict:
    """Each training camera moved 0.1 along x and its focal length times ``focal(position)`` (+10 %),
    optionally at half the image size."""
    cams = {}
    for position, i in enumerate(scene.train_indices):
        c = scene.cameras[i].scaled(0.5) if half else scene.cameras[i]
        M = c.world_to_cam.clone()
        M[0, 3] += 0.1
        K = c.K.clone()
        K[:2, :2] *= focal(position)
        cams[i] = type(c)(K=K, world_to_cam=M, width=c.width, height=c.height, name=c.name)
    return pose_file_payload(cams, {"note": "test"})


@pytest.mark.parametrize("half", [False, True])
def test_training_cameras_are_replaced_and_nothing_else(scene, tmp_path, half):
    path = tmp_path / "poses.json"
    path.write_text(json.dumps(shifted_payload(scene, half)))
    new = apply_pose_file(scene, path)
    for i, (a, b) in enumerate(zip(scene.cameras, new.cameras)):
        if i in scene.train_indices:
            assert float(b.world_to_cam[0, 3] - a.world_to_cam[0, 3]) == pytest.approx(0.1, abs=1e-6)
            assert float(b.K[0, 0] / a.K[0, 0]) == pytest.approx(1.1, rel=1e-5)  # rescaled to the scene's size
            assert (b.width, b.height, b.name, b.near, b.far) == (a.width, a.height, a.name, a.near, a.far)
        elif i in scene.test_indices:  # photographed by the same camera: its estimated focal length, its own pose
            assert float(b.K[0, 0] / a.K[0, 0]) == pytest.approx(1.1, rel=1e-5) and b.K[0, 2] == a.K[0, 2]
            assert b.world_to_cam is a.world_to_cam and (b.width, b.name) == (a.width, a.name)
        else:
            assert b is a
    assert new.image_paths == scene.image_paths and new.scene_radius == scene.scene_radius
    assert new.extras["train_poses"] == str(path)


def test_test_views_keep_their_focal_length_when_the_training_views_disagree(scene, tmp_path):
    """Training cameras whose focal lengths changed by different factors are not one camera: the
    test views keep the dataset's intrinsics."""
    path = tmp_path / "poses.json"
    path.write_text(json.dumps(shifted_payload(scene, focal=lambda position: 1.0 + 0.05 * position)))
    new = apply_pose_file(scene, path)
    assert all(new.cameras[i] is scene.cameras[i] for i in scene.test_indices)


def test_bad_pose_files_are_one_line_errors_naming_the_file(scene, tmp_path):
    good = shifted_payload(scene)
    cases = {
        "missing.json": None,
        "notjson.json": "{nope",
        "shape.json": {"views": "x"},
        "lacking.json": {"views": good["views"][1:]},
        "name.json": {"views": [{**v, "name": "other"} for v in good["views"]]},
        "aspect.json": {"views": [{**v, "width": v["width"] * 2} for v in good["views"]]},
        "nan.json": {"views": [{**v, "K": [[float("nan")] * 3] * 3} for v in good["views"]]},
    }
    for name, payload in cases.items():
        path = tmp_path / name
        if payload is not None:
            path.write_text(payload if isinstance(payload, str) else json.dumps(payload))
        with pytest.raises(DataError) as e:
            apply_pose_file(scene, path)
        msg = str(e.value)
        assert msg.startswith(str(path)) and "\n" not in msg, msg
        if name in ("aspect.json", "nan.json"):  # the file's entry by its index and its image's name
            first = scene.train_indices[0]
            assert f"view {first} ({scene.cameras[first].name}): " in msg, msg


@pytest.mark.skipif(importlib.util.find_spec("pycolmap") is None, reason="estimating poses needs pycolmap")
def test_training_poses_from_their_photos_alone_match_the_truth(scene, tmp_path):
    """3 training photos of the built-in scene posed by SfM (SIFT) and Sim(3)-aligned to the dataset's training
    cameras: within 1 degree and 1 % of the cameras' spread; the pose file round-trips into the scene."""
    from splat_framework.sfm import estimate_training_poses

    payload = estimate_training_poses(ensure_scene("forward"), views=3, matcher="sift")
    info = payload["info"]
    assert info["registered"] == 3 and info["matcher"] == "sift"
    assert max(info["rotation_deg"]) < 1.0 and max(info["center_error_rel_spread"]) < 0.01, info
    assert max(info["translation_direction_deg"]) < 2.0 and len(info["translation_direction_deg"]) == 6
    assert all(abs(e / d - 1) < 0.02 for e, d in zip(info["focal_estimated"], info["focal_dataset"]))
    path = tmp_path / "poses.json"
    path.write_text(json.dumps(payload))
    new = apply_pose_file(scene, path)
    train = scene.train_indices
    rot, shift = pose_differences(w2c([new.cameras[i] for i in train]), w2c([scene.cameras[i] for i in train]))
    assert rot.max() < 1.0 and rot.max() > 0  # the estimate, not the dataset's poses
    for i in scene.test_indices:  # one camera: its estimated focal length, the dataset's pose
        assert new.cameras[i].world_to_cam is scene.cameras[i].world_to_cam
        ratio = float(new.cameras[i].K[0, 0] / scene.cameras[i].K[0, 0])
        assert ratio == pytest.approx(info["focal_estimated"][0] / info["focal_dataset"][0], rel=1e-4)


def test_a_run_on_a_pose_file_scores_test_views_before_and_after_the_pose_fit(scene, tmp_path):
    from splat_framework.config import TrainConfig
    from splat_framework.engine.run import load_run
    from splat_framework.engine.trainer import train
    from splat_framework.registry import get_method

    path = tmp_path / "poses.json"
    path.write_text(json.dumps(shifted_payload(scene)))
    config = get_method("3dgs").default_config().model_copy(update=dict(
        data=str(ensure_scene("forward")), views=3, steps=5, output=tmp_path / "run", progress=False,
        save_renders=False, compile=False, train_poses=path, test_pose_steps=3))
    config.model.init.num_points = 300
    assert isinstance(config, TrainConfig)
    metrics = train(config)
    assert metrics["test_pose_steps"] == 3 and metrics["mean"]["psnr_before_pose_fit"] is not None
    assert all(v["pose_refined_deg"] >= 0 and "psnr_before_pose_fit" in v for v in metrics["per_view"])
    again, dm, _ = load_run(tmp_path / "run")  # splat-eval sees the run's cameras
    assert again.train_poses == path and again.test_pose_steps == 3
    i = scene.train_indices[0]
    assert float(dm.scene.cameras[i].world_to_cam[0, 3] - scene.cameras[i].world_to_cam[0, 3]) == pytest.approx(0.1, abs=1e-6)

"""The plugin's dataset format ``scene-json``: a folder holding ``scene.json`` trains as ``--data``."""

import json
import shutil

import torch

from splat_framework.testing import run_cli, scene_and_data


def write_scene_json(folder, test_every=4):
    """``folder`` as a scene.json scene of the images and cameras of the built-in scene forward-tiny
    (every ``test_every``-th frame held out); returns forward-tiny's scene."""
    scene, _ = scene_and_data("forward-tiny", views="all")
    (folder / "images").mkdir(parents=True)
    frames = []
    for i, (camera, image) in enumerate(zip(scene.cameras, scene.image_paths)):
        shutil.copy(image, folder / "images" / image.name)
        frames.append({"image": f"images/{image.name}", "K": camera.K.tolist(),
                       "world_to_camera": camera.world_to_cam.tolist(), **({"split": "test"} if i % test_every == 0 else {})})
    near = min(c.near for c in scene.cameras)
    far = max(c.far for c in scene.cameras)
    (folder / "scene.json").write_text(json.dumps({"near": near, "far": far, "frames": frames}))
    return scene


def test_a_scene_json_folder_is_recognised_and_trains(splat, tmp_path, monkeypatch):
    env, _ = splat
    monkeypatch.setenv("SPLAT_CACHE", env["SPLAT_CACHE"])  # forward-tiny as the fixture generated it
    source = write_scene_json(tmp_path / "mine")
    scene, _ = scene_and_data(tmp_path / "mine", views=3)
    assert scene.format == "scene-json" and len(scene.cameras) == len(source.cameras)
    assert scene.train_indices == [1, 2, 3] and scene.test_indices == list(range(0, len(source.cameras), 4))
    assert all(torch.equal(a.world_to_cam, b.world_to_cam) and torch.equal(a.K, b.K)
               for a, b in zip(scene.cameras, source.cameras))
    out = tmp_path / "run"
    run_cli("train", "3dgs", "--data", tmp_path / "mine", "--views", "3", "--steps", "5", "--output", out,
            "--no-progress", code=0, env=env, cwd=tmp_path)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["num_gaussians"] > 0
    trained = json.loads((out / "config.json").read_text())["config"]["resolved_data"]["train"]
    assert trained == [source.image_paths[i].stem for i in (1, 2, 3)]


def test_a_broken_scene_json_is_one_line(splat, tmp_path):
    env, _ = splat
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "scene.json").write_text('{"near": 1, "far": 2}')
    run_cli("train", "3dgs", "--data", tmp_path / "bad", "--steps", "2", "--output", tmp_path / "run",
            "--no-progress", code=2, env=env, cwd=tmp_path, match=("scene.json", "near, far and frames"))

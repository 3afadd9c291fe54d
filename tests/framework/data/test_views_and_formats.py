"""The default views follow the format, and nerfstudio's scenes are recognised (issue 61 item 8):
LLFF, Blender and DTU train on the papers' 3 views unless --views says otherwise; COLMAP,
transforms.json and one's own photos train on every view (every 8th held out beyond 8); a
nerfstudio / instant-ngp ``transforms.json`` folder and nerfstudio's ``colmap/sparse/0`` layout
load with ``--format auto``."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_harness import cli_env, run_cli
from splat_framework.config import TrainConfig, save_config
from splat_framework.data import DataError, describe_split, load_scene, resolve_views
from splat_framework.data.parsers import detect_format
from splat_framework.data.splits import default_views
from splat_framework.pipeline.scene import load_config_scene
from splat_framework.runtime.io import read_json
from support import make_blender, make_colmap, make_dtu, make_llff
from tiers import seed_kernels

FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])
N_VIEWS = 10


@pytest.fixture(scope="module")
def built_in(tmp_path_factory) -> Path:
    """A small built-in forward scene (LLFF layout) with its exact cameras in cameras.json."""
    from splat_framework.data.synthetic.generate import generate_scene

    return generate_scene("forward", tmp_path_factory.mktemp("src") / "scene", width=64, height=48, n_views=N_VIEWS)


def exact_cameras(scene: Path) -> list[dict]:
    """The generator's cameras (OpenCV K and world_to_cam per view), in image order."""
    return json.loads((scene / "cameras.json").read_text())["views"]


def write_transforms(scene: Path, out: Path, intrinsics: str = "pixels", **extra) -> Path:
    """``out`` holding ``scene``'s images and a nerfstudio-style transforms.json written from its exact
    cameras (OpenGL camera-to-world); ``intrinsics``: "pixels" (fl_x, fl_y, cx, cy, w, h) or "angle"
    (camera_angle_x, as instant-ngp's Blender conversions); ``extra``: more top-level keys."""
    shutil.copytree(scene / "images", out / "images")
    views = exact_cameras(scene)
    K, w, h = np.array(views[0]["K"]), views[0]["width"], views[0]["height"]
    if intrinsics == "pixels":
        meta = {"fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": w, "h": h}
    else:
        meta = {"camera_angle_x": 2 * np.arctan(0.5 * w / K[0, 0])}
    frames = [{"file_path": v["image"], "transform_matrix": (np.linalg.inv(v["world_to_cam"]) @ FLIP_YZ).tolist()}
              for v in reversed(views)]  # any order: frames are taken in natural order of their paths
    (out / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV", **meta, **extra, "frames": frames}))
    return out


@pytest.mark.parametrize("intrinsics", ["pixels", "angle"])
def test_a_transforms_json_folder_loads_the_same_cameras(built_in, tmp_path, intrinsics):
    root = write_transforms(built_in, tmp_path / "ns", intrinsics)
    assert detect_format(root) == "transforms"
    scene = load_scene(root)
    assert scene.format == "transforms" and [c.name for c in scene.cameras] == [f"image{i:03d}" for i in range(N_VIEWS)]
    for cam, view in zip(scene.cameras, exact_cameras(built_in)):
        assert (cam.width, cam.height) == (view["width"], view["height"])
        assert torch.allclose(cam.K, torch.tensor(view["K"], dtype=torch.float32), atol=1e-4)
        assert torch.allclose(cam.world_to_cam, torch.tensor(view["world_to_cam"], dtype=torch.float32), atol=1e-5)
        assert 0 < cam.near < cam.far
    assert scene.test_indices == [0, 8] and scene.train_indices == [1, 2, 3, 4, 5, 6, 7, 9]  # every 8th held out
    half = load_scene(root, downscale=2, views=3)
    assert (half.cameras[0].width, half.cameras[0].height) == (32, 24) and len(half.train_indices) == 3
    assert torch.allclose(half.cameras[0].K[:2], scene.cameras[0].K[:2] / 2, atol=1e-4)


@pytest.mark.parametrize("rotation", ["zeros", "nan"])
def test_a_transforms_json_frame_with_a_zero_or_nan_rotation_is_one_line_naming_the_frame(built_in, tmp_path, rotation):
    root = write_transforms(built_in, tmp_path / rotation)
    meta = json.loads((root / "transforms.json").read_text())
    m = np.array(meta["frames"][3]["transform_matrix"])
    m[:3, :3] = 0.0 if rotation == "zeros" else float("nan")
    meta["frames"][3]["transform_matrix"] = m.tolist()
    (root / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match=r"transforms.json: (frame '.*image\d+\.png': (rotation is not|degenerate pose)"
                                        r"|frames\[3\]: transform_matrix has non-finite values)") as info:
        load_scene(root)
    assert "\n" not in str(info.value)


def test_transforms_json_distortion_is_removed_without_a_warning_and_panoramas_refused(built_in, tmp_path):
    root = write_transforms(built_in, tmp_path / "k", k1=0.01, p2=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = load_scene(root)  # the images and intrinsics undistorted: tests/framework/data/test_distortion.py
    assert all(u is not None and u.lens.coeffs == (0.01, 0.0, 0.0, 0.0, 0.0) for u in scene.undistort)
    fisheye = write_transforms(built_in, tmp_path / "f", camera_model="OPENCV_FISHEYE", k1=0.0, k2=0.0, k3=0.0, k4=0.0)
    assert all(u.lens.model == "fisheye" for u in load_scene(fisheye).undistort)  # equidistant: still a lens
    panorama = write_transforms(built_in, tmp_path / "e", camera_model="EQUIRECTANGULAR")
    with pytest.raises(DataError, match="camera_model 'EQUIRECTANGULAR' is not supported"):
        load_scene(panorama)
    bare = tmp_path / "bare"
    shutil.copytree(built_in / "images", bare / "images")
    (bare / "transforms.json").write_text(json.dumps({"frames": [{"file_path": "images/image000.png",
                                                                   "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(DataError, match="no intrinsics"):
        load_scene(bare)


def test_transforms_json_reads_each_frames_own_intrinsics_over_the_top_levels(built_in, tmp_path):
    """nerfstudio's per-frame intrinsics (several cameras of one image size): a frame's fl_x, fl_y,
    cx, cy, w, h (and distortion) are its own; what a frame lacks comes from the top level."""
    root = write_transforms(built_in, tmp_path / "pf")
    meta = json.loads((root / "transforms.json").read_text())
    K = np.array(exact_cameras(built_in)[0]["K"])
    by_path = {fr["file_path"]: fr for fr in meta["frames"]}
    by_path["images/image003.png"].update(fl_x=2 * K[0, 0], fl_y=2 * K[1, 1])  # a zoomed second camera
    by_path["images/image005.png"].update(cx=K[0, 2] + 3.0, k1=0.02)
    for key in ("fl_x", "fl_y", "cx", "cy"):  # image007 states all four itself; no top-level fl_x left ...
        by_path["images/image007.png"][key] = meta[key]
    (root / "transforms.json").write_text(json.dumps(meta))
    scene = load_scene(root)
    assert [u is not None for u in scene.undistort] == [c.name == "image005" for c in scene.cameras]
    assert scene.undistort[5].lens.cx == pytest.approx(K[0, 2] + 3.0)
    Ks = {c.name: c.K for c in scene.cameras}
    assert torch.allclose(Ks["image003"][:2, :2], 2 * torch.tensor(K[:2, :2], dtype=torch.float32), atol=1e-4)
    assert torch.allclose(Ks["image003"][:2, 2], torch.tensor(K[:2, 2], dtype=torch.float32), atol=1e-4)
    assert abs(float(Ks["image005"][0, 2]) - (K[0, 2] + 3.0)) < 0.5  # its own principal point, undistorted
    assert torch.allclose(Ks["image000"], torch.tensor(K, dtype=torch.float32), atol=1e-4)
    for key in ("fl_x", "fl_y", "cx", "cy"):  # ... so a frame without its own has none, and the error names it
        meta.pop(key)
    (root / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match=r"transforms.json: frame 'images/image000.png': no intrinsics"):
        load_scene(root)


def test_nerfstudio_colmap_sparse_0_layout_is_recognised(tmp_path):
    root = make_colmap(tmp_path / "ns", binary=True, sparse_sub="colmap/sparse/0")
    assert detect_format(root) == "colmap"
    scene = load_scene(root)
    assert scene.format == "colmap" and len(scene.cameras) == 9 and scene.test_indices == [0, 8]


def test_ns_process_data_output_reads_its_transforms_json(built_in, tmp_path):
    """ns-process-data writes transforms.json and colmap/sparse/0 beside images/: the first is read."""
    root = write_transforms(built_in, tmp_path / "both")
    make_colmap(tmp_path / "c", binary=True, sparse_sub="colmap/sparse/0")
    shutil.copytree(tmp_path / "c" / "colmap", root / "colmap")
    assert detect_format(root) == "transforms"


def test_the_default_views_follow_the_format():
    assert [default_views(f) for f in ("llff", "blender", "dtu")] == [3, 3, 3]
    assert [default_views(f) for f in ("colmap", "transforms")] == ["all", "all"]


def _config(data: Path, **kw) -> TrainConfig:
    return TrainConfig(data=str(data), **kw)


def test_benchmarks_default_to_3_views_and_own_scenes_to_all(built_in, tmp_path):
    scenes = {
        "llff": make_llff(tmp_path / "l", 20), "blender": make_blender(tmp_path / "b", 10, 16),
        "dtu": make_dtu(tmp_path / "d"), "colmap": make_colmap(tmp_path / "c", binary=False, n_images=17),
        "transforms": write_transforms(built_in, tmp_path / "t"),
    }
    for fmt, root in scenes.items():
        config = resolve_views(_config(root))
        assert config.views == default_views(fmt), fmt
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the tiny COLMAP model's camera
            scene = load_config_scene(config)
        if fmt in ("llff", "blender", "dtu"):
            assert len(scene.train_indices) == 3, fmt
            assert describe_split(scene, config.views) is None  # the papers' split, as documented
    colmap = load_config_scene(resolve_views(_config(scenes["colmap"])))
    assert colmap.test_indices == [0, 8, 16] and len(colmap.train_indices) == 14
    assert describe_split(colmap, "all") == ("training on all 14 views of a COLMAP scene (its default; --views N for a "
                                             "few-shot split); 3 test views held out (every 8th image): frame_00, frame_08, frame_16")


def test_views_3_on_a_colmap_scene_is_the_few_shot_split(tmp_path):
    root = make_colmap(tmp_path / "c", binary=False, n_images=17)
    config = resolve_views(_config(root, views=3))
    scene = load_config_scene(config)
    assert config.views == 3 and scene.train_indices == [1, 7, 15] and scene.test_indices == [0, 8, 16]
    assert describe_split(scene, 3) == ("training on 3 views of a COLMAP scene: frame_01, frame_07, frame_15; "
                                        "3 test views held out (every 8th image): frame_00, frame_08, frame_16")


def test_resume_keeps_the_runs_views(tmp_path):
    """A run saved with views=3 (the old default, on any format) resumes with 3, not the format's default."""
    root = make_colmap(tmp_path / "c", binary=False, n_images=17)
    run = tmp_path / "run"
    run.mkdir()
    save_config(_config(root, views=3, output=run), run / "config.json")
    assert resolve_views(_config(root, output=run, resume=True)).views == 3
    assert resolve_views(_config(root, output=run)).views == "all"  # a new run: the format's default
    assert resolve_views(_config(root, output=run, resume=True, views="all")).views == "all"  # as given


def test_a_transforms_scene_trains_on_every_view_by_default(built_in, tmp_path):
    root = write_transforms(built_in, tmp_path / "ns")
    run = tmp_path / "run"
    res = run_cli("train", "3dgs", "--data", root, "--steps", "2", "--output", run, "--no-progress",
                  "--no-save-renders", "--model.init.num-points", "300", code=0,
                  env=cli_env(SPLAT_CACHE=str(seed_kernels(tmp_path / "cache"))))
    line = ("training on all 8 views of a transforms.json scene (its default; --views N for a few-shot split): "
            "image001, image002, image003, image004, image005, image006, image007, image009; "
            "2 test views held out (every 8th image): image000, image008")
    assert line in " ".join(res.stderr.split()), res.stderr
    config = read_json(run / "config.json")["config"]
    assert config["views"] == "all" and config["format"] == "auto"
    assert config["resolved_data"]["test"] == ["image000", "image008"] and len(config["resolved_data"]["train"]) == 8
    from splat_framework.engine.trainer import Trainer

    resumed = Trainer(_config(root, output=run, resume=True, steps=2, progress=False, save_renders=False,
                              model={"init": {"kind": "random", "num_points": 300}}))  # no --views: the run's
    try:
        assert resumed.config.views == "all" and resumed.restore() and resumed.start_step == 2
    finally:
        resumed.release()

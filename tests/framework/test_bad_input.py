"""Reliability: every bad input is a one-line DataError naming the file and the problem."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from splat_framework.data import DataError, DataManager, load_image, load_scene, read_image_size
from splat_framework.sfm import resolve_data_path
from support import llff_row, make_blender, make_colmap, make_dtu, make_llff, write_png


def raises_data_error(fn, *match: str) -> str:
    """Call ``fn``; assert it raises a one-line DataError containing every ``match``."""
    with pytest.raises(DataError) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg, msg
    for m in match:
        assert m in msg, f"{m!r} not in {msg!r}"
    return msg


# ----------------------------------------------------------------- folders


@pytest.mark.bad_input("a dataset folder that is missing, empty or of no known format; missing, corrupt or truncated images; malformed or non-finite poses", "exit 2, one line naming the file and the problem")
def test_missing_folder(tmp_path):
    raises_data_error(lambda: load_scene(tmp_path / "nope"), "nope", "no such dataset folder")


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    raises_data_error(lambda: load_scene(tmp_path / "empty"), "empty", "empty folder")


@pytest.mark.bad_input("a dataset folder that is missing, empty or of no known format; missing, corrupt or truncated images; malformed or non-finite poses", "exit 2, one line naming the file and the problem")
def test_unknown_format(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "readme.txt").write_text("hi")
    raises_data_error(lambda: load_scene(tmp_path / "x"), "neither a dataset", "splat-process")
    root = make_llff(tmp_path / "l", 3)
    raises_data_error(lambda: load_scene(root, format="nerf"), "unknown dataset format 'nerf'")
    raises_data_error(lambda: load_scene(root, format="blender"), "transforms_train.json", "not found")


def test_path_is_a_file(tmp_path):
    (tmp_path / "f.txt").write_text("x")
    raises_data_error(lambda: load_scene(tmp_path / "f.txt"), "not a folder")


def test_resolve_data_path(tmp_path, monkeypatch):
    (tmp_path / "scene").mkdir()
    assert resolve_data_path(tmp_path / "scene") == tmp_path / "scene"
    monkeypatch.setenv("SPLAT_DATA", str(tmp_path))
    assert resolve_data_path("scene") == tmp_path / "scene"
    raises_data_error(lambda: resolve_data_path("missing/x"), "missing/x", f"$SPLAT_DATA={tmp_path}")
    monkeypatch.delenv("SPLAT_DATA")
    raises_data_error(lambda: resolve_data_path("missing/x"), "not set")


@pytest.mark.bad_input("a missing `--data`: an absolute path, or a relative name with `$SPLAT_DATA` unset or set",
                       "exit 2, one line; an absolute path suggests only its siblings, a relative name says how to set $SPLAT_DATA")
def test_a_missing_data_path_gets_the_hint_that_helps(tmp_path, monkeypatch):
    (tmp_path / "llff" / "fern").mkdir(parents=True)
    (tmp_path / "unrelated").mkdir()
    monkeypatch.delenv("SPLAT_DATA", raising=False)
    monkeypatch.chdir(tmp_path / "unrelated")
    msg = raises_data_error(lambda: resolve_data_path(tmp_path / "nope"))
    assert msg == f"{tmp_path / 'nope'}: no such dataset folder"  # no unrelated folder, no $SPLAT_DATA
    assert raises_data_error(lambda: resolve_data_path(tmp_path / "llff" / "fren")).endswith("(did you mean 'fern'?)")
    assert raises_data_error(lambda: resolve_data_path("llff/fren")) == (
        "llff/fren: no such dataset folder; a relative name is also looked up under $SPLAT_DATA, which is not set: "
        "export SPLAT_DATA=/path/to/your/datasets (docs/data.md)")
    monkeypatch.setenv("SPLAT_DATA", str(tmp_path))
    assert raises_data_error(lambda: resolve_data_path("llff/fren")) == (
        f"llff/fren: no such dataset folder (did you mean 'llff/fern'?) (also looked in $SPLAT_DATA={tmp_path})")


def test_resolve_synthetic_calls_generator(tmp_path, monkeypatch):
    import sys
    import types

    calls = []
    fake = types.ModuleType("splat_framework.data.synthetic")
    fake.ensure_scene = lambda name: calls.append(name) or tmp_path / name
    monkeypatch.setitem(sys.modules, "splat_framework.data.synthetic", fake)
    import splat_framework.data as data_pkg

    monkeypatch.setattr(data_pkg, "synthetic", fake, raising=False)
    assert resolve_data_path("synthetic/planes") == tmp_path / "planes"
    assert calls == ["planes"]


# ------------------------------------------------------------------ images


def test_missing_image_llff(tmp_path):
    root = make_llff(tmp_path / "s", 5)
    (root / "images_8" / "img002.png").unlink()
    raises_data_error(lambda: load_scene(root), "poses_bounds.npy", "5 poses but 4 images")


def test_missing_image_after_parse(tmp_path):
    root = make_llff(tmp_path / "s", 10)
    scene = load_scene(root)
    scene.image_paths[1].unlink()
    raises_data_error(lambda: DataManager(scene), "img001.png", "not found")


def test_missing_image_blender(tmp_path):
    root = make_blender(tmp_path / "b", 3, 2)
    (root / "train" / "r_1.png").unlink()
    raises_data_error(lambda: load_scene(root), "r_1.png", "image file not found")


def test_an_image_that_is_a_fifo_is_named_as_not_a_regular_file_and_never_opened(tmp_path):
    # a FIFO exists: "not found" would be wrong, and opening it would wait for a writer forever
    root = make_blender(tmp_path / "b", 3, 2)
    (root / "train" / "r_1.png").unlink()
    os.mkfifo(root / "train" / "r_1.png")
    raises_data_error(lambda: load_scene(root), "r_1.png", "not a regular file (a FIFO)")
    os.mkfifo(tmp_path / "f.png")
    raises_data_error(lambda: load_image(tmp_path / "f.png"), "f.png", "not a regular file (a FIFO)")
    raises_data_error(lambda: read_image_size(tmp_path / "f.png"), "f.png", "not a regular file (a FIFO)")


def test_corrupt_image(tmp_path):
    root = make_llff(tmp_path / "s", 10)
    bad = root / "images_8" / "img003.png"
    bad.write_bytes(b"this is not an image at all")
    raises_data_error(lambda: load_scene(root), "img003.png", "cannot decode")


@pytest.mark.parametrize("fraction", [0.3, 0.7, 0.97])
def test_truncated_png(tmp_path, fraction):
    root = make_llff(tmp_path / "s", 10)
    scene = load_scene(root)
    bad = scene.image_paths[1]
    data = bad.read_bytes()
    bad.write_bytes(data[: int(len(data) * fraction)])
    raises_data_error(lambda: DataManager(scene), bad.name, "truncated")


@pytest.mark.bad_input("a dataset folder that is missing, empty or of no known format; missing, corrupt or truncated images; malformed or non-finite poses", "exit 2, one line naming the file and the problem")
def test_truncated_jpeg(tmp_path):
    rng = np.random.default_rng(0)
    p = tmp_path / "x.jpg"
    cv2.imwrite(str(p), rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    assert read_image_size(p) == (64, 64)  # header still fine
    raises_data_error(lambda: load_image(p), "x.jpg", "truncated JPEG")


def test_empty_and_unreadable_image_files(tmp_path):
    (tmp_path / "e.png").write_bytes(b"")
    raises_data_error(lambda: load_image(tmp_path / "e.png"), "e.png", "empty")
    raises_data_error(lambda: read_image_size(tmp_path / "e.png"), "e.png", "empty")
    (tmp_path / "d.png").mkdir()
    raises_data_error(lambda: load_image(tmp_path / "d.png"), "d.png", "not a regular file (a folder)")
    raises_data_error(lambda: load_image(tmp_path / "none.png"), "none.png", "not found")


def test_mixed_image_sizes_in_folder(tmp_path):
    root = make_llff(tmp_path / "s", 5)
    write_png(root / "images_8" / "img004.png", 20, 15)
    raises_data_error(lambda: load_scene(root), "img004.png", "mixed image sizes")
    b = make_blender(tmp_path / "b", 3, 2)
    write_png(b / "test" / "r_1.png", 6, 6, rgba=True)
    raises_data_error(lambda: load_scene(b), "r_1.png", "mixed image sizes")


# -------------------------------------------------------------------- LLFF


def _llff_with(tmp_path, arr, n_images=3):
    root = tmp_path / "s"
    for i in range(n_images):
        write_png(root / "images_8" / f"img{i:03d}.png", 16, 12, seed=i)
    np.save(root / "poses_bounds.npy", arr)
    return root


def _valid_rows(n=3):
    return np.stack([llff_row(np.eye(3), [0.1 * i, 0, 0], 96, 128, 100.0, 1.0, 10.0) for i in range(n)])


@pytest.mark.parametrize(
    "arr, match",
    [
        (np.zeros((3, 15)), "expected shape [N, 17], got [3, 15]"),
        (np.zeros((3, 17, 1)), "expected shape [N, 17]"),
        (np.zeros(17), "expected shape [N, 17], got [17]"),
        (np.zeros((0, 17)), "expected shape [N, 17]"),
        (np.array(["a"] * 17 * 3).reshape(3, 17), "expected a float array"),
    ],
)
def test_poses_bounds_shapes(tmp_path, arr, match):
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "poses_bounds.npy", match)


def test_poses_bounds_garbage_file(tmp_path):
    root = _llff_with(tmp_path, _valid_rows())
    (root / "poses_bounds.npy").write_bytes(b"\x93NUMPY garbage")
    raises_data_error(lambda: load_scene(root), "poses_bounds.npy", "cannot read")
    np.save(root / "poses_bounds.npy", np.array([{"a": 1}], dtype=object))
    raises_data_error(lambda: load_scene(root), "poses_bounds.npy")


def test_poses_count_mismatch(tmp_path):
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, _valid_rows(4), 3)), "4 poses but 3 images")


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.bad_input("a dataset folder that is missing, empty or of no known format; missing, corrupt or truncated images; malformed or non-finite poses", "exit 2, one line naming the file and the problem")
def test_poses_non_finite(tmp_path, value):
    arr = _valid_rows()
    arr[1, 3] = value
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "poses_bounds.npy", "non-finite", "row 1")


@pytest.mark.bad_input("a dataset folder that is missing, empty or of no known format; missing, corrupt or truncated images; malformed or non-finite poses", "exit 2, one line naming the file and the problem")
def test_poses_non_orthonormal(tmp_path):
    arr = _valid_rows()
    arr[2, :15] = (arr[2, :15].reshape(3, 5) * [1.5, 1.5, 1.5, 1, 1]).reshape(-1)
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "row 2", "not orthonormal")


def test_poses_reflection(tmp_path):
    arr = _valid_rows()
    m = arr[0, :15].reshape(3, 5)
    m[:, 2] *= -1
    arr[0, :15] = m.reshape(-1)
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "row 0", "reflection")


@pytest.mark.parametrize("focal", [0.0, -50.0])
def test_poses_bad_focal(tmp_path, focal):
    arr = _valid_rows()
    arr[1, 14] = focal
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "row 1", "focal")


@pytest.mark.parametrize("near, far", [(0.0, 10.0), (-1.0, 5.0), (5.0, 5.0), (6.0, 2.0)])
def test_poses_bad_bounds(tmp_path, near, far):
    arr = _valid_rows()
    arr[0, 15:] = [near, far]
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "row 0", "near/far")


def test_poses_size_mismatch(tmp_path):
    arr = _valid_rows()
    arr[:, 4] = 400  # H=400 with W=128: aspect differs from 16x12 images
    raises_data_error(lambda: load_scene(_llff_with(tmp_path, arr)), "aspect ratios differ")


def test_bad_depth_map(tmp_path):
    root = make_llff(tmp_path / "s", 10, depths=True)
    (root / "depths" / "img001.npy").write_bytes(b"junk")
    scene = load_scene(root)
    raises_data_error(lambda: DataManager(scene), "img001.npy", "cannot read depth")
    (root / "depths" / "img001.npy").unlink()
    raises_data_error(lambda: load_scene(root), "img001.npy", "depth map missing")


# ---------------------------------------------------------------- views


def test_views_more_than_pool(tmp_path):
    root = make_llff(tmp_path / "s", 10)  # 8 training candidates
    raises_data_error(lambda: load_scene(root, views=9), "views=9", "more than the 8")
    raises_data_error(lambda: load_scene(root, views=0), "views")
    raises_data_error(lambda: load_scene(make_blender(tmp_path / "b", 3, 2), views=4), "views=4")


def test_bad_downscale(tmp_path):
    root = make_llff(tmp_path / "s", 3)
    raises_data_error(lambda: load_scene(root, downscale=0), "downscale")
    raises_data_error(lambda: load_scene(root, downscale=2), "downscale 2 needs")  # only images_8 present


# --------------------------------------------------------------- Blender


def _edit_json(root: Path, split: str, fn) -> Path:
    p = root / f"transforms_{split}.json"
    meta = json.loads(p.read_text())
    out = fn(meta)
    p.write_text(out if isinstance(out, str) else json.dumps(out if out is not None else meta))
    return p


def _frame0(meta):
    return meta["frames"][0]


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda m: "{not json", "malformed JSON"),
        (lambda m: "[1, 2]", "expected a JSON object"),
        (lambda m: m.pop("frames") and None, "missing key 'frames'"),
        (lambda m: m.pop("camera_angle_x") and None, "missing key 'camera_angle_x'"),
        (lambda m: {**m, "frames": []}, "'frames' is empty"),
        (lambda m: {**m, "frames": {"a": 1}}, "'frames' must be a list"),
        (lambda m: {**m, "camera_angle_x": "wide"}, "expected a number"),
        (lambda m: {**m, "camera_angle_x": 0}, "camera_angle_x must be in (0, pi)"),
        (lambda m: {**m, "camera_angle_x": -0.5}, "camera_angle_x must be in (0, pi)"),
        (lambda m: _frame0(m).pop("file_path") and None, "frames[0]: missing key 'file_path'"),
        (lambda m: _frame0(m).pop("transform_matrix") and None, "missing key 'transform_matrix'"),
        (lambda m: _frame0(m).update(transform_matrix=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "must be 4x4"),
        (lambda m: _frame0(m).update(transform_matrix=[[1, 0, 0, 0]] * 5), "must be 4x4"),
        (lambda m: _frame0(m).update(transform_matrix="eye"), "transform_matrix must be a 4x4 list"),
        (lambda m: _frame0(m).update(transform_matrix=[[1, 0, 0, "x"]] * 4), "4x4 list of numbers"),
        (lambda m: _frame0(m).update(transform_matrix=np.diag([2.0, 2, 2, 1]).tolist()), "not orthonormal"),
        (lambda m: _frame0(m)["transform_matrix"][0].__setitem__(3, float("nan")), "non-finite"),
        (lambda m: _frame0(m)["transform_matrix"][3].__setitem__(0, 1.0), "last row"),
        (lambda m: _frame0(m).update(file_path=7), "file_path must be a non-empty string"),
        (lambda m: m["frames"].append(3), "frames[2]: expected an object"),
    ],
)
def test_blender_bad_json(tmp_path, edit, match):
    root = make_blender(tmp_path / "b", 2, 2)
    p = _edit_json(root, "train", edit)
    raises_data_error(lambda: load_scene(root), str(p.name), match)


def test_blender_bad_test_json(tmp_path):
    root = make_blender(tmp_path / "b", 2, 2)
    _edit_json(root, "test", lambda m: "{")
    raises_data_error(lambda: load_scene(root), "transforms_test.json", "malformed JSON")


def test_blender_missing_test_json_warns(tmp_path):
    root = make_blender(tmp_path / "b", 2, 2)
    (root / "transforms_test.json").unlink()
    with pytest.warns(UserWarning, match="transforms_test.json"):
        scene = load_scene(root)
    assert scene.test_indices == []


# ------------------------------------------------------------------- DTU


def test_dtu_missing_world_mat(tmp_path):
    root = make_dtu(tmp_path / "d", 5, masks=False)
    z = dict(np.load(root / "cameras_sphere.npz"))
    del z["world_mat_3"]
    np.savez(root / "cameras_sphere.npz", **z)
    with pytest.warns(UserWarning, match="no mask folder"):
        raises_data_error(lambda: load_scene(root), "cameras_sphere.npz", "missing 'world_mat_3'")


def test_dtu_degenerate_and_corrupt(tmp_path):
    root = make_dtu(tmp_path / "d", 5)
    z = dict(np.load(root / "cameras_sphere.npz"))
    z["world_mat_1"] = np.zeros((4, 4))
    np.savez(root / "cameras_sphere.npz", **z)
    raises_data_error(lambda: load_scene(root), "camera 1", "degenerate projection")
    z["world_mat_1"] = np.zeros((2, 2))
    np.savez(root / "cameras_sphere.npz", **z)
    raises_data_error(lambda: load_scene(root), "'world_mat_1' must be a 4x4")
    (root / "cameras_sphere.npz").write_bytes(b"PK junk")
    raises_data_error(lambda: load_scene(root), "cameras_sphere.npz", "cannot read")


def test_dtu_mask_count(tmp_path):
    root = make_dtu(tmp_path / "d", 5)
    (root / "mask_4" / "004.png").unlink()
    raises_data_error(lambda: load_scene(root), "mask_4", "4 masks but 5 images")


# ---------------------------------------------------------------- COLMAP


@pytest.mark.parametrize("name", ["cameras.bin", "images.bin", "points3D.bin"])
def test_colmap_truncated_binary(tmp_path, name):
    root = make_colmap(tmp_path / "c", binary=True)
    p = root / "sparse" / "0" / name
    p.write_bytes(p.read_bytes()[:-7])
    raises_data_error(lambda: load_scene(root), name, "truncated")


def test_colmap_malformed_text(tmp_path):
    root = make_colmap(tmp_path / "c", binary=False)
    p = root / "sparse" / "0" / "cameras.txt"
    p.write_text("1 PINHOLE 32 24 30 31 16\n")
    raises_data_error(lambda: load_scene(root), "cameras.txt", "PINHOLE needs 4 params")
    p.write_text("1 PINHOLE wide 24 30 31 16 12\n")
    raises_data_error(lambda: load_scene(root), "cameras.txt", "line 1", "malformed")
    p.write_text("1 PINHOLE 32 24 30 31 16 12\n")
    (root / "images" / "frame_03.png").unlink()
    raises_data_error(lambda: load_scene(root), "frame_03.png", "not found")


def test_colmap_bad_camera_id(tmp_path):
    root = make_colmap(tmp_path / "c", binary=False)
    p = root / "sparse" / "0" / "cameras.txt"
    p.write_text("2 PINHOLE 32 24 30 31 16 12\n")
    raises_data_error(lambda: load_scene(root), "images.txt", "camera 1")


def test_colmap_bad_focal(tmp_path):
    root = make_colmap(tmp_path / "c", binary=False)
    (root / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE 32 24 -30 31 16 12\n")
    raises_data_error(lambda: load_scene(root), "focal length must be positive")


# ------------------------------------------------------------ properties

_float = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    arr=hnp.arrays(
        dtype=st.sampled_from([np.float64, np.float32, np.int32]),
        shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=20),
        elements=None,
    )
)
def test_property_random_poses_bounds(tmp_path, arr):
    """Any array in poses_bounds.npy: a valid scene or a one-line DataError."""
    root = tmp_path / "s"
    if not (root / "images_8").is_dir():
        for i in range(3):
            write_png(root / "images_8" / f"img{i:03d}.png", 16, 12, seed=i)
    np.save(root / "poses_bounds.npy", arr)
    try:
        scene = load_scene(root)
    except DataError as e:
        assert "\n" not in str(e) and "poses_bounds.npy" in str(e)
    else:
        assert len(scene.cameras) == 3


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    row=st.integers(0, 2),
    col=st.integers(0, 16),
    value=st.one_of(_float, st.sampled_from([0.0, -1.0, 1e308, -1e-300, 2.0])),
)
def test_property_perturbed_poses_bounds(tmp_path, row, col, value):
    """One corrupted entry in a valid array: valid scene or DataError naming the file and row."""
    arr = _valid_rows()
    arr[row, col] = value
    root = tmp_path / "s"
    if not (root / "images_8").is_dir():
        for i in range(3):
            write_png(root / "images_8" / f"img{i:03d}.png", 16, 12, seed=i)
    np.save(root / "poses_bounds.npy", arr)
    try:
        scene = load_scene(root)
    except DataError as e:
        msg = str(e)
        assert "\n" not in msg and "poses_bounds.npy" in msg and f"row {row}" in msg
    else:
        for c in scene.cameras:
            assert math.isfinite(c.near) and 0 < c.near < c.far and float(c.K[0, 0]) > 0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scale=st.floats(1.01, 100.0) | st.floats(0.0, 0.99), axis=st.integers(0, 2))
def test_property_non_orthonormal_always_rejected(tmp_path, scale, axis):
    arr = _valid_rows()
    m = arr[1, :15].reshape(3, 5)
    m[:, axis] *= scale
    arr[1, :15] = m.reshape(-1)
    root = tmp_path / "s"
    if not (root / "images_8").is_dir():
        for i in range(3):
            write_png(root / "images_8" / f"img{i:03d}.png", 16, 12, seed=i)
    np.save(root / "poses_bounds.npy", arr)
    raises_data_error(lambda: load_scene(root), "row 1", "orthonormal")


_json = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 5) | _float | st.text(max_size=8),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=20,
)
_matrix = st.one_of(
    _json,
    st.lists(st.lists(st.one_of(_float, st.integers(-3, 3), st.text(max_size=2)), min_size=0, max_size=5), max_size=5),
    st.just(np.eye(4).tolist()),
)
_frame = st.one_of(
    _json,
    st.fixed_dictionaries(
        {},
        optional={
            "file_path": st.one_of(st.sampled_from(["./train/r_0", "train/r_1", "./train/r_9", "", "/abs/x"]), _json),
            "transform_matrix": _matrix,
        },
    ),
)
_meta = st.one_of(
    _json,
    st.fixed_dictionaries(
        {},
        optional={
            "camera_angle_x": st.one_of(st.floats(-1, 4), _json),
            "frames": st.one_of(st.lists(_frame, max_size=3), _json),
        },
    ),
)


@settings(max_examples=150, deadline=None)
@given(meta=_meta, raw=st.booleans())
def test_property_malformed_transforms_json(meta, raw):
    """Arbitrary transforms_train.json content: valid scene or one-line DataError."""
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        for i in range(2):
            write_png(root / "train" / f"r_{i}.png", 8, 8, rgba=True, seed=i)
        text = json.dumps(meta, allow_nan=True)
        if raw:
            text = text[: len(text) // 2]  # truncated JSON (may still parse for tiny texts)
        (root / "transforms_train.json").write_text(text)
        try:
            scene = load_scene(root)
        except DataError as e:
            assert "\n" not in str(e)
        else:
            assert len(scene.cameras) >= 1


@settings(max_examples=40, deadline=None)
@given(data=st.binary(max_size=200), name=st.sampled_from(["cameras.bin", "images.bin", "points3D.bin"]))
def test_property_garbage_colmap_binary(data, name):
    with tempfile.TemporaryDirectory() as d:
        root = make_colmap(Path(d) / "c", binary=True, n_images=2)
        (root / "sparse" / "0" / name).write_bytes(data)
        try:
            load_scene(root)
        except DataError as e:
            assert "\n" not in str(e)


def test_splat_process_without_pycolmap_names_the_extra(monkeypatch, tmp_path):
    import sys

    from splat_framework.sfm import estimate_scene

    monkeypatch.setitem(sys.modules, "pycolmap", None)  # import pycolmap -> ImportError
    photos = []
    for k in range(2):
        photos.append(tmp_path / "photos" / f"p{k}.png")
        photos[-1].parent.mkdir(exist_ok=True)
        photos[-1].write_bytes(b"")
    with pytest.raises(DataError, match=r'pip install "splat-framework\[process\]"'):
        estimate_scene(photos, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.bad_input("`--downscale 1e308`, `--model.init-scale 1e308`, `--load-config` naming a FIFO",
                       "exit 2, one line naming the flag (and the image or file)")
def test_errors_caused_by_a_flag_name_the_flag(tmp_path):
    import os

    from cli_harness import run_cli

    base = ("3dgs", "--data", "synthetic/forward-tiny", "--steps", "2", "--output", tmp_path / "run")
    res = run_cli("train", *base, "--downscale", "1e308", code=2, match="error: --downscale 1e+308: ")
    assert "would be decoded to less than one pixel; at most 48 for this dataset" in res.stderr
    run_cli("train", *base, "--model.init-scale", "1e308", code=2,
            match="error: invalid config: model.init_scale: Input should be less than or equal to 1000")
    os.mkfifo(tmp_path / "fifo")
    run_cli("train", "3dgs", "--load-config", tmp_path / "fifo", code=2,
            match=f"error: {tmp_path / 'fifo'}: not a regular file (--load-config takes a run's config.json)")
    assert not (tmp_path / "run").exists()

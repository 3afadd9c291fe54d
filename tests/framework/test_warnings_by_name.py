"""Every warning about photos names files, not indices (issue 61 item 2): the matching prior's pairs
left empty in one line by the views' names, a training view without any verified match named in
one line (from a run, and again when its matches come from the cache), splat-match alike, and a
photo that posing could not register listed with its verified matches per photo, by file name
(splat-process, and ``splat-train --data PHOTOS`` again from the cache)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli_harness import cli_env, run_cli
from splat_framework.matching.matchset import MatchSet
from splat_framework.matching.report import empty_pairs_line, unmatched_views_line
from splat_framework.sfm.posing_record import posing_record
from splat_framework.sfm.reconstruct import SfmSummary
from tiers import seed_kernels

NOISE = 3
"""The view of the scene replaced by noise: image003, the photo IMG_4.jpg."""
INDEX = re.compile(r"pair \(\d+, \d+\)|view \d+\b")
"""A pair or a view named by its index."""


def warning_lines(text: str) -> list[str]:
    """The ``warning:`` lines of a command's output."""
    return [line for line in text.splitlines() if line.startswith("warning:")]


@pytest.fixture(scope="module")
def noisy_scene(tmp_path_factory) -> Path:
    """The built-in forward scene (LLFF layout, 5 views at 192x144) with view 3 replaced by noise:
    no verified match with any other view."""
    from splat_framework.data.synthetic.generate import generate_scene

    scene = generate_scene("forward", tmp_path_factory.mktemp("noisy") / "scene", width=192, height=144, n_views=5)
    noise = np.random.default_rng(0).integers(0, 256, (144, 192, 3), dtype=np.uint8)
    cv2.imwrite(str(scene / "images" / f"image{NOISE:03d}.png"), noise)
    return scene


@pytest.fixture(scope="module")
def noisy_photos(noisy_scene, tmp_path_factory) -> Path:
    """The noisy scene's views as a folder of one's own photos, IMG_1.jpg ... IMG_5.jpg (IMG_4.jpg: noise)."""
    photos = tmp_path_factory.mktemp("own") / "photos"
    photos.mkdir()
    for k in range(5):
        img = cv2.imread(str(noisy_scene / "images" / f"image{k:03d}.png"))
        cv2.imwrite(str(photos / f"IMG_{k + 1}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    return photos


def test_the_pairs_left_empty_and_the_views_without_a_match_are_one_line_each_by_name():
    some, none = np.ones((20, 2), np.float32), np.zeros((0, 2), np.float32)
    ids = list(range(14))
    matches = {(i, j): (some, some) if (i, j) == (0, 1) else (none, none) for i in ids for j in ids if i < j}
    ms = MatchSet(view_ids=ids, matches=matches, warnings={p: "left empty" for p in matches if p != (0, 1)})
    names = {v: f"IMG_{v + 1}" for v in ids}
    line = empty_pairs_line(ms, names)
    assert line.startswith("90 of 91 pairs left empty (fewer than 8 verified matches): IMG_1-IMG_3, IMG_1-IMG_4, ")
    assert line.endswith(", IMG_1-IMG_12 and 80 more"), line
    assert unmatched_views_line(ms, names) == (
        "training views IMG_3, IMG_4, IMG_5, IMG_6, IMG_7, IMG_8, IMG_9, IMG_10, IMG_11, IMG_12 and 2 more have no "
        "verified match with any other training view: the matching prior cannot place them (photos with more "
        "overlap, or another matcher, help)")
    assert unmatched_views_line(ms, {}).startswith("training views 2, 3, 4, ")  # unnamed views: their ids
    kept = MatchSet(view_ids=[0, 1], matches={(0, 1): (some, some)})
    assert empty_pairs_line(kept, names) is None and unmatched_views_line(kept, names) is None


def test_training_names_the_pairs_left_empty_and_the_view_without_a_match_also_from_the_cache(noisy_scene, tmp_path):
    """The matching prior of a run (3dgs-triang's start) on a scene with a view of noise: one line naming
    the empty pairs, one naming the view; the same two lines when the next run reads the matches cached."""
    env = cli_env(SPLAT_CACHE=str(seed_kernels(tmp_path / "cache")))
    expected = ["warning: 3 of 6 pairs left empty (fewer than 8 verified matches): image001-image003, "
                "image002-image003, image003-image004",
                "warning: training view image003 has no verified match with any other training view: the matching "
                "prior cannot place it (photos with more overlap, or another matcher, help)"]
    for run in ("run", "again"):  # the second run's matches come from the cache
        res = run_cli("train", "3dgs-triang", "--data", noisy_scene, "--views", "all", "--steps", "1", "--output",
                      tmp_path / run, "--no-progress", "--model.init.matching.kind", "sift", code=0, env=env)
        assert warning_lines(res.stderr) == expected, res.stderr
        assert not INDEX.search(res.stdout + res.stderr), res.stderr


def test_the_pairs_left_empty_say_whether_the_poses_of_ones_photos_lack_any(tmp_path, capsys, monkeypatch):
    """Issue 107: the prior's pairs left empty on photos posed by splat (``posing.json``): every photo
    registered, an information line saying the poses are not affected (no warning); some left out, a
    warning naming them and what may pose them (the flags of ``--data PHOTOS`` or of splat-process);
    a dataset's own poses (no record), the warning as before."""
    import warnings

    from splat_framework.matching.report import warn_empty
    from splat_framework.sfm.posing_record import posing_record, write_posing_record

    some, none = np.ones((20, 2), np.float32), np.zeros((0, 2), np.float32)
    ms = MatchSet(view_ids=[0, 1, 2], matches={(0, 1): (some, some), (0, 2): (some, some), (1, 2): (none, none)},
                  warnings={(1, 2): "left empty"})
    names = {0: "IMG_1", 1: "IMG_2", 2: "IMG_3"}
    empty = "1 of 3 pairs left empty (fewer than 8 verified matches): IMG_2-IMG_3"
    photos = ["IMG_1.jpg", "IMG_2.jpg", "IMG_3.jpg", "IMG_4.jpg"]
    monkeypatch.setenv("SPLAT_CACHE", str(seed_kernels(tmp_path / "cache")))
    process, cached = tmp_path / "my_scene", tmp_path / "cache" / "photos" / "0123abcd" / "scene"
    for scene in (process, cached):
        scene.mkdir(parents=True)
    assert posing_record(process) is None  # a scene posed elsewhere: no record

    write_posing_record(process, photos[:3], [], "sift", "incremental")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_empty(ms, names, posing_record(process))
    assert " ".join(capsys.readouterr().err.split()) == (
        f"{empty}; the poses are not affected (all 3 photos registered): those photos overlap too little for the "
        "prior's matches")

    write_posing_record(process, photos, ["IMG_4.jpg"], "sift", "incremental")
    with pytest.warns(UserWarning) as caught:
        warn_empty(ms, names, posing_record(process))
    assert [str(w.message) for w in caught] == [
        f"{empty}; the poses lack 1 of the 4 photos, not registered (left out of the scene): IMG_4.jpg; more photos "
        "overlapping them, or splat-process with --matcher aliked-lightglue or --mapper global may pose them"]
    write_posing_record(cached, photos, ["IMG_4.jpg"], "aliked-lightglue", "global")
    assert posing_record(cached).retry == "more photos overlapping them, or --photos.mapper incremental"
    write_posing_record(cached, photos, ["IMG_4.jpg"], "sift", "incremental")
    assert posing_record(cached).retry == ("more photos overlapping them, --photos.matcher aliked-lightglue, or "
                                           "--photos.mapper global")
    with pytest.warns(UserWarning) as caught:
        warn_empty(ms, names, None)
    assert [str(w.message) for w in caught] == [empty]


def test_a_run_on_photos_that_all_registered_says_the_poses_are_not_affected(noisy_scene, tmp_path):
    """The prior of a run on a scene whose ``posing.json`` says every photo registered: its pairs left
    empty are an information line, not a warning (the view without a match stays one)."""
    from splat_framework.sfm.posing_record import write_posing_record

    scene = tmp_path / "scene"
    shutil.copytree(noisy_scene, scene)
    write_posing_record(scene, [f"IMG_{k + 1}.jpg" for k in range(5)], [], "sift", "incremental")
    res = run_cli("train", "3dgs-triang", "--data", scene, "--views", "all", "--steps", "1", "--output",
                  tmp_path / "run", "--no-progress", "--model.init.matching.kind", "sift", code=0,
                  env=cli_env(SPLAT_CACHE=str(seed_kernels(tmp_path / "cache"))))
    lines = warning_lines(res.stderr)
    assert len(lines) == 1 and lines[0].startswith("warning: training view image003 has no verified match"), res.stderr
    assert ("3 of 6 pairs left empty (fewer than 8 verified matches): image001-image003, image002-image003, "
            "image003-image004; the poses are not affected (all 5 photos registered)") in " ".join(res.stderr.split())


def test_splat_match_names_the_pairs_left_empty_and_the_view_without_a_match(noisy_scene, tmp_path):
    res = run_cli("match", "--data", noisy_scene, "--views", "all", "--kind", "sift", "--out", tmp_path / "m",
                  code=0)
    lines = warning_lines(res.stderr)
    assert lines[0].startswith("warning: 3 of 6 pairs left empty") and lines[0].endswith("image003-image004"), lines
    assert lines[1].startswith("warning: training view image003 has no verified match") and len(lines) == 2, lines


def test_a_photo_left_out_is_listed_with_its_verified_matches_by_file_name():
    pairs = {("IMG_1.jpg", "IMG_2.jpg"): 300, ("IMG_1.jpg", "IMG_7.jpg"): 5, ("IMG_2.jpg", "IMG_7.jpg"): 0}
    summary = SfmSummary(images=3, registered=["IMG_1", "IMG_2"], points=10, reprojection_px=0.5, seconds=1.0,
                         mapper="incremental", pair_matches=pairs, photos=["IMG_1.jpg", "IMG_2.jpg", "IMG_7.jpg"])
    assert summary.left_out == ["IMG_7.jpg"]
    assert summary.not_registered_lines() == [
        "IMG_7.jpg not registered (left out of the scene): verified matches with IMG_1.jpg 5, IMG_2.jpg 0"]
    many = [f"IMG_{k}.jpg" for k in range(1, 15)]  # one photo left out of 14: the 13 empty pairs are counted
    summary = SfmSummary(images=14, registered=[Path(n).stem for n in many[:-1]], points=10, reprojection_px=0.5,
                         seconds=1.0, mapper="incremental", photos=many,
                         pair_matches={(a, b): 0 for k, a in enumerate(many) for b in many[k + 1:]})
    assert summary.not_registered_lines() == [
        "IMG_14.jpg not registered (left out of the scene): verified matches with the other 13 photos 0"]


def test_splat_process_lists_a_photo_that_did_not_register_with_its_verified_matches(noisy_photos, tmp_path):
    pytest.importorskip("pycolmap", reason='posing photos needs pycolmap (pip install "splat-framework[process]")')
    res = run_cli("process", "images", noisy_photos, "--out", tmp_path / "scene", "--matcher", "sift", code=0)
    assert "4 of 5 images registered" in res.stdout, res.stdout
    assert ("IMG_4.jpg not registered (left out of the scene): verified matches with IMG_1.jpg 0, IMG_2.jpg 0, "
            "IMG_3.jpg 0, IMG_5.jpg 0") in res.stdout.splitlines(), res.stdout
    assert not warning_lines(res.stderr) and not INDEX.search(res.stdout + res.stderr), res.stderr
    record = posing_record(tmp_path / "scene")  # what a run's prior says about the poses, kept beside them
    assert record.photos == [f"IMG_{k + 1}.jpg" for k in range(5)] and record.left_out == ["IMG_4.jpg"], record


def test_training_on_photos_lists_the_photo_left_out_also_from_the_cache(noisy_photos, tmp_path):
    """``splat-train --data PHOTOS``: the photo posing left out is named with its verified matches when
    the photos are posed, and again when the next run reads the poses from the cache."""
    pytest.importorskip("pycolmap", reason='posing photos needs pycolmap (pip install "splat-framework[process]")')
    photos = tmp_path / "photos"
    shutil.copytree(noisy_photos, photos)
    env = cli_env(SPLAT_CACHE=str(seed_kernels(tmp_path / "cache")))
    left_out = ("IMG_4.jpg not registered (left out of the scene): verified matches with IMG_1.jpg 0, IMG_2.jpg 0, "
                "IMG_3.jpg 0, IMG_5.jpg 0")
    for run, posing in (("run", "estimating the poses of 5 photos"), ("again", "poses from the cache")):
        res = run_cli("train", "3dgs", "--data", photos, "--steps", "1", "--output", tmp_path / run, "--no-progress",
                      "--photos.matcher", "sift", "--model.init.num-points", "300", code=0, env=env)
        out = " ".join((res.stdout + res.stderr).split())  # the console may wrap a long line
        assert posing in out and left_out in out, out
        assert ("training on all 4 views of a COLMAP scene (its default; --views N for a few-shot split): "
                "IMG_1, IMG_2, IMG_3, IMG_5") in out, out

"""Own photos in one command and self-contained run folders (issue 42): ``splat-train METHOD --data
PHOTOS`` poses the photos (cached by their contents), trains on all of a few photos and says so,
names photos and views by file name in natural order; a run folder evaluates from any folder
and shell, and one written before the record existed still evaluates and resumes."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_harness import cli_env, run_cli
from splat_framework.cameras import Camera, intrinsics
from splat_framework.config.data import PhotoPosesConfig
from splat_framework.data import describe_split
from splat_framework.data.images import list_images, natural_key
from splat_framework.data.parsers.common import find_images
from splat_framework.data.scene import DataError, SceneData
from splat_framework.data.splits import own_scene_split
from splat_framework.matching.matchset import MatchSet
from splat_framework.matching.report import warn_empty
from splat_framework.runtime.io import atomic_write_json, read_json

NAMES = ["IMG_9", "IMG_18", "IMG_27", "IMG_100"]
"""The photos' stems in natural order (plain name order would be 100, 18, 27, 9)."""


def write_photos(folder: Path, scene: Path) -> Path:
    """``folder`` holding the 4 views of a small built-in forward scene as IMG_9.png ... IMG_100.png."""
    folder.mkdir(parents=True)
    for k, name in enumerate(NAMES):
        shutil.copy(scene / "images" / f"image{k:03d}.png", folder / f"{name}.png")
    return folder


@pytest.fixture(scope="module")
def photo_run(tmp_path_factory):
    """``splat-train 3dgs --data photos`` (a relative path) on 4 photos: (its result, run folder, photos folder)."""
    pytest.importorskip("pycolmap", reason='posing photos needs pycolmap (pip install "splat-framework[process]")')
    from splat_framework.data.synthetic.generate import generate_scene

    root = tmp_path_factory.mktemp("own")
    scene = generate_scene("forward", root / "scene", width=192, height=144, n_views=4, seed=0)
    photos = write_photos(root / "photos", scene)
    env = cli_env(SPLAT_CACHE=str(root / "cache"), SPLAT_COMPILE="0")  # eager: a module fixture runs before the
    # autouse one that sets it, and a compiled run built the native kernels into this empty cache (40 s)
    res = run_cli("train", "3dgs", "--data", "photos", "--steps", "2", "--output", root / "run", "--no-progress",
                  "--photos.matcher", "sift", "--model.init.num-points", "300", code=0, cwd=root, env=env)
    return res, root / "run", photos, env


def test_a_folder_of_photos_trains_in_one_command_on_all_of_a_few(photo_run):
    res, run, _, _ = photo_run
    out = " ".join((res.stdout + res.stderr).split())
    assert "photos: estimating the poses of 4 photos (pycolmap, incremental mapper, sift matches)" in out, out
    assert "photos: 4 of 4 images registered" in out, out
    assert ("training on all 4 views of a COLMAP scene (its default; --views N for a few-shot split): IMG_9, IMG_18, "
            "IMG_27, IMG_100; nothing is held out, so the metrics are training-view metrics (--test-every K holds out "
            "every K-th image)") in out, out
    assert "train psnr" in res.stdout and "test psnr" not in res.stdout and "Training-view metrics" in out
    config = read_json(run / "config.json")["config"]
    assert config["views"] == "all"
    record = config["resolved_data"]
    assert Path(record["path"]).is_absolute() and (Path(record["path"]) / "sparse" / "0").is_dir()
    assert record["train"] == NAMES and record["test"] == []
    metrics = read_json(run / "metrics.json")
    assert [(v["view"], v["split"]) for v in metrics["per_view"]] == [(n, "train") for n in NAMES]
    assert all((run / "renders" / f"{n}_render.png").is_file() for n in NAMES)


def test_a_few_photos_give_a_held_out_figure_with_test_every(photo_run, tmp_path):
    """Issue 107: 4 photos and ``--test-every 2``: IMG_9 and IMG_27 held out and scored (a test PSNR,
    not a training-view one), the poses read from the cache, the split recorded for splat-eval."""
    _, _, photos, env = photo_run
    run = tmp_path / "run"
    res = run_cli("train", "3dgs", "--data", photos, "--test-every", "2", "--steps", "2", "--output", run,
                  "--no-progress", "--photos.matcher", "sift", "--model.init.num-points", "300", code=0, env=env)
    out = " ".join((res.stdout + res.stderr).split())
    assert "photos: poses from the cache" in out, out
    assert ("training on all 2 views of a COLMAP scene (its default; --views N for a few-shot split): IMG_18, IMG_100; "
            "2 test views held out (every 2nd image): IMG_9, IMG_27") in out, out
    assert "test psnr" in res.stdout and "train psnr" not in res.stdout and "Training-view metrics" not in out
    metrics = read_json(run / "metrics.json")
    assert [(v["view"], v["split"]) for v in metrics["per_view"]] == [("IMG_9", "test"), ("IMG_27", "test")]
    assert np.isfinite(metrics["mean"]["psnr"]) and metrics["mean"]["psnr"] > 5
    record = read_json(run / "config.json")["config"]["resolved_data"]
    assert (record["train"], record["test"]) == (["IMG_18", "IMG_100"], ["IMG_9", "IMG_27"])
    assert read_json(run / "config.json")["config"]["test_every"] == 2


def test_the_run_folder_evaluates_from_another_folder_and_shell(photo_run, tmp_path):
    """``--data photos`` was relative to the training shell's folder; splat-eval elsewhere, without
    $SPLAT_DATA, reads the recorded dataset folder and split."""
    _, run, _, env = photo_run
    env = {k: v for k, v in env.items() if k != "SPLAT_DATA"}
    res = run_cli("eval", run, "--no-renders", code=0, cwd=tmp_path, env=env)
    assert "train psnr" in res.stdout
    assert [v["view"] for v in read_json(run / "metrics.json")["per_view"]] == NAMES


def test_the_same_photos_are_posed_once_and_a_changed_photo_again(photo_run, tmp_path, monkeypatch, capsys):
    from splat_framework.data.photos import photo_source
    from splat_framework.runtime import threads
    from splat_framework.sfm.own_photos import photos_key, posed_photos

    _, run, photos, env = photo_run
    monkeypatch.setenv("SPLAT_CACHE", env["SPLAT_CACHE"])
    options = PhotoPosesConfig(matcher="sift")
    scene = posed_photos(photos, "photos", options)
    assert str(scene) == read_json(run / "config.json")["config"]["resolved_data"]["path"]
    assert "photos: poses from the cache (4 of 4 images registered" in capsys.readouterr().err
    files = list_images(photos)
    key = photos_key(files, "photos", options)
    assert photos_key(files, "photos", PhotoPosesConfig(matcher="sift", mapper="global")) != key
    assert photos_key(files, "photos", PhotoPosesConfig(matcher="sift", frames=5)) == key  # frames: videos only
    assert photos_key(files, "photos", PhotoPosesConfig(matcher="sift", pairs="exhaustive")) != key
    cores = threads.machine_thread_count()
    with monkeypatch.context() as m:
        m.setattr(threads, "machine_thread_count", lambda: cores + 1)
        assert photos_key(files, "photos", options) != key  # posed on another core count: other matches
    changed = tmp_path / "changed"
    shutil.copytree(photos, changed)
    (changed / "IMG_27.png").write_bytes((changed / "IMG_27.png").read_bytes() + b"\0")
    assert photos_key(list_images(changed), "photos", options) != key
    assert photo_source(photos) == "photos" and photo_source(scene) is None  # a posed scene is a dataset
    (tmp_path / "clip.mp4").write_bytes(b"")
    assert photo_source(tmp_path / "clip.mp4") == "video" and photo_source(tmp_path / "notes.txt") is None


@pytest.mark.bad_input("a photo-pose cache entry edited by hand (a pose, an image painted or emptied, a file added or removed)",
                       "posed again, with one warning line naming the file")
@pytest.mark.parametrize("tamper", ["pose", "image", "emptied"])  # an added file: test_trusted_caches
def test_an_edited_cache_entry_is_posed_again_with_one_line_naming_the_file(photo_run, tmp_path, monkeypatch,
                                                                          capsys, tamper):
    """Issue 60: the cached entry's manifest covers poses, images and matches; an entry edited by
    hand (a moved pose, a painted or emptied image) is posed again, never used."""
    from splat_framework.sfm.own_photos import posed_photos

    _, _, photos, env = photo_run
    cache = tmp_path / "cache"
    shutil.copytree(env["SPLAT_CACHE"], cache)
    monkeypatch.setenv("SPLAT_CACHE", str(cache))
    (entry,) = (cache / "photos").iterdir()
    scene = entry / "scene"
    edited = {"pose": scene / "sparse" / "0" / "images.bin", "image": scene / "images" / "IMG_27.png",
              "emptied": scene / "images" / "IMG_18.png"}[tamper]
    if tamper == "pose":
        data = bytearray(edited.read_bytes())
        data[-20] ^= 0x40  # one byte of the sparse model (poses and their points)
        edited.write_bytes(bytes(data))
    elif tamper == "image":
        import cv2

        img = cv2.imread(str(edited))
        img[:] = (0, 0, 255)
        cv2.imwrite(str(edited), img)
    else:
        edited.write_bytes(b"")
    capsys.readouterr()
    with pytest.warns(UserWarning) as caught:
        posed_photos(photos, "photos", PhotoPosesConfig(matcher="sift"))
    err = capsys.readouterr().err
    (line,) = [str(w.message) for w in caught if "cached poses not used" in str(w.message)]
    assert line.startswith(f"{photos}: cached poses not used ({edited}: ") and line.endswith("estimating them again")
    assert "poses from the cache" not in err and f"poses cached for the next run in {entry}" in err
    assert posed_photos(photos, "photos", PhotoPosesConfig(matcher="sift")) == scene  # whole again: used
    assert "poses from the cache" in capsys.readouterr().err


def test_a_failed_posing_leaves_no_entry_and_does_not_say_cached(photo_run, tmp_path, monkeypatch, capsys):
    import splat_framework.sfm.reconstruct as reconstruct
    from splat_framework.errors import DataError
    from splat_framework.sfm.own_photos import posed_photos

    _, _, photos, _ = photo_run
    monkeypatch.setenv("SPLAT_CACHE", str(tmp_path / "cache"))

    asked = {}

    def fail(images, out, **kwargs):
        asked.update(kwargs)
        (Path(out) / "sparse").mkdir(parents=True)  # half a scene, then the failure
        raise DataError("photos: only 1 of 4 images registered")

    monkeypatch.setattr(reconstruct, "estimate_scene", fail)
    with pytest.raises(DataError):
        posed_photos(photos, "photos", PhotoPosesConfig(matcher="sift", pairs="exhaustive"))
    assert asked["pairs"] == "exhaustive" and asked["matcher"] == "sift"  # the options reach the posing
    assert "cached" not in capsys.readouterr().err
    assert [p for p in (tmp_path / "cache" / "photos").rglob("*")] == []


def test_a_run_folder_from_before_the_record_evaluates_and_resumes(photo_run, tmp_path, monkeypatch):
    """config.json as written before it recorded the dataset (no ``resolved_data``, no ``photos``): the
    run resolves ``data`` under $SPLAT_DATA as it did then, evaluates and resumes."""
    from splat_framework.cli.eval import EvalArgs, evaluate_run
    from splat_framework.config import TrainConfig
    from splat_framework.engine.trainer import Trainer

    _, _, photos, env = photo_run
    monkeypatch.setenv("SPLAT_CACHE", env["SPLAT_CACHE"])
    monkeypatch.setenv("SPLAT_DATA", str(photos.parent))  # the fixture's LLFF scene is "scene" under it
    run = tmp_path / "old"

    def config(**kw) -> TrainConfig:
        return TrainConfig(data="scene", output=run, progress=False, save_renders=False, compile=False,
                           model={"init": {"kind": "random", "num_points": 300}}, **kw)

    Trainer(config(steps=2)).train()
    payload = read_json(run / "config.json")
    assert payload["config"]["resolved_data"]["train"] == ["image001", "image002", "image003"]
    for key in ("resolved_data", "photos"):
        payload["config"].pop(key)
    atomic_write_json(run / "config.json", payload)  # signed, as the older version signed it
    metrics = evaluate_run(EvalArgs(run_dir=run, renders=False))
    assert [v["view"] for v in metrics["per_view"]] == ["image000"]
    resumed = Trainer(config(steps=2, resume=True))  # the resume check accepts the old config.json
    try:
        assert resumed.restore() and resumed.start_step == 2
        assert resumed.config.resolved_data.test == ["image000"]  # recorded when it writes config.json again
    finally:
        resumed.release()


def test_photos_are_listed_in_natural_order_and_llff_dtu_keep_name_order(tmp_path):
    for name in ("IMG_100.png", "IMG_18.png", "img_9.png", "IMG_009.png", "a.png"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in list_images(tmp_path)] == ["a.png", "IMG_009.png", "img_9.png", "IMG_18.png", "IMG_100.png"]
    assert sorted(["frame10", "frame9", "frame100"], key=natural_key) == ["frame9", "frame10", "frame100"]
    # LLFF's poses_bounds.npy rows and DTU's world_mat_i follow plain name order: the pairing stays
    assert [p.name for p in find_images(tmp_path)] == ["IMG_009.png", "IMG_100.png", "IMG_18.png", "a.png", "img_9.png"]


def _scene(n: int, views) -> SceneData:
    cams = [Camera(K=intrinsics(4.0, 4.0, 2.0, 2.0), world_to_cam=torch.eye(4), width=4, height=4, name=f"IMG_{k + 1}")
            for k in range(n)]
    train, test = own_scene_split(n, views)
    return SceneData(root=Path("."), format="colmap", cameras=cams, image_paths=[Path(f"IMG_{k + 1}.png") for k in range(n)],
                     train_indices=train, test_indices=test)


def test_more_photos_say_which_train_and_which_test_by_name():
    assert describe_split(_scene(10, "all"), "all") == (
        "training on all 8 views of a COLMAP scene (its default; --views N for a few-shot split): IMG_2, IMG_3, "
        "IMG_4, IMG_5, IMG_6, IMG_7, IMG_8, IMG_10; 2 test views held out (every 8th image): IMG_1, IMG_9")
    assert describe_split(_scene(8, "all"), "all").startswith("training on all 8 views of a COLMAP scene (its default; "
                                                              "--views N for a few-shot split): IMG_1, ")
    assert describe_split(_scene(20, "all"), "all") == (  # more than 8: counted, not named
        "training on all 17 views of a COLMAP scene (its default; --views N for a few-shot split); "
        "3 test views held out (every 8th image): IMG_1, IMG_9, IMG_17")
    assert describe_split(_scene(3, 3), 3) == ("training on 3 views of a COLMAP scene: IMG_1, IMG_2, IMG_3; nothing is "
                                               "held out, so the metrics are training-view metrics (--test-every K "
                                               "holds out every K-th image)")
    benchmark = _scene(10, 3)
    benchmark.format = "llff"
    assert describe_split(benchmark, 3) is None


def test_photos_are_held_out_at_any_count_with_test_every():
    """``--test-every K``: every K-th photo (the first, the K+1-th, ...) is a test view, also of 8
    photos or fewer; the line names the rule and the photos; a benchmark split by it says so too;
    Blender's and DTU's protocol lists are not replaced."""
    from splat_framework.data.run_data import every_kth_split

    few = every_kth_split(_scene(8, "all"), 3, "all")
    assert few.test_indices == [0, 3, 6] and few.train_indices == [1, 2, 4, 5, 7]
    assert describe_split(few, "all", 3) == (
        "training on all 5 views of a COLMAP scene (its default; --views N for a few-shot split): IMG_2, IMG_3, "
        "IMG_5, IMG_6, IMG_8; 3 test views held out (every 3rd image): IMG_1, IMG_4, IMG_7")
    two = every_kth_split(_scene(4, "all"), 2, 1)
    assert (two.train_indices, two.test_indices) == ([1], [0, 2])
    assert describe_split(two, 1, 2) == ("training on 1 view of a COLMAP scene: IMG_2; 2 test views held out "
                                         "(every 2nd image): IMG_1, IMG_3")
    assert every_kth_split(few, None, "all") is few
    llff = _scene(10, 3)
    llff.format = "llff"
    assert describe_split(every_kth_split(llff, 5, 3), 3, 5).endswith("2 test views held out (every 5th image): IMG_1, IMG_6")
    blender = _scene(10, "all")
    blender.format = "blender"
    with pytest.raises(DataError, match="--test-every holds out every K-th image of LLFF, COLMAP and transforms.json"):
        every_kth_split(blender, 2, "all")
    with pytest.raises(DataError, match="views=4 is more than the 2 images"):
        every_kth_split(_scene(4, "all"), 2, 4)


def test_a_training_view_without_any_verified_match_is_named():
    empty = np.zeros((0, 2), np.float32)
    some = np.ones((20, 2), np.float32)
    ms = MatchSet(view_ids=[0, 4, 9], matches={(0, 4): (some, some), (0, 9): (empty, empty), (4, 9): (empty, empty)})
    with pytest.warns(UserWarning, match="training view IMG_52 has no verified match with any other training view"):
        warn_empty(ms, {0: "IMG_18", 4: "IMG_9", 9: "IMG_52"})
    assert ms.unmatched_views() == [9]


@pytest.mark.bad_input("`splat-train --data` a folder that is neither a dataset nor photos", "exit 2, one line pointing at splat-process")
def test_a_folder_that_is_neither_a_dataset_nor_photos_points_at_splat_process(tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("hi")
    run_cli("train", "3dgs", "--data", tmp_path / "notes", "--output", tmp_path / "run", code=2,
            match=("neither a dataset", "nor a folder of photos", "splat-process"), watch=[tmp_path / "notes"])


def test_two_runs_posing_the_same_photos_at_once_both_finish(photo_run, tmp_path):
    """Two runs pose the same photos at the same time (two terminals, a sweep): the one that finishes
    second finds the first one's entry in place; it keeps it when it verifies (found by the
    first-hour benchmark: ``OSError: Directory not empty`` and a traceback before), and never keeps
    one that does not verify."""
    from splat_framework.runtime.trusted import write_folder_manifest
    from splat_framework.sfm.own_photos import _install_private

    _, _, _, env = photo_run
    cache = tmp_path / "cache"
    shutil.copytree(env["SPLAT_CACHE"], cache)
    (entry,) = (cache / "photos").iterdir()
    built = tmp_path / "built"  # what the second run built: the same files
    shutil.copytree(entry, built)
    before = sorted(p.relative_to(entry) for p in entry.rglob("*"))
    second = tmp_path / "second-work"
    shutil.copytree(built, second)
    _install_private(second, entry)  # the first one's entry stands
    assert sorted(p.relative_to(entry) for p in entry.rglob("*")) == before
    (entry / "scene" / "stray.txt").write_text("not in the manifest")
    third = tmp_path / "third-work"
    shutil.copytree(built, third)
    write_folder_manifest(third)
    with pytest.raises(OSError):
        _install_private(third, entry)

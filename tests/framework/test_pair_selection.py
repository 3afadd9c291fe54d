"""The posing's chosen pairs (``sfm.pair_selection``): every pair of a small set; above 10 photos
each photo's nearest by a vocabulary built from the photos themselves, and a clip's neighbours in
time; the matching and COLMAP see only those pairs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from splat_framework.sfm.pair_selection import (
    EXHAUSTIVE_MAX_PHOTOS,
    RETRIEVAL_NEIGHBOURS,
    SEQUENTIAL_NEIGHBOURS,
    all_pairs,
    choose_pairs,
    pairs_from_similarity,
)


def _crops(seed: int, n: int, size=(240, 320)) -> list[np.ndarray]:
    """``n`` overlapping views of one random texture: crops sliding across it."""
    rng = np.random.default_rng(seed)
    texture = (rng.random((size[0] // 4, (size[1] + 40 * n) // 4)) * 255).astype(np.uint8)
    texture = cv2_resize(texture, (size[1] + 40 * n, size[0]))
    return [np.repeat(texture[:, 40 * k: 40 * k + size[1], None], 3, axis=2) for k in range(n)]


def cv2_resize(a, wh):
    import cv2

    return cv2.resize(a, wh, interpolation=cv2.INTER_CUBIC)


def test_a_small_set_matches_every_pair():
    images = _crops(0, EXHAUSTIVE_MAX_PHOTOS)
    assert choose_pairs(images) == all_pairs(EXHAUSTIVE_MAX_PHOTOS) and len(all_pairs(10)) == 45


def test_nearest_photos_by_the_similarity_and_a_clips_neighbours_in_time():
    n = 14
    sim = -np.abs(np.subtract.outer(np.arange(n), np.arange(n))).astype(float)  # nearer in order: more alike
    pairs = pairs_from_similarity(sim, neighbours=2)
    assert (0, 1) in pairs and (0, 2) in pairs and (0, 3) not in pairs and len(pairs) == len(set(pairs))
    assert all(a < b for a, b in pairs) and pairs == sorted(pairs)
    far = pairs_from_similarity(np.eye(n), ordered=True, neighbours=1)
    assert {(i, i + k) for i in range(n - SEQUENTIAL_NEIGHBOURS) for k in range(1, SEQUENTIAL_NEIGHBOURS + 1)} <= set(far)


def test_the_vocabulary_pairs_photos_of_the_same_place():
    """Two places, 6 photos of each (crops of two textures): every photo's nearest photos are of its
    own place, so no pair joins the places while each place is connected."""
    a, b = _crops(1, 6), _crops(2, 6)
    pairs = choose_pairs(a + b, neighbours=RETRIEVAL_NEIGHBOURS)
    assert pairs and all((i < 6) == (j < 6) for i, j in pairs), pairs
    assert len(pairs) < len(all_pairs(12))


def test_the_matching_takes_only_the_chosen_pairs():
    from splat_framework.config import match_config
    from splat_framework.matching import compute_matches

    images = _crops(3, 4, size=(96, 128))
    cfg = match_config("dense", cache=False)
    chosen = compute_matches(images, None, [0, 1, 2, 3], cfg, pairs=[(2, 1), (0, 3)])
    assert chosen.pairs() == [(0, 3), (1, 2)]
    every = compute_matches(images, None, [0, 1, 2, 3], cfg)
    assert len(every.pairs()) == 6 and chosen.meta["cache_key"] != every.meta["cache_key"]
    assert np.array_equal(chosen.get(1, 2)[0], every.get(1, 2)[0])  # a pair's matches do not depend on the others
    with pytest.raises(ValueError, match="name views that are not among"):
        compute_matches(images, None, [0, 1, 2, 3], cfg, pairs=[(0, 9)])


def test_a_matcher_without_a_pairs_parameter_has_the_others_dropped():
    from splat_framework.sfm.photo_matchers import run_matcher

    def every_pair(images):
        return {(i, j): (np.zeros((1, 2)), np.zeros((1, 2))) for i, j in all_pairs(len(images))}

    def with_pairs(images, pairs=None):
        return {p: (np.zeros((1, 2)), np.zeros((1, 2))) for p in pairs}

    assert sorted(run_matcher(every_pair, [0] * 5, [(0, 1), (2, 4)])) == [(0, 1), (2, 4)]
    assert sorted(run_matcher(with_pairs, [0] * 5, [(1, 3)])) == [(1, 3)]


@pytest.mark.slow
def test_sixteen_photos_pose_on_chosen_pairs_to_the_true_poses(tmp_path, monkeypatch):
    """The built-in forward scene's 16 photos with SIFT: the chosen pairs (fewer than half of the 120)
    register every photo, with the true poses (after a similarity transform); that they register as
    many photos as every pair does, the next test shows on real photos."""
    pytest.importorskip("pycolmap", reason='posing needs pycolmap (pip install "splat-framework[process]")')
    from splat_framework.data.parsers.colmap import load_colmap
    from splat_framework.data.parsers.llff import load_llff
    from splat_framework.data.synthetic import ensure_scene
    from splat_framework.sfm import camera_centers, estimate_scene, reconstruct, sim3_errors

    forward = load_llff(ensure_scene("forward"))
    idx = np.linspace(0, len(forward.image_paths) - 1, 16).round().astype(int)
    photos = [Path(forward.image_paths[i]) for i in idx]
    picked = []
    monkeypatch.setattr(reconstruct, "choose_pairs", lambda rgb, ordered=False: picked.extend(choose_pairs(rgb)) or picked)
    chosen = estimate_scene(photos, tmp_path / "chosen")
    assert 16 <= len(picked) < len(all_pairs(16)) / 2
    assert sum(n > 0 for n in chosen.pair_matches.values()) <= len(picked)  # COLMAP matched only those
    assert len(chosen.registered) == 16
    est = load_colmap(tmp_path / "chosen")
    true_w2c = np.stack([forward.cameras[i].world_to_cam.double().numpy() for i in idx])
    rot_deg, center_err = sim3_errors(np.stack([c.world_to_cam.double().numpy() for c in est.cameras]), true_w2c)
    true_c = camera_centers(true_w2c)
    assert rot_deg.max() < 1.0 and center_err.max() < 0.01 * np.linalg.norm(true_c.max(0) - true_c.min(0))


@pytest.mark.slow
def test_fern_photos_as_a_plain_folder_register_on_chosen_pairs_as_on_every_pair(tmp_path):
    """Issue 83, on real photos: 16 of fern's 20 images (evenly spaced) as a plain folder, posed with
    SIFT on the chosen pairs, register as many photos as on every pair, and 8 of them (every pair
    below the threshold) all register."""
    from support import DATA

    folder = DATA / "llff" / "fern" / "images_8"
    if not folder.is_dir():
        pytest.skip(f"needs the LLFF fern photos ({folder}; set $SPLAT_DATA)")
    pytest.importorskip("pycolmap", reason='posing needs pycolmap (pip install "splat-framework[process]")')
    from splat_framework.sfm import estimate_scene

    images = sorted(folder.glob("*.png"))
    photos = [images[int(i)] for i in np.linspace(0, len(images) - 1, 16).round()]
    chosen = estimate_scene(photos, tmp_path / "chosen")
    every = estimate_scene(photos, tmp_path / "every", pairs="exhaustive")
    matched = sum(n > 0 for n in chosen.pair_matches.values())
    assert matched < len(all_pairs(16)) * 0.6 < sum(n > 0 for n in every.pair_matches.values()), matched
    assert len(chosen.registered) == len(every.registered) >= 14, (chosen.registered, every.registered)
    eight = estimate_scene(photos[::2], tmp_path / "eight")
    assert len(eight.registered) == 8


@pytest.mark.bad_input("a folder whose photos form two groups with no verified match between them",
                       "one line naming both groups by file name and which one was posed, then one line per photo left out")
def test_two_groups_of_photos_are_named_with_the_one_posed():
    from splat_framework.sfm.reconstruct import SfmSummary

    photos = ["a.jpg", "b.jpg", "c.jpg", "d.jpg", "e.jpg", "lone.jpg"]
    counts = {(x, y): 0 for i, x in enumerate(photos) for y in photos[i + 1:]}
    counts |= {("a.jpg", "b.jpg"): 300, ("b.jpg", "c.jpg"): 120, ("d.jpg", "e.jpg"): 200}
    summary = SfmSummary(images=6, registered=["a", "b", "c"], points=500, reprojection_px=0.5, seconds=1.0,
                         mapper="incremental", pair_matches=counts, photos=photos)
    assert summary.groups() == [["a.jpg", "b.jpg", "c.jpg"], ["d.jpg", "e.jpg"], ["lone.jpg"]]
    lines = summary.not_registered_lines()
    assert lines[0] == ("the photos form 2 groups with no verified match between them: a.jpg, b.jpg, c.jpg "
                        "(posed: the scene) and d.jpg, e.jpg (left out); photos of one place, each overlapping "
                        "others, pose as one")
    assert [line.split()[0] for line in lines[1:]] == ["d.jpg", "e.jpg", "lone.jpg"]
    one = SfmSummary(images=3, registered=["a", "b"], points=5, reprojection_px=0.5, seconds=1.0, mapper="incremental",
                     pair_matches={("a.jpg", "b.jpg"): 50, ("a.jpg", "c.jpg"): 0, ("b.jpg", "c.jpg"): 0},
                     photos=["a.jpg", "b.jpg", "c.jpg"])
    assert one.groups_line() is None and len(one.not_registered_lines()) == 1


def test_an_unknown_pair_choice_is_one_line_before_any_work(tmp_path):
    """(On the command line tyro refuses it: ``--pairs: 'every' is not one of auto, exhaustive``.)"""
    from splat_framework.errors import DataError
    from splat_framework.sfm import estimate_scene

    with pytest.raises(DataError, match=r"^--pairs must be one of auto, exhaustive, got 'every'$"):
        estimate_scene([tmp_path / "a.png", tmp_path / "b.png"], tmp_path / "out", pairs="every")

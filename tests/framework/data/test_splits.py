"""Few-shot split rules (see ../shared/data/README.md)."""

from __future__ import annotations

import pytest

from splat_framework.data import DataError, load_scene
from splat_framework.data.splits import (
    BLENDER_DIETNERF_8,
    DTU_TEST,
    blender_split,
    check_views,
    dtu_split,
    linspace_pick,
    llff_split,
    own_scene_split,
)
from support import DATA


def test_llff_fern_protocol_numbers():
    train, test = llff_split(20, 3)
    assert train == [1, 10, 19]
    assert test == [0, 8, 16]
    # the 2- and 5-view rows of the literature (RegNeRF's np.round(np.linspace(0, 16, k)) over
    # the 17 non-test images): fern's images 1 and 19; 1, 5, 10, 14 and 19
    assert llff_split(20, 2) == ([1, 19], [0, 8, 16])
    assert llff_split(20, 5) == ([1, 5, 10, 14, 19], [0, 8, 16])


def test_own_scene_with_too_few_photos_trains_on_all_of_them():
    assert own_scene_split(3, 3) == ([0, 1, 2], [])  # holding out photo 0 would leave 2 < 3
    assert own_scene_split(2, 2) == ([0, 1], [])
    assert own_scene_split(3, 2) == llff_split(3, 2) == ([1, 2], [0])  # enough: the usual hold-out
    assert own_scene_split(20, 3) == llff_split(20, 3)
    assert own_scene_split(3, "all") == ([0, 1, 2], [])  # a few photos of one's own: all of them train
    assert own_scene_split(8, "all") == (list(range(8)), [])
    assert own_scene_split(9, "all") == llff_split(9, "all") == ([1, 2, 3, 4, 5, 6, 7], [0, 8])
    with pytest.raises(DataError, match="views=4"):
        own_scene_split(3, 4)


def test_llff_rules():
    train, test = llff_split(20, "all")
    assert test == [0, 8, 16]
    assert train == [i for i in range(20) if i % 8]
    # banker's rounding: linspace(0, 16, 5) = 0, 4, 8, 12, 16; linspace(0, 16, 6) has .2/.4/.6/.8 only
    rest = [i for i in range(20) if i % 8]
    assert llff_split(20, 6)[0] == [rest[round(x)] for x in (0, 3.2, 6.4, 9.6, 12.8, 16)]
    # .5 cases round to even: linspace(0, 3, 3) = 0, 1.5, 3 -> positions 0, 2, 3
    assert linspace_pick([10, 11, 12, 13], 3) == [10, 12, 13]
    assert linspace_pick([10, 11, 12, 13, 14, 15], 3) == [10, 12, 15]  # 2.5 -> 2
    assert llff_split(20, 1)[0] == [1]
    assert llff_split(20, 17)[0] == rest


def test_views_larger_than_pool():
    with pytest.raises(DataError, match="views=18 is more than the 17"):
        llff_split(20, 18)
    with pytest.raises(DataError, match="views=11"):
        blender_split(range(10), range(10, 20), 11)
    with pytest.raises(DataError, match="views=25"):
        dtu_split(49, 25)


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "many", None])
def test_check_views_rejects(bad):
    with pytest.raises(DataError, match="views"):
        check_views(bad)


def test_check_views_accepts():
    assert check_views("all") == "all" and check_views(3) == 3 and check_views("4") == 4


def test_blender_rules():
    train, test = blender_split(range(100), range(100, 300), 8)
    assert train == BLENDER_DIETNERF_8
    assert test == list(range(100, 300, 8)) and len(test) == 25
    train4, _ = blender_split(range(100), range(100, 300), 4)
    assert train4 == [0, 33, 66, 99]
    small, _ = blender_split(range(20), range(20, 30), 8)  # < 94 frames -> linspace
    assert small == linspace_pick(list(range(20)), 8)
    assert blender_split(range(100), range(100, 300), "all")[0] == list(range(100))


def test_dtu_rules():
    train, test = dtu_split(49, 3)
    assert train == [25, 22, 28] and test == DTU_TEST
    assert dtu_split(49, 9)[0] == [25, 22, 28, 40, 44, 48, 0, 8, 13]
    all_train, _ = dtu_split(49, "all")
    assert sorted(all_train + test) == list(range(49)) and len(all_train) == 24
    assert not set(dtu_split(49, 12)[0]) & set(test)


@pytest.mark.integration
def test_fern_split_on_real_data():
    fern = DATA / "llff" / "fern"
    if not (fern / "poses_bounds.npy").is_file():
        pytest.skip(f"real data not found at {fern} (set SPLAT_DATA to ../shared/data)")
    scene = load_scene(fern, views=3)
    assert scene.train_indices == [1, 10, 19]
    assert scene.test_indices == [0, 8, 16]
    assert [scene.image_paths[i].name for i in scene.train_indices] == ["image001.png", "image010.png", "image019.png"]

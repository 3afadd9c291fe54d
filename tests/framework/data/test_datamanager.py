"""DataManager: decoding, seeded training order, masks/depths, lazy mode."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from splat_framework.data import DataError, DataManager, load_image, load_scene
from splat_framework.data.images import read_image_size
from support import make_blender, make_dtu, make_llff, write_png


@pytest.fixture
def llff_scene(tmp_path):
    return load_scene(make_llff(tmp_path / "llff", 10, depths=True), views=4)


def test_decodes_train_and_test_once(llff_scene, monkeypatch):
    calls = []
    import splat_framework.data.datamanager as dm_mod

    real = dm_mod.load_image
    monkeypatch.setattr(dm_mod, "load_image", lambda p, **kw: calls.append(p) or real(p, **kw))
    dm = DataManager(llff_scene)
    used = set(llff_scene.train_indices) | set(llff_scene.test_indices)
    assert len(calls) == len(used) == 6
    for step in range(20):
        dm.next_train(step)
    dm.eval_views()
    assert len(calls) == 6


def test_batch_contents(llff_scene):
    dm = DataManager(llff_scene)
    cam, batch = dm.next_train(0)
    i = batch["index"]
    assert i in llff_scene.train_indices and cam.name == llff_scene.cameras[i].name
    img = batch["image"]
    assert img.shape == (12, 16, 3) and img.dtype == torch.float32
    expect = cv2.imread(str(llff_scene.image_paths[i]))[:, :, ::-1].astype(np.float32) / 255
    assert np.allclose(img.numpy(), expect, atol=1e-6)
    assert batch["depth"].shape == (12, 16, 1) and float(batch["depth"].mean()) == pytest.approx(5.0)
    assert "mask" not in batch
    evals = dm.eval_views()
    assert [b["index"] for _, b in evals] == llff_scene.test_indices == [0, 8]
    assert [b["index"] for _, b in dm.train_views()] == llff_scene.train_indices


def test_training_batches_carry_their_position_in_the_training_split(llff_scene):
    dm = DataManager(llff_scene, seed=3)
    assert [b["train_position"] for _, b in dm.train_views()] == list(range(len(llff_scene.train_indices)))
    for step in range(2 * len(llff_scene.train_indices)):
        cam, batch = dm.next_train(step)
        assert llff_scene.train_indices[batch["train_position"]] == batch["index"]
        assert cam is dm.train_cameras[batch["train_position"]] or cam.name == dm.train_cameras[batch["train_position"]].name
    assert all("train_position" not in b for _, b in dm.eval_views())  # a test view has no training position


def test_training_order_epochs_and_resume(llff_scene):
    dm = DataManager(llff_scene, seed=7)
    seq = [dm.next_train(s)[1]["index"] for s in range(40)]
    n = len(llff_scene.train_indices)
    for e in range(40 // n):  # every epoch is a permutation of the training views
        assert sorted(seq[e * n : (e + 1) * n]) == sorted(llff_scene.train_indices)
    assert len({tuple(seq[e * n : (e + 1) * n]) for e in range(10)}) > 1  # reshuffled
    # resuming at step s gives the same views, regardless of call history
    dm2 = DataManager(llff_scene, seed=7)
    assert [dm2.next_train(s)[1]["index"] for s in range(23, 40)] == seq[23:]
    assert [dm2.next_train(s)[1]["index"] for s in (5, 3, 38, 0)] == [seq[5], seq[3], seq[38], seq[0]]
    other = DataManager(llff_scene, seed=8)
    assert [other.next_train(s)[1]["index"] for s in range(40)] != seq


def test_blender_white_background(tmp_path):
    root = make_blender(tmp_path / "b", 3, 3, size=8)
    # frame 0: fully transparent -> white after compositing
    arr = np.zeros((8, 8, 4), np.uint8)
    cv2.imwrite(str(root / "train" / "r_0.png"), arr)
    scene = load_scene(root)
    dm = DataManager(scene)
    batch = dm.batch(0)
    assert batch["image"].shape == (4, 4, 3)
    assert torch.allclose(batch["image"], torch.ones(4, 4, 3))


def test_alpha_of_rgba_images_only(tmp_path):
    """DataManager.alpha: an RGBA image's own alpha at the training size; None for RGB and for DTU's eval masks."""
    root = make_blender(tmp_path / "b", 3, 3, size=8)
    arr = np.full((8, 8, 4), 200, np.uint8)
    arr[:, :4, 3] = 0  # left half transparent
    cv2.imwrite(str(root / "train" / "r_0.png"), arr)
    dm = DataManager(load_scene(root))
    a = dm.alpha(0)
    assert a.shape == (4, 4) and a.dtype == np.float32
    assert np.allclose(a[:, :2], 0.0) and np.allclose(a[:, 2:], 200 / 255)
    assert DataManager(load_scene(make_dtu(tmp_path / "d", 49), views=3)).alpha(0) is None


def test_dtu_masks(tmp_path):
    scene = load_scene(make_dtu(tmp_path / "d", 49), views=3)
    dm = DataManager(scene)
    cam, batch = dm.next_train(0)
    m = batch["mask"]
    assert m.shape == (12, 16, 1)
    assert set(m.unique().tolist()) == {0.0, 1.0}
    assert m[6, 8, 0] == 1.0 and m[0, 0, 0] == 0.0
    assert len(dm.eval_views()) == 25


def test_dark_backdrop_rule():
    """Dark and dark over the run above it (1/6 of the height): backdrop; a dark patch under a bright row is not."""
    from splat_framework.data.images import dark_backdrop_mask

    img = np.full((24, 5, 3), 0.5, np.float32)
    img[:12] = 0.05  # unlit backdrop on top
    img[20:23, 1] = 0.0  # a dark object part lower down: 3 dark rows under a bright one
    img[0:3, 4] = 0.2  # bright enough (> 30/255) at the top of the last column
    m = dark_backdrop_mask(img)  # run = 4 rows
    assert m[:12, :4].all() and not m[12:].any()
    assert not m[:6, 4].any() and m[6:12, 4].all()  # rows 3-5 have a bright pixel within their run
    assert dark_backdrop_mask(img, run=1.0)[:12, :4].all()  # the window is clipped at the top edge


def test_backdrop_only_on_scenes_that_declare_one(tmp_path):
    """DTU training batches carry the backdrop mask of their own image when asked; test views
    and LLFF batches never do."""
    from splat_framework.data.images import dark_backdrop_mask

    root = make_dtu(tmp_path / "d", 49)
    for i in (22, 25, 28):  # the training views: a black band on top
        img = cv2.imread(str(root / "images_4" / f"{i:06d}.png"))
        img[:5] = 0
        cv2.imwrite(str(root / "images_4" / f"{i:06d}.png"), img)
    assert "backdrop" not in DataManager(load_scene(root, views=3)).next_train(0)[1]  # not asked for
    dm = DataManager(load_scene(root, views=3), fields={"backdrop"})
    assert "backdrop" not in dm.batch(dm.test_indices[0])
    _, batch = dm.next_train(0)
    expect = dark_backdrop_mask(batch["image"].numpy())
    assert batch["backdrop"].shape == (12, 16, 1) and expect[:5].all()
    assert torch.equal(batch["backdrop"][..., 0].bool(), torch.from_numpy(expect))
    llff = DataManager(load_scene(make_llff(tmp_path / "l", 10), views=3), fields={"backdrop"})
    assert "backdrop" not in llff.next_train(0)[1]


def test_memory_budget_lazy(llff_scene):
    eager = DataManager(llff_scene)
    lazy = DataManager(llff_scene, memory_budget_bytes=100)
    assert lazy.lazy and not eager.lazy and not lazy._cache
    for s in range(8):
        ce, be = eager.next_train(s)
        cl, bl = lazy.next_train(s)
        assert be["index"] == bl["index"] and torch.equal(be["image"], bl["image"])


def test_mixed_image_sizes(tmp_path):
    root = make_llff(tmp_path / "s", 10)
    scene = load_scene(root)
    bad = scene.image_paths[scene.train_indices[1]]
    write_png(bad, 20, 15)  # now differs from its camera
    with pytest.raises(DataError, match=bad.name):
        DataManager(scene)


def test_image_loader_formats(tmp_path):
    # 16-bit RGB
    a16 = np.zeros((4, 5, 3), np.uint16)
    a16[..., 2] = 65535  # BGR: red channel full
    cv2.imwrite(str(tmp_path / "a16.png"), a16)
    img = load_image(tmp_path / "a16.png")
    assert img.shape == (4, 5, 3) and np.allclose(img[..., 0], 1) and np.allclose(img[..., 1:], 0)
    # gray
    cv2.imwrite(str(tmp_path / "g.png"), np.full((4, 5), 128, np.uint8))
    assert np.allclose(load_image(tmp_path / "g.png"), 128 / 255)
    # RGBA half transparent on black / white
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[..., 3] = 255
    rgba[:, :2, 3] = 0
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    assert np.allclose(load_image(tmp_path / "a.png")[:, :2], 0)
    assert np.allclose(load_image(tmp_path / "a.png", white_background=True)[:, :2], 1)
    # INTER_AREA downscale: exact 2x2 block averages
    blk = np.arange(16, dtype=np.uint8).reshape(4, 4) * 10
    cv2.imwrite(str(tmp_path / "b.png"), blk)
    small = load_image(tmp_path / "b.png", scale=0.5)
    assert small.shape == (2, 2, 3)
    assert np.allclose(small[0, 0, 0], blk[:2, :2].mean() / 255, atol=1e-6)
    # JPEG header size
    cv2.imwrite(str(tmp_path / "j.jpg"), np.zeros((7, 9, 3), np.uint8))
    assert read_image_size(tmp_path / "j.jpg") == (9, 7)
    assert load_image(tmp_path / "j.jpg").shape == (7, 9, 3)


def test_device_and_cameras(llff_scene):
    dm = DataManager(llff_scene, device=torch.device("cpu"))
    cam, batch = dm.next_train(3)
    assert cam.device.type == "cpu" and batch["image"].device.type == "cpu"
    assert len(dm.train_cameras) == dm.num_train == 4 and dm.num_eval == 2


def test_the_fields_asked_for_may_be_any_iterable(tmp_path):
    """``fields`` is read twice (checked, then used): a generator asking for the backdrop still gets it."""
    dm = DataManager(load_scene(make_dtu(tmp_path / "scan", 49), views=3), fields=(f for f in ["backdrop"]))
    assert "backdrop" in dm.next_train(0)[1]

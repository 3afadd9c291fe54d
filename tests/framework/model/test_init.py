"""Random initialisation of 3DGS: the reference's grey box and our frustum sampling."""

from __future__ import annotations

import pytest
import torch

from splat_framework.cameras import Camera
from splat_framework.config import apply_overrides
from splat_framework.data import DataManager, load_scene
from splat_framework.data.synthetic import generate_scene
from splat_framework.model.gaussians import (
    GaussianModel,
    frustum_box,
    knn_scale,
    random_init,
    sample_box_points,
    sample_frustum_points,
)
from splat_framework.registry import get_method


def _camera_at_origin() -> Camera:
    """Looks down +z; 2x2 pixels, focal 1, principal point (1, 1), depths [1, 2]."""
    K = torch.tensor([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    return Camera(K=K, world_to_cam=torch.eye(4), width=2, height=2, near=1.0, far=2.0)


def test_frustum_box_is_the_box_of_the_cut_frustum():
    box = frustum_box([_camera_at_origin()])
    # at depth 2 the image corners (0, 0) and (2, 2) lie at x, y = -2 and +2
    assert torch.allclose(box, torch.tensor([[-2.0, -2.0, 1.0], [2.0, 2.0, 2.0]]))


def test_box_points_are_uniform_grey_and_seeded():
    box = torch.tensor([[-1.0, 0.0, 2.0], [1.0, 4.0, 3.0]])
    pts, cols = sample_box_points(box, 20000, torch.Generator().manual_seed(0))
    assert pts.shape == (20000, 3) and cols.shape == (20000, 3)
    assert (pts >= box[0]).all() and (pts <= box[1]).all()
    assert torch.allclose(pts.mean(0), box.mean(0), atol=0.05)  # uniform: mean at the centre
    assert torch.all(cols == 0.5)
    again, _ = sample_box_points(box, 20000, torch.Generator().manual_seed(0))
    assert torch.equal(pts, again)


@pytest.fixture(scope="module")
def forward_dm(tmp_path_factory):
    root = generate_scene("forward", tmp_path_factory.mktemp("init") / "scene", width=64, height=48, n_views=5, seed=1)
    return DataManager(load_scene(root, views=3), device="cpu", seed=0)


def test_random_init_uses_the_content_box_when_the_dataset_has_one(forward_dm):
    cams, imgs = zip(*[(c, b["image"]) for c, b in forward_dm.train_views()])
    g = torch.Generator().manual_seed(0)
    scene = forward_dm.scene
    assert scene.content_box is None
    pts, _ = random_init("random", scene, list(cams), list(imgs), 5000, g)
    box = frustum_box(list(cams))
    assert (pts >= box[0] - 1e-5).all() and (pts <= box[1] + 1e-5).all()
    assert (pts.amax(0) - pts.amin(0) > 0.9 * (box[1] - box[0])).all()  # fills the box
    boxed = type(scene)(**{**scene.__dict__, "content_box": ((0.0, 0.0, 0.0), (0.1, 0.2, 0.3))})
    pts, _ = random_init("random", boxed, list(cams), list(imgs), 5000, g)
    assert (pts >= 0).all() and (pts <= torch.tensor([0.1, 0.2, 0.3])).all()
    with pytest.raises(ValueError, match="unknown random initialisation"):
        random_init("sphere", scene, list(cams), list(imgs), 10, g)


def test_3dgs_starts_from_the_reference_random_init_and_frustum_is_a_variant(forward_dm):
    cams, imgs = zip(*[(c, b["image"]) for c, b in forward_dm.train_views()])
    cfg = get_method("3dgs").default_config()
    assert cfg.model.init == "random"
    model = GaussianModel.from_data(cfg, forward_dm, torch.Generator().manual_seed(0))
    box = frustum_box(list(cams))
    means = model.params["means"].detach()
    assert (means >= box[0] - 1e-5).all() and (means <= box[1] + 1e-5).all()
    sh0 = model.params["sh0"].detach()
    assert torch.all(sh0 == sh0[0])  # one grey for all

    frustum = get_method("3dgs-frustum").default_config()
    assert frustum.model.init == "frustum"
    assert apply_overrides(cfg, {"model": {"init": "frustum"}}).model.init == "frustum"
    model = GaussianModel.from_data(frustum, forward_dm, torch.Generator().manual_seed(0))
    expected, _ = sample_frustum_points(list(cams), list(imgs), frustum.model.init_num_points, torch.Generator().manual_seed(0))
    assert torch.allclose(model.params["means"].detach(), expected)
    assert model.params["sh0"].detach().std(0).max() > 0.1  # pixel colours, not one grey


def test_knn_scale_matches_brute_force_with_duplicates_and_tiny_sets():
    """The k-d tree search gives every point's RMS distance to its 3 nearest others, exactly
    as all pairwise distances do (anisotropic cloud, duplicated points at distance 0)."""
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(700, 3, generator=g) * torch.tensor([1.0, 3.0, 0.05])
    pts = torch.cat([pts, pts[:30]])
    brute = torch.cdist(pts.double(), pts.double()).square().topk(4, dim=1, largest=False).values[:, 1:]
    expected = brute.mean(1).sqrt().clamp_min(1e-7).float()
    got = knn_scale(pts)
    assert got.shape == (730,) and got.dtype == torch.float32
    assert torch.allclose(got, expected, rtol=1e-4, atol=1e-6)
    assert got[:30].eq(got[700:]).all() and got[:30].gt(0).all()  # a duplicate is not "itself"
    two = torch.tensor([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]])
    assert torch.allclose(knn_scale(two), torch.tensor([5.0, 5.0]))  # k shrinks to the one other point
    assert knn_scale(two[:1]).tolist() == pytest.approx([0.01])
    assert knn_scale(pts.double()).dtype == torch.float64

"""Initialisation kinds (model.init): the reference's grey box, frustum sampling, triangulated
matches, a dataset's SfM points and a PLY file, for every method."""

from __future__ import annotations

import pytest
import torch

from splat_framework.cameras import Camera
from splat_framework.config import RunFacts, apply_overrides
from splat_framework.config.init import RandomInitConfig
from splat_framework.data import DataManager, load_scene
from splat_framework.data.synthetic import generate_scene
from splat_framework.model.gaussians import GaussianModel, knn_scale
from splat_framework.model.init import frustum_box, initial_points, sample_box_points, sample_frustum_points
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
    cams = [c for c, _ in forward_dm.train_views()]
    g = torch.Generator().manual_seed(0)
    scene = forward_dm.scene
    assert scene.content_box is None
    pts = initial_points(RandomInitConfig(num_points=5000), forward_dm, g).points
    box = frustum_box(cams)
    assert (pts >= box[0] - 1e-5).all() and (pts <= box[1] + 1e-5).all()
    assert (pts.amax(0) - pts.amin(0) > 0.9 * (box[1] - box[0])).all()  # fills the box
    boxed = type(scene)(**{**scene.__dict__, "content_box": ((0.0, 0.0, 0.0), (0.1, 0.2, 0.3))})
    pts = initial_points(RandomInitConfig(num_points=5000), DataManager(boxed, device="cpu", seed=0), g).points
    assert (pts >= 0).all() and (pts <= torch.tensor([0.1, 0.2, 0.3])).all()


def test_3dgs_starts_from_the_reference_random_init_and_frustum_is_a_variant(forward_dm):
    cams, imgs = zip(*[(c, b["image"]) for c, b in forward_dm.train_views()])
    cfg = get_method("3dgs").default_config()
    assert cfg.model.init.kind == "random"
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), forward_dm, torch.Generator().manual_seed(0))
    box = frustum_box(list(cams))
    means = model.params["means"].detach()
    assert (means >= box[0] - 1e-5).all() and (means <= box[1] + 1e-5).all()
    sh0 = model.params["sh0"].detach()
    assert torch.all(sh0 == sh0[0])  # one grey for all

    frustum = get_method("3dgs-frustum").default_config()
    assert frustum.model.init.kind == "frustum"
    assert apply_overrides(cfg, {"model": {"init": {"kind": "frustum"}}}).model.init == frustum.model.init
    model = GaussianModel.from_data(frustum.model, RunFacts.of(frustum), forward_dm, torch.Generator().manual_seed(0))
    expected, _ = sample_frustum_points(list(cams), list(imgs), frustum.model.init.num_points, torch.Generator().manual_seed(0))
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


@pytest.mark.bad_input("`--model.init.kind sfm` on a dataset without SfM points; `ply` with a missing or non-splat PLY", "exit 2, one line naming the dataset or file")
def test_sfm_kind_starts_from_a_colmap_datasets_points_and_refuses_a_dataset_without(tmp_path, forward_dm):
    from tests.support import make_colmap

    from splat_framework.config.init import SfMInitConfig
    from splat_framework.errors import DataError

    dm = DataManager(load_scene(make_colmap(tmp_path / "c", binary=True), views=3), device="cpu", seed=0)
    start = initial_points(SfMInitConfig(), dm, torch.Generator().manual_seed(0))
    assert torch.equal(start.points, torch.as_tensor(dm.scene.extras["points3d"]))
    assert torch.allclose(start.colors[0], torch.tensor([10.0, 20.0, 30.0]) / 255)
    with pytest.raises(DataError, match="no structure-from-motion points"):
        initial_points(SfMInitConfig(), forward_dm, torch.Generator())


def test_ply_kind_starts_3dgs_from_an_exported_model(tmp_path, forward_dm):
    """Export a model to PLY, start 3dgs from it: its initial means are the PLY's, its colours the
    PLY's base colours; a missing file is one DataError naming it."""
    from splat_framework.errors import DataError
    from splat_framework.export.ply import export_ply, load_ply

    cfg = get_method("3dgs-frustum").default_config()
    source = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), forward_dm, torch.Generator().manual_seed(0))
    path = export_ply(source, tmp_path / "start.ply")
    ply = load_ply(path)
    cfg = apply_overrides(get_method("3dgs").default_config(), {"model": {"init": {"kind": "ply", "path": str(path)}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), forward_dm, torch.Generator().manual_seed(1))
    assert torch.equal(model.params["means"].detach(), ply["means"])
    assert torch.allclose(model.params["sh0"].detach(), ply["sh0"], atol=1e-5)
    assert model.init_stats == {"num_points": ply["means"].shape[0]}
    with pytest.raises(DataError, match="missing.ply"):
        GaussianModel.from_data(cfg.model.model_copy(
            update={"init": cfg.model.init.model_copy(update={"path": tmp_path / "missing.ply"})}),
            RunFacts.of(cfg), forward_dm, torch.Generator())


@pytest.mark.bad_input("`--model.init.kind` naming a kind the method does not take", "exit 2, one line naming the kinds it takes")
def test_any_method_starts_from_a_ply_on_the_command_line(tmp_path):
    """``--model.init.kind ply --model.init.path x.ply`` on 3dgs, scaffold-gs and scgaussian; --help shows
    the chosen kind's flags; an unknown kind, or one the method does not take (scgaussian's ordinary
    Gaussians are random or a PLY's), is one line naming the choices."""
    import tyro

    from splat_framework.cli.common import ArgumentsError
    from splat_framework.cli.train import build_parser_type
    from splat_framework.registry import discover_methods

    methods = discover_methods()
    for method in ("3dgs", "scaffold-gs", "scgaussian"):
        argv = [method, "--model.init.kind", "ply", "--model.init.path", str(tmp_path / "x.ply")]
        config = tyro.cli(build_parser_type(methods, argv, method), args=argv)
        assert config.model.init.kind == "ply" and config.model.init.path == tmp_path / "x.ply"
    argv = ["3dgs-triang", "--model.init.kind=triangulated", "--model.init.max-reprojection-px", "3"]
    config = tyro.cli(build_parser_type(methods, argv, "3dgs-triang"), args=argv)
    assert config.model.init.max_reprojection_px == 3 and config.model.init.matching == methods["3dgs-triang"].default_config().model.init.matching
    with pytest.raises(ArgumentsError, match="'sphere' is not one of random, frustum, ply, sfm, triangulated"):
        build_parser_type(methods, ["3dgs", "--model.init.kind", "sphere"], "3dgs")
    with pytest.raises(ArgumentsError, match="'sfm' is not one of random, frustum, ply"):
        build_parser_type(methods, ["scgaussian", "--model.init.kind", "sfm"], "scgaussian")


def test_triangulation_without_matches_falls_back_to_the_reference_random_init(forward_dm, monkeypatch):
    """``3dgs-triang`` whose matcher finds nothing: one warning, and the reference random start
    (FALLBACK_POINTS grey points in the frustum box)."""
    import splat_framework.matching.prior as prior
    from splat_framework.config.init import FALLBACK_POINTS
    from splat_framework.matching import MatchSet

    dm = forward_dm
    monkeypatch.setattr(
        prior, "compute_match_set",
        lambda matching, dm: MatchSet(view_ids=[int(i) for i in dm.scene.train_indices], matches={}),
    )
    with pytest.warns(UserWarning, match="too few triangulated matches"):
        cfg = get_method("3dgs-triang").default_config()
        model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    assert model.num_gaussians == FALLBACK_POINTS
    box = frustum_box(dm.train_cameras)
    means = model.params["means"].detach()
    assert (means >= box[0] - 1e-5).all() and (means <= box[1] + 1e-5).all()
    sh0 = model.params["sh0"].detach()
    assert torch.all(sh0 == sh0[0])  # grey, like 3dgs
    # the run still names the (empty) matches it tried to start from
    assert model.init_stats["matches_digest"] == MatchSet(view_ids=[int(i) for i in dm.scene.train_indices], matches={}).digest()

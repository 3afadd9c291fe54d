"""SCGaussian on a built-in synthetic scene with exact depth: losses, warm-up, hybrid densification."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from scg_plugin.losses import rendering_geometry_loss
from scg_plugin.method import config_scgaussian
from scg_plugin.model import SCGaussianModel
from scg_plugin.pipeline import SCGaussianPipeline
from scg_plugin.ray_gaussians import (
    MatchCache,
    _position_error_grad,
    build_ray_bundle,
    gaussian_position_loss,
    partner_projections,
    pixel_errors,
    position_errors,
    warm_up,
    warmup_step_size,
)
from splat_framework.plugin import GaussianModel, RunFacts
from splat_framework.testing import (
    MatchSet,
    Trainer,
    apply_overrides,
    area_resized,
    compute_matches,
    config_3dgs,
    export_ply,
    generate_scene,
    get_method,
    load_ply,
    load_trained_model,
    match_config,
    resolve_steps,
    scene_and_data,
    triangulate,
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = generate_scene("forward", tmp_path_factory.mktemp("fwd") / "scene", width=128, height=96, n_views=9, seed=3)
    sc, dm = scene_and_data(root, views=3)
    depths = [np.load(sc.depth_paths[i]) for i in sc.train_indices]
    return sc, dm, depths


def true_correspondences(dm, depths, a=0, b=1, n=300, seed=0):
    """Exact matches: pixels of view a lifted with GT depth and projected into view b."""
    cams = dm.train_cameras
    rng = np.random.default_rng(seed)
    h, w = depths[a].shape
    xs, ys = rng.integers(0, w, 4 * n), rng.integers(0, h, 4 * n)
    uv_a = torch.tensor(np.stack([xs + 0.5, ys + 0.5], 1), dtype=torch.float32)
    z = torch.tensor(depths[a][ys, xs])
    pts = cams[a].unproject_depth(uv_a.double(), z.double())
    uv_b, zb = cams[b].project(pts)
    inside = (zb > 0) & (uv_b[:, 0] > 0) & (uv_b[:, 0] < w) & (uv_b[:, 1] > 0) & (uv_b[:, 1] < h) & (z > 0)
    # visible in b too (not occluded): b's depth map agrees with the point's depth
    px = uv_b.floor().long().clamp(min=0)
    px[:, 0] = px[:, 0].clamp(max=w - 1)
    px[:, 1] = px[:, 1].clamp(max=h - 1)
    seen = (torch.tensor(depths[b][px[:, 1], px[:, 0]]).double() - zb).abs() < 0.02 * zb
    inside &= seen
    return uv_a[inside][:n], uv_b[inside][:n].float(), pts[inside][:n]


def test_gp_loss_is_zero_at_true_depth_and_positive_otherwise(scene):
    _, dm, depths = scene
    cams = dm.train_cameras
    uv_a, uv_b, pts = true_correspondences(dm, depths)
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], cams, torch.Generator().manual_seed(0))
    # exact distance along each Gaussian's own ray to the true point
    true_pts = pts.float().repeat_interleave(2, dim=0)
    bundle.z = (true_pts - bundle.origins).norm(dim=-1)
    assert torch.allclose(bundle.positions(), true_pts, atol=1e-3)
    assert float(gaussian_position_loss(bundle.positions(), bundle, cams)) < 1e-5
    off = bundle.positions(bundle.z * 1.05)
    assert float(gaussian_position_loss(off, bundle, cams)) > 1e-3


def _depth_rel_error(bundle, z, cams, depths):
    """Relative error of each Gaussian's camera z (own view) against the GT depth at its pixel."""
    rel = []
    for v in torch.unique(bundle.view).tolist():
        sel = bundle.view == v
        zc = cams[v].world_to_camera_points(bundle.positions(z)[sel])[:, 2]
        px = bundle.uv[sel].floor().long()
        gt = torch.tensor(depths[v][px[:, 1], px[:, 0]])
        rel.append(((zc - gt).abs() / gt)[gt > 0])
    return torch.cat(rel)


def test_warm_up_finds_the_true_depth_from_exact_matches(scene):
    """Exact correspondences, z uniform in [near, far]: 600 warm-up steps reach the
    surface to within 0.5% of the depth for 95% of the Gaussians."""
    _, dm, depths = scene
    cams = dm.train_cameras
    uv_a, uv_b, pts = true_correspondences(dm, depths)
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], cams, torch.Generator().manual_seed(0))
    true_pts = pts.float().repeat_interleave(2, dim=0)
    dist = (true_pts - bundle.origins).norm(dim=-1)
    before = (bundle.positions() - true_pts).norm(dim=-1) / dist
    z = warm_up(bundle, cams, steps=600, lr=warmup_step_size(0.03, "depth-range", bundle), halve_every=150, cache=None)
    rel = (bundle.positions(z) - true_pts).norm(dim=-1) / dist
    assert float(before.median()) > 0.1
    assert float(rel.quantile(0.95)) < 0.005, float(rel.quantile(0.95))


def test_warm_up_gradient_in_closed_form_is_autograds_of_the_position_loss(scene):
    """The warm-up's closed-form d/dz of each L_gp term equals autograd's through
    position_errors (float64), for rows in front of and behind their partner camera; 20
    warm-up iterations follow an autograd Adam loop on gaussian_position_loss (float64), and the
    cache keeps, per match, the z of the iteration with the lowest pixel error."""
    _, dm, depths = scene
    cams = dm.train_cameras
    uv_a, uv_b, _ = true_correspondences(dm, depths)
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], cams, torch.Generator().manual_seed(0))
    z = bundle.z.double().clone()
    z[:40] = -z[:40]  # behind both cameras
    b64 = type(bundle)(**{k: (v.double() if v.is_floating_point() else v) for k, v in bundle.to_dict().items()})
    zr = z.clone().requires_grad_(True)
    position_errors(b64.positions(zr), b64, cams).sum().backward()
    P, size = (t.double() for t in partner_projections(b64, cams))
    h0 = ((P[:, :, :3] * b64.origins[:, None, :]).sum(-1) + P[:, :, 3]).T
    h1 = (P[:, :, :3] * b64.dirs[:, None, :]).sum(-1).T
    h = h0 + z * h1
    uv = h[:2] / h[2].clamp(min=1e-9)
    grad = _position_error_grad(uv, uv - b64.partner_uv.T, h[2], h1, size.reciprocal().T)
    assert bool((h[2] <= 0).any()) and bool((h[2] > 0).any())
    torch.testing.assert_close(grad, zr.grad, rtol=1e-9, atol=1e-12)

    lr = warmup_step_size(0.03, "depth-range", b64)
    ref = torch.nn.Parameter(b64.z.clone())
    opt = torch.optim.Adam([ref], lr=lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=5, gamma=0.5)
    seen = []
    for _ in range(20):
        opt.zero_grad()
        gaussian_position_loss(b64.positions(ref), b64, cams).backward()
        opt.step()
        sched.step()
        with torch.no_grad():
            ref.clamp_(min=1e-3)
        seen.append(ref.detach().clone())
    cache = MatchCache(b64)
    z = warm_up(b64, cams, steps=20, lr=lr, halve_every=5, cache=cache)
    torch.testing.assert_close(z, seen[-1], rtol=1e-4, atol=1e-5)
    errs = torch.stack([pixel_errors(b64.positions(s), b64, cams) for s in seen])
    best = errs.argmin(0).repeat_interleave(2)
    expect = torch.stack(seen)[best, torch.arange(len(b64))]
    torch.testing.assert_close(cache.best_z, expect, rtol=1e-4, atol=1e-5)


def test_warm_up_step_size_in_scene_units_or_of_the_depth_range(scene):
    """warmup_lr in the scene's own unit (the official code's 0.5) is the step itself; as a fraction
    of the depth range it scales with the median far - near of the matched rays."""
    _, dm, depths = scene
    uv_a, uv_b, _ = true_correspondences(dm, depths)
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], dm.train_cameras, torch.Generator().manual_seed(0))
    depth_range = float((bundle.far - bundle.near).median())
    assert depth_range > 0 and depth_range != 1.0
    assert warmup_step_size(0.5, "scene", bundle) == 0.5
    assert warmup_step_size(0.03, "depth-range", bundle) == pytest.approx(0.03 * depth_range)


def test_warm_up_with_real_matches_is_as_good_as_triangulation(scene):
    """Dense matches on 128x96 views: after warm-up with cache-and-filter, the depth
    error of the ray Gaussians is that of exact two-view triangulation of the same
    matches (median within +10%), i.e. only the matches' own noise remains."""
    _, dm, depths = scene
    views = dm.train_views()
    cams = [c for c, _ in views]
    ids = [int(b["index"]) for _, b in views]
    ms = compute_matches([b["image"].numpy() for _, b in views], cams, ids, match_config("dense"))
    pos = {v: k for k, v in enumerate(ids)}
    pairs = [(pos[i], pos[j], *ms.get(i, j)) for i, j in ms.pairs()]
    assert sum(len(p[2]) for p in pairs) > 500
    bundle = build_ray_bundle(pairs, cams, torch.Generator().manual_seed(0))
    tri = []
    for i, j, a, b in pairs:
        p, _ = triangulate(cams[i], cams[j], torch.as_tensor(a), torch.as_tensor(b))
        zc = cams[i].world_to_camera_points(p)[:, 2]
        px = torch.as_tensor(a).floor().long()
        gt = torch.tensor(depths[i][px[:, 1], px[:, 0]])
        tri.append(((zc - gt).abs() / gt)[gt > 0])
    tri_median = float(torch.cat(tri).median())
    cache = MatchCache(bundle)
    warm_up(bundle, cams, steps=600, lr=warmup_step_size(0.03, "depth-range", bundle), halve_every=150, cache=cache)
    keep = cache.keep_mask(2.0)
    assert keep.float().mean() > 0.8
    b = bundle.select(keep)
    rel = _depth_rel_error(b, cache.best_z[keep], cams, depths)
    assert float(rel.median()) < 1.1 * tri_median + 0.002, (float(rel.median()), tri_median)
    assert float(pixel_errors(b.positions(cache.best_z[keep]), b, cams).median()) < 1.0


def test_triangulation_recovers_exact_points(scene):
    _, dm, depths = scene
    cams = dm.train_cameras
    uv_a, uv_b, pts = true_correspondences(dm, depths, 0, 2)
    tri, err = triangulate(cams[0], cams[2], uv_a, uv_b)
    assert torch.allclose(tri, pts.float(), atol=1e-3 * float(pts.norm(dim=-1).max()))
    assert float(err.max()) < 0.01


def _hybrid_model(dm, overrides=None, bound=True):
    """The default's model, 8 matched rows from 4 matches and 6 ordinary ones; ``bound``: the matched
    Gaussians bound to their rays (the paper's hybrid; the default releases them after the warm-up)."""
    cfg = apply_overrides(config_scgaussian(), {"model": {"ray_binding": bound}})
    if overrides:
        cfg = apply_overrides(cfg, overrides)
    cams = dm.train_cameras
    imgs = [b["image"] for _, b in dm.train_views()]
    uv_a = torch.tensor([[10.5, 10.5], [40.5, 30.5], [70.5, 60.5], [100.5, 80.5]])
    bundle = build_ray_bundle([(0, 1, uv_a, uv_a + 2.0)], cams, torch.Generator().manual_seed(0))
    free = torch.rand(6, 3) + torch.tensor([0.0, 0.0, 4.0])
    model = SCGaussianModel(cfg.model, RunFacts.of(cfg), 1.0, free, torch.rand(6, 3), bundle, cams, imgs)
    return cfg, model


def test_ray_gaussians_move_only_along_their_rays(scene):
    _, dm, _ = scene
    cfg, model = _hybrid_model(dm)
    opts = model.make_optimizers()
    cam, batch = dm.next_train(0)
    for step in range(5):
        out = model.get_outputs(cam, torch.zeros(3))
        loss = out.rgb.sum() + out.depth.mean() + model.positions().sum()
        loss.backward()
        for o in opts.values():
            o.step()
            o.zero_grad()
    p = model.params
    ray = p["is_ray"] > 0.5
    assert int(ray.sum()) == 8
    moved = model.positions().detach()[ray] - p["ray_o"][ray]
    cross = torch.linalg.cross(moved, p["ray_d"][ray]).norm(dim=-1)
    assert float(cross.max()) < 1e-4
    assert not torch.allclose(p["z"][ray], model.bundle.z)  # they did move


def test_the_default_releases_the_matched_gaussians_from_their_rays(scene):
    """``scgaussian`` as it ships: the matched rows start where their rays put them, flagged as
    matches but not bound, and one step moves them off their rays (``scgaussian-ray-bound`` keeps them on)."""
    _, dm, _ = scene
    assert not config_scgaussian().model.ray_binding
    _, model = _hybrid_model(dm, bound=False)
    p = model.params
    assert p["is_match"][:8].tolist() == [1.0] * 8 and float(p["is_ray"].sum()) == 0.0
    assert torch.allclose(model.positions()[:8], model.bundle.positions())
    opts = model.make_optimizers()
    cam, _ = dm.next_train(0)
    out = model.get_outputs(cam, torch.zeros(3))
    (out.rgb.sum() + model.positions().sum()).backward()
    for o in opts.values():
        o.step()
    moved = model.positions().detach()[:8] - p["ray_o"][:8]
    assert float(torch.linalg.cross(moved, p["ray_d"][:8]).norm(dim=-1).max()) > 1e-4  # off the rays
    assert get_method("scgaussian-ray-bound").default_config().model.ray_binding


def _refine_once(model, cfg, dm):
    strategy = cfg.strategy.setup()  # RayGaussianStrategy: keeps the Gaussians of matches
    assert type(strategy).__name__ == "RayGaussianStrategy"
    opts = model.make_optimizers()
    state = strategy.initialize_state(1.0)
    cam, _ = dm.next_train(0)
    out = model.get_outputs(cam, torch.zeros(3))
    strategy.step_pre_backward(model.params, opts, state, 1, out.meta)
    (out.rgb.sum() + 1e3 * out.meta["means2d"].sum()).backward()
    with torch.no_grad():
        model.prepare_for_strategy()
    return strategy.step_post_backward(model.params, opts, state, 1, out.meta)


def test_children_of_ray_parents_are_ordinary(scene):
    _, dm, _ = scene
    cfg, model = _hybrid_model(dm, {"strategy": {"refine_start_iter": 0, "refine_every": 1, "prune_opa": 0.0, "grow_grad2d": 0.0}})
    pos_before = model.positions()[:8].detach().clone()
    counts = _refine_once(model, cfg, dm)
    p = model.params
    assert counts["n_clone"] + counts["n_split"] > 0 and counts["n_prune"] == 0
    assert model.num_gaussians > 14
    # parents keep their rows, flags and rays; every new row is ordinary
    assert torch.all(p["is_ray"][:8] == 1) and torch.all(p["is_match"][:8] == 1)
    assert torch.all(p["is_ray"][8:] == 0) and torch.all(p["is_match"][8:] == 0)
    assert torch.allclose(model.positions()[:8], pos_before)
    assert model.num_gaussians == 14 + counts["n_clone"] + counts["n_split"]


def test_ray_gaussians_survive_pruning(scene):
    _, dm, _ = scene
    cfg, model = _hybrid_model(dm, {"strategy": {"refine_start_iter": 0, "refine_every": 1, "prune_opa": 0.99, "grow_grad2d": 1e9}})
    counts = _refine_once(model, cfg, dm)
    assert counts["n_prune"] == 6  # every ordinary Gaussian has opacity 0.1 < 0.99
    assert model.num_gaussians == 8 and torch.all(model.params["is_ray"] == 1)


def test_too_few_matches_warn_and_fall_back_to_ordinary_gaussians(scene, monkeypatch, tmp_path):
    """Texture-less views (simulated: the matcher finds nothing) must not crash or train nothing."""
    import scg_plugin.startup as startup

    sc, _, _ = scene
    monkeypatch.setattr(
        startup, "compute_match_set",
        lambda config, dm: MatchSet(view_ids=[int(i) for i in dm.scene.train_indices], matches={}),
    )
    cfg = config_scgaussian().model_copy(update=dict(data=str(sc.root), steps=10, output=tmp_path / "run", progress=False, save_renders=False))
    with pytest.warns(UserWarning, match="only 0 verified matches"):
        tr = Trainer(cfg)
    assert tr.model.num_match_gaussians == 0 and tr.model.num_gaussians >= 10000
    # with no prior it trains as the 3dgs baseline would at the same 10 iterations
    assert_baseline_schedule(tr)
    metrics = tr.train()
    assert metrics["init_stats"]["num_matches"] == 0 and metrics["mean"]["psnr"] > 5
    assert metrics["init_stats"]["baseline_schedule"] is True
    # which matches the run trained on (none here), as the framework's MatchSet names them
    empty = MatchSet(view_ids=[int(i) for i in tr.datamanager.scene.train_indices], matches={})
    assert metrics["init_stats"]["matches_digest"] == empty.digest()


def pipeline_on(cfg, dm):
    """SCGaussian's pipeline of ``cfg`` on the fixture's data manager ``dm``: a subclass that
    builds its data differently (it takes ``dm``), then builds the model as every run does."""

    class OnFixture(SCGaussianPipeline):
        def build_datamanager(self):
            return dm

    return OnFixture(cfg, SCGaussianModel, torch.device("cpu"), torch.Generator().manual_seed(0))


def assert_baseline_schedule(trainer):
    """The trainer's strategy and the model's SH schedule are 3dgs's at the run's budget, the
    strategy still SCGaussian's kind (ray-based Gaussians kept)."""
    from scg_plugin.config import RayStrategyConfig

    base = resolve_steps(config_3dgs().model_copy(update={"steps": trainer.config.total_steps}))
    used = trainer.pipeline.strategy_config()
    assert isinstance(used, RayStrategyConfig)
    assert trainer.strategy.config == used
    assert used.model_dump(exclude={"kind"}) == base.strategy.model_dump(exclude={"kind"})
    assert trainer.pipeline.baseline.sh_degree_interval == base.model.sh_degree_interval
    trainer.model.on_step_start(base.model.sh_degree_interval)
    assert trainer.model.active_sh_degree == 1  # the baseline's SH schedule, not the run config's
    # one config: the run's (config.json, --resume), unchanged; the pipeline applied the schedule
    assert trainer.pipeline.config is trainer.config and trainer.config.strategy != used
    assert trainer.config.model.sh_degree_interval != base.model.sh_degree_interval


def test_thin_prior_baseline_keeps_the_flags_the_user_set(scene, monkeypatch):
    """The switch to the baseline's schedule replaces only what the user left at the method's
    defaults, and says in one line what it changed and what it kept."""
    import scg_plugin.startup as startup

    sc, dm, _ = scene
    monkeypatch.setattr(startup, "compute_match_set",
                        lambda config, dm: MatchSet(view_ids=[int(i) for i in sc.train_indices], matches={}))
    cfg = apply_overrides(config_scgaussian(), {"strategy": {"grow_grad2d": 0.001}, "model": {"sh_degree_interval": 7}})
    with pytest.warns(UserWarning, match=r"thin prior: .*refine_stop_iter .* kept as you set: "
                                          r"--model\.sh-degree-interval, --strategy\.grow-grad2d$"):
        pipeline = pipeline_on(cfg, dm)
    used = pipeline.strategy_config()
    assert used.grow_grad2d == 0.001 and pipeline.baseline.sh_degree_interval == 7
    assert "grow_grad2d" not in pipeline.baseline.changed
    base = resolve_steps(config_3dgs().model_copy(update={"steps": cfg.total_steps}))
    assert used.refine_stop_iter == base.strategy.refine_stop_iter != cfg.strategy.refine_stop_iter


def test_sparse_prior_warns_and_adds_random_ordinary_gaussians(scene, monkeypatch):
    """A prior of a few hundred matches (wide baselines, DTU) keeps its ray Gaussians and gets a random start too."""
    import scg_plugin.startup as startup

    sc, dm, depths = scene
    uv_a, uv_b, _ = true_correspondences(dm, depths, 0, 1, n=100)
    ids = [int(i) for i in sc.train_indices]
    monkeypatch.setattr(
        startup, "compute_match_set",
        lambda config, dm: MatchSet(view_ids=ids, matches={(ids[0], ids[1]): (uv_a.numpy(), uv_b.numpy())}),
    )
    cfg = apply_overrides(config_scgaussian(), {"model": {"warmup_steps": 50}})
    with pytest.warns(UserWarning, match="only 100 verified matches .* adding 10000 random ordinary Gaussians"):
        pipeline = pipeline_on(cfg, dm)
    model = pipeline.model
    assert model.num_match_gaussians == 200 - model.init_stats.get("filtered_matches", 0) * 2
    assert model.num_gaussians == model.num_match_gaussians + 10000
    assert model.init_stats["baseline_schedule"] is True
    assert pipeline.strategy_config().grow_grad2d == 0.0002 != cfg.strategy.grow_grad2d  # 3dgs's threshold
    no_baseline = apply_overrides(cfg, {"model": {"thin_prior_baseline": False}})
    with pytest.warns(UserWarning, match="only 100 verified matches"):
        pipeline = pipeline_on(no_baseline, dm)
    assert pipeline.strategy_config() == no_baseline.strategy and not pipeline.model.init_stats["baseline_schedule"]
    # without the warning, the default still starts with init.num_points (10,000) random ordinary Gaussians
    cfg = apply_overrides(cfg, {"model": {"sparse_matches": 0}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pipeline = pipeline_on(cfg, dm)
    model = pipeline.model
    assert model.num_gaussians == model.num_match_gaussians + 10000
    assert pipeline.strategy_config() == cfg.strategy and not model.init_stats["baseline_schedule"]
    # sparse_matches = 0 and init.num_points = 0: ray-based Gaussians only (the only-ray variant)
    cfg = apply_overrides(cfg, {"model": {"sparse_matches": 0, "init": {"num_points": 0}}})
    model = SCGaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    assert model.num_gaussians == model.num_match_gaussians


def test_a_ply_start_gives_the_ordinary_gaussians_beside_the_ray_based_ones(scene, monkeypatch, tmp_path):
    """``--model.init.kind ply``: the PLY's Gaussians (centres, base colours) are SCGaussian's ordinary
    Gaussians, after the ray-based ones, whatever the prior: a sparse one adds no random fill."""
    import scg_plugin.startup as startup

    sc, dm, depths = scene
    frustum = get_method("3dgs-frustum").default_config()
    source = GaussianModel.from_data(frustum.model, RunFacts.of(frustum), dm, torch.Generator().manual_seed(0))
    ply = load_ply(export_ply(source, tmp_path / "start.ply"))
    uv_a, uv_b, _ = true_correspondences(dm, depths, 0, 1, n=100)
    ids = [int(i) for i in sc.train_indices]
    monkeypatch.setattr(
        startup, "compute_match_set",
        lambda config, dm: MatchSet(view_ids=ids, matches={(ids[0], ids[1]): (uv_a.numpy(), uv_b.numpy())}),
    )
    cfg = apply_overrides(config_scgaussian(), {"model": {"warmup_steps": 50,
                                                          "init": {"kind": "ply", "path": str(tmp_path / "start.ply")}}})
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        model = pipeline_on(cfg, dm).model
    # a sparse prior: nothing random added, so the one line is the switch to the baseline's schedule
    assert [str(w.message).split(":")[0] for w in said] == ["thin prior"]
    rays = model.num_match_gaussians
    assert rays > 0 and model.num_gaussians == rays + ply["means"].shape[0]
    assert torch.equal(model.params["means"].detach()[rays:], ply["means"])
    assert torch.allclose(model.params["sh0"].detach()[rays:], ply["sh0"], atol=1e-5)


def test_scgaussian_trains_from_a_ply_on_the_command_line(run_dir, tmp_path):
    """``splat-train scgaussian --model.init.kind ply --model.init.path X.ply`` trains (the tiny scene, a few steps)."""
    import json

    from cli_harness import run_cli

    _, source = load_trained_model(run_dir)
    ply = export_ply(source, tmp_path / "start.ply")
    run_cli("train", "scgaussian", "--data", "synthetic/forward-tiny", "--steps", "4", "--output", tmp_path / "run",
            "--no-progress", "--model.init.kind", "ply", "--model.init.path", ply, code=0)
    saved = json.loads((tmp_path / "run" / "config.json").read_text())["config"]["model"]["init"]
    assert saved == {"kind": "ply", "path": str(ply)} and (tmp_path / "run" / "metrics.json").is_file()


def test_rendering_geometry_loss_reads_a_coarse_render_at_its_own_pixel_size(scene):
    """The trainer's coarse steps (``coarse_steps``) hand the model its view's camera resized: L_rg
    scales the matched pixels (kept at the view's own size) to it, so the true depth costs (almost)
    nothing at either size, and the pixels left unscaled would cost a lot."""
    _, dm, depths = scene
    cams = dm.train_cameras
    uv_a, uv_b, _ = true_correspondences(dm, depths)
    bundle = build_ray_bundle([(0, 1, uv_a, uv_b)], cams, torch.Generator().manual_seed(0))
    imgs = [b["image"] for _, b in dm.train_views()]
    free = torch.rand(6, 3) + torch.tensor([0.0, 0.0, 4.0])
    cfg = config_scgaussian()
    model = SCGaussianModel(cfg.model, RunFacts.of(cfg), 1.0, free, torch.rand(6, 3), bundle, cams, imgs)
    full_cam, batch = dm.train_view(0)
    coarse_cam, _ = dm.coarse_view(full_cam, batch, 0.5)
    depth = torch.tensor(depths[0], dtype=torch.float32)[..., None]
    coarse_depth = area_resized(depth, coarse_cam.width, coarse_cam.height)

    def rendered(d):
        return SimpleNamespace(depth=d, expected_depth=d)

    full = float(model._rg_loss(rendered(depth), full_cam, 0))
    coarse = float(model._rg_loss(rendered(coarse_depth), coarse_cam, 0))
    sel = bundle.view == 0
    unscaled = float(rendering_geometry_loss(coarse_depth, coarse_cam, bundle.uv[sel], cams[1], bundle.partner_uv[sel]))
    assert full < 2e-3 and coarse < 2e-3 and unscaled > 20 * coarse

"""Scaffold-GS and Octree-GS as a plugin: decoding, the opacity filter, anchor growing / pruning
with aligned Adam state, networks in checkpoints, registry entries, and tiny training runs
(the octree's own geometry is tested in test_octree.py)."""

from __future__ import annotations

import pytest
import torch

from anchor_gs.method import config_octree_gs, config_scaffold_gs
from anchor_gs.model import ScaffoldModel, voxelize
from anchor_gs.octree import OctreeModel
from splat_framework.plugin import RunFacts, compute_match_set
from splat_framework.testing import (
    Trainer,
    apply_overrides,
    discover_methods,
    evaluate,
    export_ply,
    load_ply,
    load_trained_model,
    scene_and_data,
    splat_arrays,
)


@pytest.fixture(scope="module")
def dm():
    return scene_and_data("forward-tiny", views=3)[1]


METHODS = {"scaffold-gs": (config_scaffold_gs, ScaffoldModel), "octree-gs": (config_octree_gs, OctreeModel)}


def build(dm, overrides: dict | None = None, triang: bool = False, method: str = "scaffold-gs") -> tuple:
    make, model_class = METHODS[method]
    init = {"kind": "triangulated"} if triang else {"num_points": 500}  # as the -triang variants
    cfg = apply_overrides(make(), {"data": "synthetic/forward-tiny", "model": {"init": init}} | (overrides or {}))
    torch.manual_seed(0)
    return cfg, model_class.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))


def test_voxelize_keeps_one_centre_per_occupied_cell():
    pts = torch.tensor([[0.01, 0.02, 0.0], [0.04, -0.02, 0.01], [1.0, 1.0, 1.0]])
    assert torch.allclose(voxelize(pts, 0.1), torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))


def test_decoding_shapes_and_the_opacity_filter(dm):
    cfg, model = build(dm)
    k = cfg.model.n_offsets
    camera = dm.train_cameras[0]
    visible = model.visible_anchors(camera)
    assert visible.dtype == torch.bool and 0 < int(visible.sum()) <= model.num_anchors
    with torch.no_grad():  # open up half the opacity outputs: Gaussians with opacity <= 0 are dropped
        last = model.networks["mlp_opacity"][2]
        last.weight.zero_()
        last.bias.copy_(torch.linspace(-1, 1, k))
    g = model.decode(camera.center, visible)
    a = int(visible.sum())
    assert g["neural_opacity"].shape == (a, k) and g["kept"].shape == (a * k,)
    m = int(g["kept"].sum())
    assert m == a * int((torch.linspace(-1, 1, k) > 0).sum())
    for key, shape in (("means", (m, 3)), ("quats", (m, 4)), ("scales", (m, 3)), ("opacities", (m,)), ("colors", (m, 3))):
        assert tuple(g[key].shape) == shape, key
    assert bool((g["opacities"] > 0).all()) and torch.allclose(g["quats"].norm(dim=-1), torch.ones(m))
    assert bool((g["colors"] >= 0).all() and (g["colors"] <= 1).all())
    out = model.get_outputs(camera, torch.zeros(3))
    assert out.rgb.shape == (camera.height, camera.width, 3) and out.meta["means2d"].shape[0] == m


@pytest.mark.slow  # trains an octree of anchors for many steps
@pytest.mark.parametrize("method", sorted(METHODS))
def test_anchor_growing_and_pruning_keep_every_parameter_and_its_adam_state_aligned(dm, method):
    cfg, model = build(dm, {"strategy": {"start_stat": 0, "update_from": 0, "update_interval": 2,
                                         "success_threshold": 0.5, "grad_threshold": 0.0, "min_opacity": 0.9}},
                       method=method)
    with torch.no_grad():  # offsets away from their anchors, as after some training: new cells to grow into
        model.params["offsets"].normal_(0.0, 3.0)
    strategy = cfg.strategy.setup()
    optimizers = model.make_optimizers()
    strategy.check_sanity(model.params, optimizers)
    state = strategy.initialize_state()
    a0 = model.num_anchors
    grown = pruned = 0
    for step in range(1, 5):
        camera, batch = dm.next_train(step)
        out = model.get_outputs(camera, torch.zeros(3))
        strategy.step_pre_backward(model.params, optimizers, state, step, out.meta)
        sum(model.get_loss_dict(out, batch, camera, step).values()).backward()
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        counts = strategy.step_post_backward(model.params, optimizers, state, step, out.meta)
        grown, pruned = grown + counts["n_grow"], pruned + counts["n_prune"]
    assert grown > 0 and pruned > 0
    a = model.num_anchors
    assert a == a0 + grown - pruned
    for key, p in model.params.items():
        assert p.shape[0] == a, key
        if p.requires_grad:
            st = optimizers[key].state[p]
            assert optimizers[key].param_groups[0]["params"][0] is p
            assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape, key
    for key in ("opacity_accum", "anchor_denom", "offset_grad", "offset_denom"):
        assert state[key].shape[0] == a, key
    for key in model.FIXED:  # anchors stay where they were put, as in the public code
        assert not model.params[key].requires_grad, key
    model.get_outputs(dm.train_cameras[0], torch.zeros(3))  # still renders


def test_registry_lists_the_plugin_methods_from_its_entry_points():

    methods = discover_methods()
    for name in ("scaffold-gs", "scaffold-gs-triang", "octree-gs", "octree-gs-triang"):
        assert methods[name].model.startswith("anchor_gs.")


@pytest.mark.slow  # matches the views
@pytest.mark.parametrize("method", sorted(METHODS))
def test_triangulated_anchors_start_from_the_matching_prior(dm, method):
    cfg, model = build(dm, triang=True, method=method)
    assert model.init_stats["num_points"] >= 50 and model.num_anchors > 0
    assert "matching_s" in model.init_timing
    # which matches the anchors came from (the cached set the prior reads: the same digest)
    assert model.init_stats["matches_digest"] == compute_match_set(cfg.model.init.matching, dm).digest()


@pytest.mark.parametrize("method", sorted(METHODS))
def test_a_tiny_run_improves_and_resumes_with_its_networks(tmp_path, method):

    cfg = apply_overrides(METHODS[method][0](), {
        "data": "synthetic/forward-tiny", "steps": 60, "output": str(tmp_path / "run"), "progress": False,
        "save_renders": False, "compile": False, "checkpoint_every": 30, "model": {"init": {"num_points": 1000}}})
    trainer = Trainer(cfg)
    before = evaluate(trainer.model, trainer.datamanager, trainer.background)["mean"]["psnr"]
    metrics = trainer.train()
    assert metrics["strategy"] == "anchor_gs.strategy." + ("OctreeStrategy" if method == "octree-gs" else "AnchorStrategy")
    assert metrics["mean"]["psnr"] > before + 1.0, (before, metrics["mean"]["psnr"])
    _, model = load_trained_model(tmp_path / "run")

    ply = load_ply(export_ply(model, tmp_path / "scaffold.ply"))  # the decoded Gaussians of the reference view
    assert 0 < ply["means"].shape[0] <= model.num_gaussians and ply["sh0"].shape[1:] == (1, 3)
    pytest.importorskip("viser")

    splats = splat_arrays(model, by_type=True)  # the viewer draws the same decoded Gaussians
    assert torch.allclose(torch.from_numpy(splats["centers"]), ply["means"], atol=1e-5)
    assert splats["covariances"].shape == (ply["means"].shape[0], 3, 3)
    for k, v in trainer.model.networks.state_dict().items():
        assert torch.equal(model.networks.state_dict()[k].cpu(), v.cpu()), k
    camera = trainer.datamanager.train_cameras[0]  # the rebuilt model draws what the trained one does
    with torch.no_grad():
        assert torch.allclose(model.get_outputs(camera).rgb, trainer.model.get_outputs(camera).rgb, atol=1e-6)
    resumed = Trainer(cfg.model_copy(update={"resume": True}))
    assert resumed.restore() and resumed.start_step == 60
    assert torch.equal(resumed.model.networks["mlp_color"][0].weight, trainer.model.networks["mlp_color"][0].weight)

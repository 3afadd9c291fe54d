"""Densification strategy and parameter/optimizer surgery (synthetic, CPU, fast)."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import ValidationError

from splat_framework.model import ops
from splat_framework.model.strategy import DefaultStrategy, DensifyConfig

TRAINABLE = ("means", "quats", "scales", "opacities", "sh0", "shN")


def make_params(n: int = 6, k_rest: int = 3, is_ray: list[float] | None = None, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    data = {
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        "scales": torch.full((n, 3), math.log(0.001)),
        "opacities": torch.full((n,), torch.logit(torch.tensor(0.5)).item()),
        "sh0": torch.rand(n, 1, 3, generator=g),
        "shN": torch.zeros(n, k_rest, 3),
    }
    params = torch.nn.ParameterDict({k: torch.nn.Parameter(v) for k, v in data.items()})
    params["is_ray"] = torch.nn.Parameter(
        torch.tensor(is_ray if is_ray is not None else [0.0] * n), requires_grad=False
    )
    optimizers = {k: torch.optim.Adam([params[k]], lr=1e-3) for k in TRAINABLE}
    return params, optimizers


def prime_adam(params, optimizers):
    """One Adam step (values restored), then overwrite moments with row ids so rows can be traced."""
    saved = {k: params[k].detach().clone() for k in TRAINABLE}
    loss = sum(params[k].sum() for k in TRAINABLE)
    loss.backward()
    for o in optimizers.values():
        o.step()
        o.zero_grad()
    for k in TRAINABLE:
        with torch.no_grad():
            params[k].copy_(saved[k])
        st = optimizers[k].state[params[k]]
        rows = torch.arange(1, params[k].shape[0] + 1, dtype=torch.float32)
        st["exp_avg"] = rows.reshape(-1, *[1] * (params[k].dim() - 1)).expand_as(params[k]).clone()
        st["exp_avg_sq"] = st["exp_avg"].clone() * 10


def row_ids(params, optimizers, key="means"):
    return optimizers[key].state[params[key]]["exp_avg"].reshape(params[key].shape[0], -1)[:, 0]


def assert_aligned(params, optimizers):
    n = params["means"].shape[0]
    for k, p in params.items():
        assert p.shape[0] == n, k
        if k in optimizers:
            opt = optimizers[k]
            assert opt.param_groups[0]["params"][0] is p
            st = opt.state.get(p)
            assert len(opt.state) == (st is not None)
            if st is not None:
                    assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape
        else:
            assert not p.requires_grad


def fake_info(n: int, grad_rows: dict[int, float], width=100, height=80, radii=None):
    means2d = torch.zeros(n, 2, requires_grad=True)
    g = torch.zeros(n, 2)
    for i, v in grad_rows.items():
        g[i] = torch.tensor([v, 0.0])
    means2d.grad = g
    r = torch.full((n,), 5, dtype=torch.int32) if radii is None else radii
    return {"means2d": means2d, "radii": r, "width": width, "height": height}


# ------------------------------------------------------------------ config
def test_config_defaults_and_docstrings():
    c = DensifyConfig()
    assert (c.prune_opa, c.grow_grad2d, c.grow_scale3d, c.prune_scale3d, c.prune_scale2d) == (
        0.005, 0.0002, 0.01, 0.1, 0.15,
    )
    assert (c.refine_start_iter, c.refine_stop_iter, c.reset_every, c.refine_every) == (500, 2500, 3000, 100)
    for name, field in DensifyConfig.model_fields.items():
        assert field.description, f"{name} has no docstring"
    with pytest.raises(ValidationError):
        DensifyConfig(prune_opacity=0.1)


# ------------------------------------------------------------------ ops
def test_duplicate_shapes_and_adam_alignment():
    params, opts = make_params(5)
    prime_adam(params, opts)
    state = {"grad2d": torch.arange(5.0), "count": torch.ones(5), "scene_scale": 1.0}
    mask = torch.tensor([False, True, False, True, False])
    old_means = params["means"].detach().clone()
    ops.duplicate(params, opts, state, mask, child_values={"is_ray": 0.0})
    assert_aligned(params, opts)
    assert params["means"].shape == (7, 3) and params["shN"].shape == (7, 3, 3)
    torch.testing.assert_close(params["means"][5:], old_means[[1, 3]])
    assert row_ids(params, opts).tolist() == [1, 2, 3, 4, 5, 0, 0]
    assert opts["means"].state[params["means"]]["exp_avg_sq"][5:].abs().sum() == 0
    assert state["grad2d"].tolist() == [0, 1, 2, 3, 4, 1, 3]
    assert state["scene_scale"] == 1.0
    # new params are still optimised
    params["means"].sum().backward()
    before = params["means"].detach().clone()
    opts["means"].step()
    assert not torch.equal(before, params["means"].detach())


def test_remove_drops_rows_and_moments():
    params, opts = make_params(5)
    prime_adam(params, opts)
    state = {"grad2d": torch.arange(5.0), "count": torch.ones(5), "scene_scale": 1.0}
    keep_means = params["means"].detach()[[0, 2, 4]].clone()
    ops.remove(params, opts, state, torch.tensor([False, True, False, True, False]))
    assert_aligned(params, opts)
    torch.testing.assert_close(params["means"], keep_means)
    for k in TRAINABLE:
        ids = row_ids(params, opts, k)
        assert ids.tolist() == [1, 3, 5], k
    assert state["grad2d"].tolist() == [0, 2, 4]
    assert params["is_ray"].shape == (3,) and not params["is_ray"].requires_grad


def test_rewrite_overwrites_rows_and_restarts_their_moments():
    """``ops.rewrite`` (gsplat's relocate): the named keys of rows [1, 3] take the new values, the
    other keys and rows are kept; every key's moments and every per-row state tensor restart at those rows."""
    params, opts = make_params(5)
    prime_adam(params, opts)
    state = {"grad2d": torch.arange(1.0, 6.0), "scene_scale": 1.0}
    before = {k: p.detach().clone() for k, p in params.items()}
    new_means = torch.full((2, 3), 7.0)
    ops.rewrite(params, opts, state, torch.tensor([3, 1]), {"means": new_means, "opacities": torch.zeros(2)})
    assert_aligned(params, opts)
    torch.testing.assert_close(params["means"][[3, 1]], new_means)
    assert params["opacities"].tolist() == [before["opacities"][0].item(), 0.0] * 2 + [before["opacities"][4].item()]
    torch.testing.assert_close(params["scales"], before["scales"])
    torch.testing.assert_close(params["means"][[0, 2, 4]], before["means"][[0, 2, 4]])
    for k in TRAINABLE:
        assert row_ids(params, opts, k).tolist() == [1, 0, 3, 0, 5], k
    assert state["grad2d"].tolist() == [1, 0, 3, 0, 5]
    with pytest.raises(ValueError, match="distinct"):
        ops.rewrite(params, opts, state, torch.tensor([1, 1]), {})
    with pytest.raises(ValueError, match="not in params"):
        ops.rewrite(params, opts, state, torch.tensor([1]), {"colour": torch.zeros(1)})


def test_strategy_loss_defaults_to_none():
    """A strategy adds no loss term unless it overrides ``Strategy.loss`` (the built-in ones do not)."""
    from splat_framework.model.strategy import Strategy

    params, _ = make_params(4)
    assert Strategy().loss(params, 0) == {} and DefaultStrategy().loss(params, 0) == {}


def test_split_parent_in_place_child_appended():
    params, opts = make_params(4, is_ray=[1.0, 0.0, 1.0, 0.0])
    with torch.no_grad():
        params["scales"][:] = math.log(0.5)
    prime_adam(params, opts)
    state = {"grad2d": torch.arange(4.0), "scene_scale": 1.0}
    old = {k: v.detach().clone() for k, v in params.items()}
    mask = torch.tensor([True, True, False, False])
    torch.manual_seed(0)
    ops.split(params, opts, state, mask, child_values={"is_ray": 0.0})
    assert_aligned(params, opts)
    assert params["means"].shape == (6, 3)
    # parents stay in their rows, scale / 1.6, new means near the old ones
    torch.testing.assert_close(params["scales"][:2], torch.full((2, 3), math.log(0.5 / 1.6)))
    torch.testing.assert_close(params["scales"][4:], torch.full((2, 3), math.log(0.5 / 1.6)))
    assert not torch.equal(params["means"][:2], old["means"][:2])
    assert (params["means"][:2] - old["means"][:2]).norm(dim=-1).max() < 5 * 0.5
    # untouched rows unchanged
    torch.testing.assert_close(params["means"][2:4], old["means"][2:4])
    torch.testing.assert_close(params["sh0"][4:], old["sh0"][:2])
    # identity: parent keeps flag, appended children get child value
    assert params["is_ray"].tolist() == [1.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    # Adam: both children zero, other rows keep their moments
    assert row_ids(params, opts).tolist() == [0, 0, 3, 4, 0, 0]
    assert state["grad2d"].tolist() == [0, 1, 2, 3, 0, 1]


def test_split_revised_opacity():
    params, opts = make_params(2)
    ops.split(params, opts, {}, torch.tensor([True, False]), revised_opacity=True)
    o = torch.sigmoid(params["opacities"].detach())
    torch.testing.assert_close(o, torch.tensor([1 - math.sqrt(0.5), 0.5, 1 - math.sqrt(0.5)]))


def test_reset_opa_clamps_and_zeros_moments():
    params, opts = make_params(3)
    with torch.no_grad():
        params["opacities"][0] = torch.logit(torch.tensor(0.001))
    prime_adam(params, opts)
    ops.reset_opa(params, opts, {}, value=0.01)
    o = torch.sigmoid(params["opacities"].detach())
    torch.testing.assert_close(o, torch.tensor([0.001, 0.01, 0.01]))
    st = opts["opacities"].state[params["opacities"]]
    assert st["exp_avg"].abs().sum() == 0 and st["exp_avg_sq"].abs().sum() == 0
    assert row_ids(params, opts, "means").tolist() == [1, 2, 3]  # others untouched


def test_decay_opa_scales_opacity_and_keeps_moments():
    params, opts = make_params(3)
    with torch.no_grad():
        params["opacities"].copy_(torch.logit(torch.tensor([0.9, 0.5, 0.01])))
    prime_adam(params, opts)
    ops.decay_opa(params, 0.5)
    torch.testing.assert_close(torch.sigmoid(params["opacities"].detach()), torch.tensor([0.45, 0.25, 0.005]))
    assert row_ids(params, opts, "opacities").tolist() == [1, 2, 3]  # moments untouched, no surgery
    assert opts["opacities"].param_groups[0]["params"][0] is params["opacities"]
    with torch.no_grad():
        params["opacities"].fill_(-120.0)  # sigmoid underflows in float32: the decay must stay finite
    ops.decay_opa(params, 0.5)
    torch.testing.assert_close(params["opacities"].detach(), torch.full((3,), -120.0 + math.log(0.5)))


def test_surgery_before_first_adam_step():
    params, opts = make_params(3)
    ops.duplicate(params, opts, {}, torch.tensor([True, False, False]))
    assert_aligned_no_state = all(opts[k].param_groups[0]["params"][0] is params[k] for k in TRAINABLE)
    assert assert_aligned_no_state and params["means"].shape[0] == 4


def test_trainable_key_without_optimizer_is_error():
    params, opts = make_params(3)
    del opts["shN"]
    with pytest.raises(ValueError):
        DefaultStrategy().check_sanity(params, opts)
    with pytest.raises(ValueError):
        ops.remove(params, opts, {}, torch.tensor([True, False, False]))


# ------------------------------------------------------------------ strategy
def cfg(**kw):
    base = dict(refine_start_iter=0, refine_every=10, reset_every=1000, refine_stop_iter=10_000)
    base.update(kw)
    return DensifyConfig(**base)


def test_pre_backward_retains_grad():
    params, opts = make_params(3)
    means2d = params["means"][:, :2] * 2.0
    strat = DefaultStrategy(cfg())
    strat.step_pre_backward(params, opts, strat.initialize_state(), 0, {"means2d": means2d})
    means2d.sum().backward()
    assert means2d.grad is not None


def test_clone_split_prune_counts():
    params, opts = make_params(6)
    with torch.no_grad():
        params["scales"][3:] = math.log(0.05)  # large (> 0.01 * scene_scale): split
        params["opacities"][5] = torch.logit(torch.tensor(0.001))  # pruned (and not grown)
    strat = DefaultStrategy(cfg())
    strat.check_sanity(params, opts)
    state = strat.initialize_state(scene_scale=1.0)
    # NDC grad threshold 2e-4 -> pixel grad 2e-4 / (W/2) = 4e-6 for W=100
    info = fake_info(6, {0: 1e-4, 1: 1e-4, 3: 1e-4})
    counts = strat.step_post_backward(params, opts, state, 5, info)  # not a refine step
    assert counts == {"n_clone": 0, "n_split": 0, "n_prune": 0}
    assert state["count"].tolist() == [1.0] * 6
    counts = strat.step_post_backward(params, opts, state, 10, info)
    assert counts == {"n_clone": 2, "n_split": 1, "n_prune": 1}
    assert params["means"].shape[0] == 6 + 2 + 1 - 1
    assert_aligned(params, opts)
    assert state["grad2d"].shape == (8,) and state["grad2d"].abs().sum() == 0
    assert state["count"].abs().sum() == 0


def test_absgrad_grows_a_gaussian_whose_pixel_gradients_cancel():
    """An isotropic Gaussian centred in the image over a uniform error: its pixels' gradients cancel
    in means2d.grad, so the standard criterion never grows it, but not in their absolute sums, so
    with absgrad (AbsGS) it is split."""
    from splat_framework.cameras import intrinsics, look_at
    from splat_framework.render import rasterize

    viewmat = look_at(torch.tensor([0.0, 0.0, -4.0]), torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))
    K = intrinsics(40.0, 40.0, 16.0, 16.0)
    for absgrad in (False, True):
        params, opts = make_params(1)
        with torch.no_grad():
            params["means"].zero_()
            params["scales"].fill_(math.log(0.3))
            params["sh0"].fill_(0.8)
        strat = DefaultStrategy(cfg(absgrad=absgrad, grow_grad2d=0.0008 if absgrad else 0.0002))
        state = strat.initialize_state(scene_scale=1.0)
        out = rasterize(params["means"], params["quats"], params["scales"].exp(), torch.sigmoid(params["opacities"]),
                        params["sh0"][:, 0], viewmat, K, 32, 32, absgrad=strat.absgrad)
        assert strat.absgrad == absgrad
        strat.step_pre_backward(params, opts, state, 10, out.meta)
        (out.rgb - 0.2).abs().mean().backward()
        m2d = out.meta["means2d"]
        assert m2d.grad.abs().max() < 1e-6  # the symmetric pixels cancel
        counts = strat.step_post_backward(params, opts, state, 10, out.meta)
        assert counts["n_split"] == int(absgrad), (absgrad, counts)
        if absgrad:
            assert m2d.absgrad.min() > 1e-3


def test_invisible_rows_do_not_accumulate():
    params, opts = make_params(3)
    strat = DefaultStrategy(cfg())
    state = strat.initialize_state()
    radii = torch.tensor([5, 0, 5], dtype=torch.int32)
    strat.step_post_backward(params, opts, state, 1, fake_info(3, {0: 1.0, 1: 1.0}, radii=radii))
    assert state["count"].tolist() == [1.0, 0.0, 1.0]
    assert state["grad2d"][1] == 0
    torch.testing.assert_close(state["grad2d"][0], torch.tensor(50.0))  # 1.0 * W/2


class KeepRays(DefaultStrategy):
    """The extension hooks as a model with per-row flags uses them: rows flagged is_ray are never
    pruned, and clone / split children are not ray rows."""

    def protected_rows(self, params):
        return params["is_ray"].detach() > 0.5

    def child_values(self, params):
        return {"is_ray": 0.0}


def test_protected_rows_are_never_pruned():
    params, opts = make_params(4, is_ray=[1.0, 0.0, 1.0, 0.0])
    with torch.no_grad():
        params["opacities"][:] = -20.0  # opacity ~ 0
        params["scales"][:] = math.log(100.0)  # huge
    strat = KeepRays(cfg(reset_every=20, refine_scale2d_stop_iter=1000, grow_scale2d=1e6))
    state = strat.initialize_state(1.0)
    radii = torch.full((4,), 1000, dtype=torch.int32)  # huge on screen too
    counts = strat.step_post_backward(params, opts, state, 30, fake_info(4, {}, radii=radii))
    assert counts["n_prune"] == 2
    assert params["is_ray"].tolist() == [1.0, 1.0]
    # without the hook they all go
    params, opts = make_params(4, is_ray=[1.0, 0.0, 1.0, 0.0])
    with torch.no_grad():
        params["opacities"][:] = -20.0
    strat = DefaultStrategy(cfg())
    strat.step_post_backward(params, opts, strat.initialize_state(), 10, fake_info(4, {}))
    assert params["means"].shape[0] == 0


def test_child_values_on_clone_and_split():
    params, opts = make_params(4, is_ray=[1.0, 1.0, 0.0, 0.0])
    with torch.no_grad():
        params["scales"][1] = math.log(0.05)  # row 1: ray parent, split
        params["scales"][3] = math.log(0.05)  # row 3: ordinary, split
    old_means = params["means"].detach().clone()
    strat = KeepRays(cfg())
    strat.check_sanity(params, opts)
    state = strat.initialize_state(1.0)
    counts = strat.step_post_backward(params, opts, state, 10, fake_info(4, {0: 1e-4, 1: 1e-4, 3: 1e-4}))
    assert counts == {"n_clone": 1, "n_split": 2, "n_prune": 0}
    # rows: 0..3 originals (1 and 3 are split parents), 4 clone of 0, 5 child of 1, 6 child of 3
    assert params["is_ray"].tolist() == [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    torch.testing.assert_close(params["means"][4], old_means[0])
    torch.testing.assert_close(params["means"][0], old_means[0])  # clone parent untouched
    torch.testing.assert_close(params["scales"][1], torch.full((3,), math.log(0.05 / 1.6)))
    torch.testing.assert_close(params["scales"][5], torch.full((3,), math.log(0.05 / 1.6)))
    assert_aligned(params, opts)


def test_opacity_reset_schedule_and_stop():
    params, opts = make_params(3)
    strat = DefaultStrategy(cfg(reset_every=20, refine_every=1000, prune_opa=0.005))
    state = strat.initialize_state()
    strat.step_post_backward(params, opts, state, 19, fake_info(3, {}))
    assert torch.sigmoid(params["opacities"]).min() > 0.4
    strat.step_post_backward(params, opts, state, 20, fake_info(3, {}))
    torch.testing.assert_close(torch.sigmoid(params["opacities"].detach()), torch.full((3,), 0.01))
    # nothing happens at / after refine_stop_iter, not even accumulation
    strat = DefaultStrategy(cfg(reset_every=20, refine_stop_iter=40))
    params, opts = make_params(3)
    state = strat.initialize_state()
    assert strat.step_post_backward(params, opts, state, 40, fake_info(3, {0: 1.0})) == {
        "n_clone": 0, "n_split": 0, "n_prune": 0,
    }
    assert state["grad2d"] is None and torch.sigmoid(params["opacities"]).min() > 0.4


def test_opacity_decay_from_refine_start_to_the_end_without_reset():
    strat = DefaultStrategy(cfg(refine_start_iter=10, refine_stop_iter=20, refine_every=1000, reset_every=None,
                                opacity_decay=0.9))
    params, opts = make_params(3)
    state = strat.initialize_state()
    for step in range(1, 31):
        strat.step_post_backward(params, opts, state, step, fake_info(3, {}))
    # steps 11..30 decay (also after refine_stop_iter); reset_every=None never clamps to 2 * prune_opa
    torch.testing.assert_close(torch.sigmoid(params["opacities"].detach()), torch.full((3,), 0.5 * 0.9**20))
    params, opts = make_params(3)
    for step in range(1, 31):
        DefaultStrategy(cfg(refine_every=1000, reset_every=None)).step_post_backward(
            params, opts, strat.initialize_state(), step, fake_info(3, {}))
    torch.testing.assert_close(torch.sigmoid(params["opacities"].detach()), torch.full((3,), 0.5))
    with pytest.raises(ValidationError):
        cfg(opacity_decay=0.0)
    with pytest.raises(ValidationError):
        cfg(opacity_decay=1.5)


def test_pause_refine_after_reset():
    params, opts = make_params(3)
    strat = DefaultStrategy(cfg(reset_every=100, refine_every=10, pause_refine_after_reset=30))
    state = strat.initialize_state()
    assert strat.step_post_backward(params, opts, state, 120, fake_info(3, {0: 1.0}))["n_clone"] == 0
    assert strat.step_post_backward(params, opts, state, 130, fake_info(3, {0: 1.0}))["n_clone"] == 1


def test_missing_grad_and_row_mismatch_fail_loudly():
    params, opts = make_params(3)
    strat = DefaultStrategy(cfg())
    state = strat.initialize_state()
    info = fake_info(3, {})
    info["means2d"].grad = None
    with pytest.raises(RuntimeError, match="step_pre_backward"):
        strat.step_post_backward(params, opts, state, 1, info)
    strat.step_post_backward(params, opts, state, 1, fake_info(3, {}))
    params2, opts2 = make_params(4)
    with pytest.raises(RuntimeError, match="initialize_state"):
        strat.step_post_backward(params2, opts2, state, 2, fake_info(4, {}))


def test_full_sequence_grows_then_prunes():
    """Real autograd: a loss pulls means2d; positional grads grow the set, then opacity decay prunes."""
    torch.manual_seed(0)
    params, opts = make_params(8)
    strat = DefaultStrategy(
        cfg(refine_start_iter=5, refine_every=5, reset_every=1000, refine_stop_iter=60, prune_opa=0.3)
    )
    strat.check_sanity(params, opts)
    state = strat.initialize_state(scene_scale=1.0)
    history = []
    for step in range(60):
        n = params["means"].shape[0]
        means2d = params["means"][:, :2] * 50.0 + 50.0  # fake projection, pixels
        info = {"means2d": means2d, "radii": torch.full((n,), 3, dtype=torch.int32), "width": 100, "height": 100}
        strat.step_pre_backward(params, opts, state, step, info)
        growing = step < 30
        loss = (means2d - 10.0).square().mean() * (1.0 if growing else 0.0)
        loss = loss + (torch.sigmoid(params["opacities"]) - (0.9 if growing else 0.0)).square().sum()
        loss = loss + sum(0.0 * params[k].sum() for k in ("quats", "scales", "sh0", "shN"))
        loss.backward()
        counts = strat.step_post_backward(params, opts, state, step, info)
        history.append((step, params["means"].shape[0], counts))
        for o in opts.values():
            if o is opts["opacities"] and not growing:
                for g in o.param_groups:
                    g["lr"] = 0.5
            o.step()
            o.zero_grad(set_to_none=True)
        assert_aligned(params, opts)
    sizes = [h[1] for h in history]
    assert max(sizes) > 8, history
    assert sum(h[2]["n_clone"] for h in history) > 0
    assert sum(h[2]["n_prune"] for h in history) > 0
    assert sizes[-1] < max(sizes)


def test_configs_saved_before_the_ray_rule_moved_still_load():
    """config.json of older runs holds strategy.never_prune_key / child_defaults (now SCGaussian's
    RayGaussianStrategy) or steps_per_view (now schedule_views): they are dropped on reading, and
    SCGaussian models use that strategy."""
    from scg_plugin.method import config_scgaussian
    from scg_plugin.strategy import RayGaussianStrategy
    from splat_framework.config import TrainConfig, upgrade_saved_config

    for config in (TrainConfig(method="3dgs"), config_scgaussian()):
        raw = config.model_dump(mode="json")
        raw["strategy"] |= {"never_prune_key": "is_match", "child_defaults": {"is_ray": 0.0}}
        raw["steps_per_view"] = 250  # became schedule_views (same iteration counts)
        with pytest.raises(ValidationError):
            type(config).model_validate(raw)
        assert type(config).model_validate(upgrade_saved_config(raw, 1, config)) == config
    params, opts = make_params(3, is_ray=[1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="is_match"):
        RayGaussianStrategy(cfg()).check_sanity(params, opts)

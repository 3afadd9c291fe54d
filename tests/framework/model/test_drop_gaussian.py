"""DropGaussian: training renders drop random Gaussians (opacity compensated), evaluation renders all."""

from __future__ import annotations

import pytest
import torch

from splat_framework.config import RunFacts, apply_overrides
from splat_framework.data import DataManager, load_scene
from splat_framework.data.synthetic import generate_scene
from splat_framework.model.gaussians import GaussianModel
from splat_framework.registry import get_method


@pytest.fixture(scope="module")
def dm(tmp_path_factory):
    root = generate_scene("forward", tmp_path_factory.mktemp("drop") / "scene", width=48, height=36, n_views=4, seed=2)
    return DataManager(load_scene(root, views=3), device="cpu", seed=0)


def _config(method: str, rate: float, seed: int = 0, noise: float = 0.0):
    return apply_overrides(get_method(method).default_config(),
                           {"steps": 100, "seed": seed, "model": {"reg": {"drop_rate": rate, "opacity_noise": noise},
                                                                  "init": {"num_points": 2000}}})


def _model(dm, rate: float, seed: int = 0, noise: float = 0.0) -> GaussianModel:
    cfg = _config("3dgs", rate, seed, noise)
    return GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))


def test_drop_rate_ramps_with_the_run_and_is_a_function_of_seed_and_step(dm):
    model = _model(dm, 0.4)
    ones = torch.ones(model.num_gaussians)

    def kept(m, step):
        return m.drop_opacities(ones, step)

    assert torch.equal(model.drop_opacities(ones, None), ones)  # not a training render
    assert torch.equal(kept(model, 0), ones)  # the ramp starts at 0
    keep = kept(model, 50)
    rate = 0.4 * 50 / 100
    assert keep.unique().tolist() == [0.0, pytest.approx(1 / (1 - rate))]
    assert (keep == 0).float().mean().item() == pytest.approx(rate, abs=0.03)
    assert torch.equal(keep, kept(model, 50))  # same seed and step: same draw
    assert not torch.equal(keep, kept(model, 51))
    assert not torch.equal(keep, kept(_model(dm, 0.4, seed=1), 50))
    # past the run's end the rate stays at its maximum
    assert (kept(model, 500) == 0).float().mean().item() == pytest.approx(0.4, abs=0.03)


def test_dropped_gaussians_get_no_gradient_and_evaluation_renders_all(dm):
    cam, _ = next(iter(dm.train_views()))
    model, plain = _model(dm, 0.5), _model(dm, 0.0)
    keep = model.drop_opacities(torch.ones(model.num_gaussians), 80)
    out = model.get_outputs(cam, step=80)
    out.rgb.sum().backward()
    grad = model.params["opacities"].grad
    assert torch.all(grad[keep == 0] == 0)
    assert grad[keep > 0].abs().sum() > 0
    assert not torch.allclose(out.rgb, plain.get_outputs(cam, step=80).rgb)  # rate 0: the full model
    with torch.no_grad():
        assert torch.equal(model.get_outputs(cam).rgb, plain.get_outputs(cam).rgb)


def test_opacity_noise_is_multiplicative_per_step_and_off_in_evaluation(dm):
    """Co-Adaptation's opacity noise: o (1 + sigma eps), floored at 0, drawn per (seed, step) after
    DropGaussian's draw; not applied where step is None."""
    model = _model(dm, 0.0, noise=0.3)
    half = torch.full((model.num_gaussians,), 0.5)
    noisy = model.drop_opacities(half, 40)
    assert torch.equal(model.drop_opacities(half, None), half)
    assert torch.equal(noisy, model.drop_opacities(half, 40)) and not torch.equal(noisy, model.drop_opacities(half, 41))
    factor = noisy / 0.5 - 1.0
    assert noisy.min() >= 0 and factor.mean().abs() < 0.03 and factor.std().item() == pytest.approx(0.3, abs=0.03)
    both = _model(dm, 0.4, noise=0.3).drop_opacities(half, 50)  # dropped rows stay dropped
    dropped = _model(dm, 0.4).drop_opacities(half, 50) == 0
    assert torch.all(both[dropped] == 0) and torch.all(both[~dropped] != half[~dropped])


def test_anchor_models_drop_their_decoded_gaussians(dm):
    from anchor_gs.model import ScaffoldModel

    cfg = _config("scaffold-gs", 0.6)
    model = ScaffoldModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cam, _ = next(iter(dm.train_views()))
    with torch.no_grad():
        full = model.get_outputs(cam)
        dropped = model.get_outputs(cam, step=100)
        assert not torch.allclose(full.rgb, dropped.rgb)
        assert torch.equal(full.rgb, model.get_outputs(cam).rgb)


def test_keyed_generators_repeat_per_key_and_do_not_collide():
    """The (seed, step) draw does not alias another seed's draw at a shifted step (as a linear mix
    seed * K + step would)."""
    from splat_framework.runtime.rng import keyed_generator

    def draw(*key):
        return torch.rand(8, generator=keyed_generator(*key))

    assert torch.equal(draw(3, 7), draw(3, 7))
    assert not torch.equal(draw(0, 1_000_003), draw(1, 0))
    assert not torch.equal(draw(0, 1), draw(1, 0))

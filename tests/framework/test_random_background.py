"""Random training backgrounds (``random_background``, off by default): each step's colour comes
from the seed and the step alone, only scenes of opaque photos take one, and what it is for: a model
trained over it renders its training views opaque, where one trained over black leaves see-through
Gaussians in front of dark parts of the photos."""

from __future__ import annotations

import pytest
import torch

from splat_framework.config import apply_overrides
from splat_framework.engine.trainer import Trainer
from splat_framework.registry import get_method


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPLAT_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("SPLAT_THREADS", "1")


def trainer(tmp_path, name: str, **over) -> Trainer:
    cfg = get_method("3dgs").default_config()
    base = {"data": "synthetic/forward-tiny", "output": str(tmp_path / name), "steps": 150, "progress": False,
            "save_renders": False, "model": {"init": {"num_points": 500}}}
    return Trainer(apply_overrides(apply_overrides(cfg, base), over))


def test_a_steps_background_is_drawn_from_the_seed_and_the_step(tmp_path):
    on = trainer(tmp_path, "a", random_background=True).pipeline
    colours = torch.stack([on.train_background(step) for step in range(4)])
    assert colours.shape == (4, 3) and colours.min() >= 0 and colours.max() <= 1
    assert len({tuple(c.tolist()) for c in colours}) == 4, "a new colour every step"
    again = trainer(tmp_path, "b", random_background=True).pipeline
    assert torch.equal(again.train_background(2), colours[2]), "the same run (or its resume) draws the same"
    other_seed = trainer(tmp_path, "c", random_background=True, seed=1).pipeline
    assert not torch.equal(other_seed.train_background(2), colours[2])
    off = trainer(tmp_path, "d").pipeline
    assert off.train_background(2) is off.background
    on.datamanager.scene.white_background = True  # RGBA photos composited on white keep their backdrop
    assert on.train_background(2) is on.background


def test_trained_over_random_colours_the_training_views_render_opaque(tmp_path):
    coverage = {}
    for random_background in (False, True):
        run = trainer(tmp_path, str(random_background), random_background=random_background)
        run.train()
        with torch.no_grad():
            alphas = [run.model.get_outputs(camera, run.background).alpha for camera, _ in run.datamanager.train_views()]
        coverage[random_background] = torch.cat([a.flatten() for a in alphas])
    # over black, dark pixels need no Gaussian in front of them; over random colours every pixel does
    see_through = {k: float((a < 0.9).float().mean()) for k, a in coverage.items()}
    assert see_through[True] < 0.02 < see_through[False], see_through

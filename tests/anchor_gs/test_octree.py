"""Octree-GS's geometry: the number of levels from the cameras' distances, the level of detail
chosen per view on a hand-made camera set, weeding, and progressive training."""

from __future__ import annotations

import math

import pytest
import torch

from anchor_gs.method import config_octree_gs
from anchor_gs.octree import OctreeModel, build_octree, coarse_intervals
from splat_framework.plugin import RunFacts
from splat_framework.testing import apply_overrides


def line_of_points(near: float = 1.0, far: float = 16.0, n: int = 61) -> torch.Tensor:
    """[n, 3] points on the +z axis from ``near`` to ``far`` (a camera sits at the origin)."""
    z = torch.linspace(near, far, n)
    return torch.stack([torch.zeros(n), torch.zeros(n), z], dim=-1)


def config(**model):
    return apply_overrides(config_octree_gs(), {"data": "synthetic/forward-tiny", "model": {"dist_ratio": 1.0} | model})


def model_args(**model):
    """(model config, run facts) of :func:`config`: what an Octree-GS model is built with."""
    cfg = config(**model)
    return cfg.model, RunFacts.of(cfg)


def test_levels_follow_the_ratio_of_far_to_near_distances():
    cams = torch.zeros(1, 3)
    tree = build_octree(config().model, line_of_points(1.0, 16.0), cams, base_size=0.5)
    assert tree.standard_dist == pytest.approx(16.0)
    assert tree.levels == 5 and tree.init_level == 2  # log2(16 / 1) + 1, training starts at levels // 2
    assert tree.size(2) == 0.5 and tree.size(0) == 2.0 and tree.size(4) == 0.125
    # the wanted level of detail: 0 at the standard distance, one finer per halving of the distance
    wanted = tree.pred_level(torch.tensor([[0, 0, 16.0], [0, 0, 8.0], [0, 0, 1.0]]), cams[0])
    assert torch.allclose(wanted, torch.tensor([0.0, 1.0, 4.0]))
    fixed = build_octree(config(levels=3, init_level=0).model, line_of_points(), cams, base_size=0.5)
    assert (fixed.levels, fixed.init_level) == (3, 0)


def test_each_view_draws_fine_levels_near_the_camera_and_coarse_ones_far_away():
    near_cam, far_cam = torch.tensor([[0.0, 0.0, 0.0]]), torch.tensor([[0.0, 0.0, 40.0]])
    cams = torch.cat([near_cam, far_cam])
    model = OctreeModel(*model_args(voxel_size=0.25), 1.0, line_of_points(), torch.rand(61, 3), cams)
    level, z = model.params["level"], model.params["anchors"][:, 2]
    assert set(level.tolist()) == set(map(float, range(model.octree.levels)))
    seen_near = model.lod_mask(near_cam[0])
    # from the origin an anchor at distance d is drawn when its level <= round(log2(d_max / d)) ...
    expected = level <= torch.round(torch.log2(model.octree.standard_dist / z.clamp_min(1e-9))).clamp(0, model.octree.levels - 1)
    assert torch.equal(seen_near, expected)
    # ... so the finest level is drawn only close to the camera, and the coarsest everywhere
    finest = level == model.octree.levels - 1
    assert bool(seen_near[finest & (z < 2)].all()) and not bool(seen_near[finest & (z > 8)].any())
    assert bool(seen_near[level == 0].all())
    # a camera farther away than every anchor draws coarser levels only
    assert int(model.lod_mask(far_cam[0]).sum()) < int(seen_near.sum())
    # extra_level (raised by the strategy) makes an anchor drawn from farther away
    far_fine = finest & (z > 8)
    with torch.no_grad():
        model.params["extra_level"][far_fine] = float(model.octree.levels)
    assert bool(model.lod_mask(near_cam[0])[far_fine].all())


def test_weeding_drops_anchors_no_training_camera_draws():
    cams = torch.zeros(1, 3)
    tree = build_octree(config(visible_threshold=0.0).model, line_of_points(), cams, base_size=0.5)
    positions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 15.0]])
    finest = torch.full((2,), float(tree.levels - 1))
    assert tree.keep(positions, finest).tolist() == [True, False]  # the finest level far away: never drawn
    assert tree.keep(positions, torch.zeros(2)).tolist() == [True, True]


def test_progressive_training_opens_one_level_after_another():
    intervals = coarse_intervals(levels=6, init_level=2, coarse_iter=250, coarse_factor=1.5)
    assert len(intervals) == 3 and intervals[-1] == pytest.approx(250.0)
    gaps = [intervals[0]] + [b - a for a, b in zip(intervals, intervals[1:])]
    assert all(math.isclose(g1 / g0, 1 / 1.5) for g0, g1 in zip(gaps, gaps[1:]))  # each shorter by coarse_factor
    assert coarse_intervals(levels=3, init_level=2, coarse_iter=250, coarse_factor=1.5) == []

    model = OctreeModel(*model_args(voxel_size=0.25), 1.0, line_of_points(), torch.rand(61, 3), torch.zeros(1, 3))
    tree, last = model.octree, model.octree.levels - 1
    assert model.max_level() == last  # not training: every level
    model.on_step_start(1)
    assert model.max_level() == tree.init_level
    opened = []
    for step in range(1, 300):
        model.on_step_start(step)
        opened.append(model.max_level())
    assert opened == sorted(opened) and opened[-1] == last and opened[251 - 1] == last
    model.on_step_start(1)
    assert not bool(model.lod_mask(torch.zeros(3))[model.params["level"] > tree.init_level].any())

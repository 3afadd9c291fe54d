"""`3dgs-triang` and `scgaussian` start exactly as before the triangulated initialisation moved from
`scg_plugin` into the framework (issue 18): row counts and per-parameter absolute sums of the
initial model on the built-in forward-tiny scene, recorded with the code of commit 55d1791 (the
last before the move)."""

from __future__ import annotations

import pytest
import torch

from scg_plugin.method import config_scgaussian
from scg_plugin.model import SCGaussianModel
from splat_framework.config import apply_overrides
from splat_framework.data import DataManager, load_scene
from splat_framework.data.synthetic import ensure_scene
from splat_framework.methods.triangulated import config_3dgs_triang
from splat_framework.model.triangulated import TriangulatedGaussianModel

BEFORE_THE_MOVE = {
    "3dgs-triang": (7437, {"means": 63731.444, "opacities": 16340.759, "quats": 7437.0, "scales": 48432.086,
                           "sh0": 15565.307, "shN": 0.0}),
    "scgaussian": (24874, {"is_match": 14874.0, "is_ray": 14874.0, "means": 242424.468, "opacities": 54653.765,
                           "quats": 24874.0, "ray_d": 20275.083, "ray_o": 4951.545, "scales": 146151.885,
                           "sh0": 31318.007, "shN": 0.0, "z": 95479.884}),
}


@pytest.mark.parametrize("method", sorted(BEFORE_THE_MOVE))
def test_initial_model_is_the_one_from_before_the_move(method):
    factory, model_class = {"3dgs-triang": (config_3dgs_triang, TriangulatedGaussianModel),
                            "scgaussian": (config_scgaussian, SCGaussianModel)}[method]
    dm = DataManager(load_scene(ensure_scene("forward-tiny"), views=3), device="cpu", seed=0)
    cfg = apply_overrides(factory(), {"data": "synthetic/forward-tiny"})
    torch.manual_seed(0)
    model = model_class.from_data(cfg, dm, torch.Generator().manual_seed(0))
    rows, sums = BEFORE_THE_MOVE[method]
    assert model.num_gaussians == rows
    got = {k: float(p.detach().double().abs().sum()) for k, p in model.params.items()}
    assert got == pytest.approx(sums, rel=1e-4, abs=1e-3)

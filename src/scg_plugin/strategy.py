"""SCGaussian's densification: 3DGS adaptive density control that keeps the Gaussians of matches."""

from __future__ import annotations

from typing import Mapping

import torch
from torch import Tensor

from splat_framework.plugin import DefaultStrategy

#: Per-row flags of SCGaussian's parameters: ``is_match`` (a Gaussian of a match, rows [0, G)) and
#: ``is_ray`` (its position is ``ray_o + z * ray_d``).
FLAG_KEYS = ("is_match", "is_ray")


class RayGaussianStrategy(DefaultStrategy):
    """:class:`DefaultStrategy` for the hybrid model: the Gaussians of matches are never pruned (rows
    ``[0, G)`` keep their order for the whole run), and clones / split children are ordinary Gaussians."""

    def check_sanity(self, params: Mapping[str, Tensor], optimizers: Mapping[str, torch.optim.Optimizer]) -> None:
        super().check_sanity(params, optimizers)
        for key in FLAG_KEYS:
            if key not in params:
                raise ValueError(f"params is missing SCGaussian's per-Gaussian flag {key!r}")

    def protected_rows(self, params: Mapping[str, Tensor]) -> Tensor:
        flag = params["is_match"].detach()
        return flag.reshape(flag.shape[0]) > 0.5

    def child_values(self, params: Mapping[str, Tensor]) -> dict[str, float]:
        return {key: 0.0 for key in FLAG_KEYS}

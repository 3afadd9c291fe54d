"""An MCMC-style densification strategy, after Kheradmand et al. 2024, "3D Gaussian Splatting as
Markov Chain Monte Carlo".

Every ``refine_every`` iterations the dead Gaussians (opacity at most ``min_opacity``) are
moved onto live ones drawn with probability proportional to opacity, and ``growth_rate`` more
are drawn the same way; a Gaussian drawn ``c`` times becomes ``c + 1`` Gaussians that together
render about as it did (the paper's eq. 9). Nearly transparent Gaussians take a random step
shaped by their covariance every iteration, and the loss holds the mean opacity and scale down.
Rows are rewritten with ``splat_framework.model.ops`` (``rewrite``, ``append``), which restart
their optimizer state.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from splat_framework.plugin import Strategy, check_rows, ops, quat_to_rotmat

MAX_COPIES = 51
"""Most Gaussians one Gaussian is split into at one refinement (further draws of it share the split)."""


def split_opacity_scale(opacity: Tensor, log_scales: Tensor, copies: Tensor) -> tuple[Tensor, Tensor]:
    """Opacity and log-scales of each of ``copies`` Gaussians replacing one (the paper's eq. 9).

    ``opacity`` [M] in (0, 1), ``log_scales`` [M, 3], ``copies`` [M] int >= 1. Returns the new
    opacity [M], ``1 - (1 - o)^(1 / copies)``, and log-scales [M, 3] scaled by ``o / d`` with
    ``d = sum_{i=1..copies} sum_{k<i} C(i-1, k) (-1)^k o_new^(k+1) / sqrt(k+1)``, so that
    ``copies`` overlapping Gaussians composite close to the one they replace."""
    o = opacity.double()
    n = copies.to(o.device, torch.long)
    o_new = 1.0 - (1.0 - o) ** (1.0 / n.double())
    size = int(n.max())
    k = torch.arange(size, device=o.device)
    binom = torch.tensor([[math.comb(a, b) for b in range(size)] for a in range(size)], dtype=o.dtype, device=o.device)
    coef = binom * ((-1.0) ** k / torch.sqrt(k + 1.0))  # [I, K]: C(i-1, k) (-1)^k / sqrt(k+1), row i-1
    inner = (o_new[:, None] ** (k + 1)) @ coef.T  # [M, I]
    denom = (inner * (k[None] < n[:, None])).sum(dim=1)
    factor = (o / denom).clamp_min(1e-12)
    return o_new.to(opacity.dtype), log_scales + torch.log(factor).to(log_scales.dtype)[:, None]


class MCMCStrategy(Strategy):
    """Relocation of dead Gaussians, growth by opacity-weighted draws, noise and regularisers
    (``MCMCConfig`` in ``splat_example_plugin``)."""

    REQUIRED_KEYS = ("means", "quats", "scales", "opacities")

    def check_sanity(self, params, optimizers) -> None:
        check_rows(params, optimizers, self.REQUIRED_KEYS)
        if "means" not in optimizers:
            raise ValueError("MCMCStrategy needs an optimizer for params['means'] (its noise follows its lr)")

    def loss(self, params, step: int) -> dict[str, Tensor]:
        cfg, out = self.config, {}
        if cfg.opacity_reg > 0:
            out["mcmc_opacity"] = cfg.opacity_reg * torch.sigmoid(params["opacities"]).mean()
        if cfg.scale_reg > 0:
            out["mcmc_scale"] = cfg.scale_reg * torch.exp(params["scales"]).mean()
        return out

    def step_post_backward(self, params, optimizers, state, step: int, info) -> dict[str, int]:
        cfg, counts = self.config, {}
        if cfg.refine_start_iter < step < cfg.refine_stop_iter and step % cfg.refine_every == 0:
            counts["n_relocate"] = self._relocate(params, optimizers, state)
            counts["n_add"] = self._add(params, optimizers, state)
        if cfg.noise_lr > 0:
            self._inject_noise(params, optimizers["means"].param_groups[0]["lr"])
        return counts

    @torch.no_grad()
    def _relocate(self, params, optimizers, state) -> int:
        """Move every dead Gaussian onto a live one drawn by opacity; returns how many moved."""
        opacity = torch.sigmoid(params["opacities"].flatten())
        dead = torch.where(opacity <= self.config.min_opacity)[0]
        alive = torch.where(opacity > self.config.min_opacity)[0]
        if len(dead) == 0 or len(alive) == 0:
            return 0
        sources = alive[torch.multinomial(opacity[alive], len(dead), replacement=True)]
        self._copy(params, optimizers, state, sources, dead)
        return len(dead)

    @torch.no_grad()
    def _add(self, params, optimizers, state) -> int:
        """Append ``growth_rate`` more Gaussians (up to ``cap_max``) drawn by opacity; returns how many."""
        n = params["means"].shape[0]
        n_add = max(0, min(self.config.cap_max, int(n * (1.0 + self.config.growth_rate))) - n)
        if n_add == 0:
            return 0
        opacity = torch.sigmoid(params["opacities"].flatten())
        sources = torch.multinomial(opacity, n_add, replacement=True)
        self._copy(params, optimizers, state, sources, None)
        return n_add

    def _copy(self, params, optimizers, state, sources: Tensor, targets: Tensor | None) -> None:
        """Split each drawn source among itself and its copies: the copies overwrite rows ``targets``
        [M] (one per draw in ``sources`` [M]), or are appended when ``targets`` is None."""
        unique, inverse, drawn = torch.unique(sources, return_inverse=True, return_counts=True)
        copies = (drawn + 1).clamp_max(MAX_COPIES)
        opacity = torch.sigmoid(params["opacities"][unique].flatten())
        new_opacity, new_scales = split_opacity_scale(opacity, params["scales"][unique], copies)
        lo = max(self.config.min_opacity, 1e-6)
        new_logit = torch.logit(new_opacity.clamp(lo, 1.0 - 1e-6)).reshape(params["opacities"][unique].shape)
        split = {key: p[unique].detach() for key, p in params.items()}
        split["opacities"], split["scales"] = new_logit, new_scales
        copied = {key: v[inverse] for key, v in split.items()}
        if targets is None:
            ops.rewrite(params, optimizers, state, unique, {"opacities": new_logit, "scales": new_scales})
            ops.append(params, optimizers, state, copied)
        else:
            rows = torch.cat([unique, targets])
            ops.rewrite(params, optimizers, state, rows, {key: torch.cat([split[key], copied[key]]) for key in split})

    @torch.no_grad()
    def _inject_noise(self, params, means_lr: float) -> None:
        """Move nearly transparent Gaussians by noise shaped by their covariance (the paper's SGLD step)."""
        opacity = torch.sigmoid(params["opacities"].flatten())
        gate = torch.sigmoid(100.0 * ((1.0 - opacity) - 0.995))  # about 1 below opacity 0.005, about 0 above
        rot = quat_to_rotmat(params["quats"])  # [N, 3, 3]
        var = torch.exp(params["scales"]) ** 2  # [N, 3]
        cov = rot @ (var[:, :, None] * rot.transpose(1, 2))  # [N, 3, 3]
        noise = torch.randn_like(params["means"]) * (gate * self.config.noise_lr * means_lr)[:, None]
        params["means"].add_(torch.einsum("nij,nj->ni", cov, noise))

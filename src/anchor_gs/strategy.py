"""Scaffold-GS's anchor growing and pruning as a framework ``Strategy``.

It sees the parameter and optimizer dicts, its own state and the renderer's ``meta``
(``info``), never the model. Statistics per anchor and offset slot (rows aligned with
the anchors, so ``splat_framework.model.ops`` resizes them with every row change):

- ``opacity_accum`` [A], ``anchor_denom`` [A]: summed neural opacities (clamped at 0) and
  the number of steps an anchor was decoded;
- ``offset_grad`` [A, k], ``offset_denom`` [A, k]: summed screen-space gradient norms
  (NDC units) of the drawn neural Gaussians with a footprint, and their counts.

Every ``update_interval`` steps within [update_from, update_until]: growing at
``update_depth`` levels i (threshold ``grad_threshold * (hierarchy_factor // 2)^i``, a
random half, a quarter, ... of the candidates, voxel size ``voxel * init_factor /
hierarchy_factor^i``): the positions of the candidate neural Gaussians are snapped to
that grid and each cell not yet holding an anchor gets one (feature: the max over its
candidates' anchors' features, zero offsets, scaling the cell size); then anchors seen
in more than ``success_threshold`` of the interval whose mean summed opacity is below
``min_opacity`` are removed.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import torch
from torch import Tensor

from splat_framework.plugin import Strategy, check_rows, ops

REQUIRED_KEYS = ("anchors", "offsets", "anchor_feat", "scaling")


class AnchorStrategy(Strategy):
    """Scaffold-GS anchor growing and pruning (see the module docstring)."""

    def __init__(self, config) -> None:
        self.config = config

    def initialize_state(self, scene_scale: float = 1.0) -> dict[str, Any]:
        return {"opacity_accum": None, "anchor_denom": None, "offset_grad": None, "offset_denom": None,
                "scene_scale": float(scene_scale)}

    REQUIRED = REQUIRED_KEYS

    def check_sanity(self, params, optimizers) -> None:
        check_rows(params, optimizers, self.REQUIRED)

    def step_pre_backward(self, params, optimizers, state, step: int, info: Mapping[str, Any]) -> None:
        if info["means2d"].requires_grad:
            info["means2d"].retain_grad()

    def step_post_backward(self, params, optimizers, state, step: int, info: Mapping[str, Any]) -> dict[str, int]:
        cfg = self.config
        counts = {"n_grow": 0, "n_prune": 0}
        if step > cfg.update_until or step <= cfg.start_stat:
            return counts
        self._accumulate(params, state, info)
        if step > cfg.update_from and step % cfg.update_interval == 0:
            counts["n_grow"] = self._grow(params, optimizers, state, info)
            counts["n_prune"] = self._prune(params, optimizers, state)
        return counts

    # ------------------------------------------------------------- internals
    def _fresh(self, params, state) -> None:
        a, k = params["offsets"].shape[:2]
        dev = params["anchors"].device
        if state["opacity_accum"] is None:
            state.update(opacity_accum=torch.zeros(a, device=dev), anchor_denom=torch.zeros(a, device=dev),
                         offset_grad=torch.zeros(a, k, device=dev), offset_denom=torch.zeros(a, k, device=dev))
        elif state["opacity_accum"].shape[0] != a:
            raise RuntimeError(f"strategy state has {state['opacity_accum'].shape[0]} rows but params have {a}: "
                               "anchors were added or removed outside the strategy")

    @torch.no_grad()
    def _accumulate(self, params, state, info) -> None:
        self._fresh(params, state)
        visible, opacity, kept = info["anchor_visible"], info["neural_opacity"], info["neural_kept"]
        grad = info["means2d"].grad
        if grad is None:
            raise RuntimeError("info['means2d'].grad is None: call step_pre_backward before backward()")
        state["opacity_accum"][visible] += opacity.clamp_min(0).sum(dim=1)
        state["anchor_denom"][visible] += 1
        k = opacity.shape[1]
        norms = torch.zeros(kept.shape[0], device=grad.device)
        drawn = torch.zeros_like(kept)
        g = grad.detach().reshape(-1, 2).clone()
        g[:, 0] *= info["width"] / 2.0
        g[:, 1] *= info["height"] / 2.0
        radii = info["radii"].detach().reshape(g.shape[0], -1).amax(dim=-1)
        idx = torch.where(kept)[0]
        norms[idx] = g.norm(dim=-1)
        drawn[idx] = radii > 0
        rows = torch.where(visible)[0]
        state["offset_grad"][rows] += norms.reshape(-1, k) * drawn.reshape(-1, k)
        state["offset_denom"][rows] += drawn.reshape(-1, k).float()

    @torch.no_grad()
    def _grow(self, params, optimizers, state, info) -> int:
        cfg = self.config
        voxel_size = info["voxel_size"]
        a0, k = params["offsets"].shape[:2]
        grads, ready = self._mean_grads(state)
        grown = 0
        for i in range(cfg.update_depth):
            a = params["anchors"].shape[0]
            threshold = cfg.grad_threshold * (cfg.hierarchy_factor // 2) ** i
            candidate = (grads >= threshold) & ready
            candidate &= torch.rand(candidate.shape, device=candidate.device) > 0.5 ** (i + 1)
            candidate = torch.cat([candidate, candidate.new_zeros(a - a0, k)])  # anchors grown at earlier levels
            if not bool(candidate.any()):
                continue
            size = voxel_size * cfg.init_factor / cfg.hierarchy_factor ** i
            scale = torch.exp(params["scaling"][:, :3])
            xyz = params["anchors"][:, None] + params["offsets"] * scale[:, None]  # [A, k, 3]
            cells, inverse = torch.unique(torch.round(xyz[candidate] / size), dim=0, return_inverse=True)
            occupied = torch.round(params["anchors"] / size)
            new = ~_rows_in(cells, occupied)
            if not bool(new.any()):
                continue
            cell_feat = _cell_max(params["anchor_feat"][:, None].expand(-1, k, -1)[candidate], inverse, cells.shape[0])
            m = int(new.sum())
            dev = params["anchors"].device
            ops.append(params, optimizers, state, {
                "anchors": cells[new] * size,
                "offsets": torch.zeros(m, k, 3, device=dev),
                "anchor_feat": cell_feat[new],
                "scaling": torch.full((m, 6), float(torch.log(torch.tensor(size))), device=dev),
            })
            grown += m
        self._restart_grads(state, ready)
        return grown

    def _mean_grads(self, state) -> tuple[Tensor, Tensor]:
        """[A, k] mean screen-space gradient of each neural Gaussian, and [A, k] bool: drawn in enough
        of the interval (half of ``success_threshold``) to be judged."""
        cfg = self.config
        grads = state["offset_grad"] / state["offset_denom"].clamp_min(1)
        return grads, state["offset_denom"] > cfg.update_interval * cfg.success_threshold * 0.5

    @staticmethod
    def _restart_grads(state, ready: Tensor) -> None:
        """Zero the gradient statistics of the judged neural Gaussians (rows of anchors before growing)."""
        a0 = ready.shape[0]
        state["offset_grad"][:a0][ready] = 0
        state["offset_denom"][:a0][ready] = 0

    @torch.no_grad()
    def _prune(self, params, optimizers, state) -> int:
        cfg = self.config
        seen = state["anchor_denom"] > cfg.update_interval * cfg.success_threshold
        weak = (state["opacity_accum"] < cfg.min_opacity * state["anchor_denom"]) & seen
        state["opacity_accum"][seen] = 0
        state["anchor_denom"][seen] = 0
        n = int(weak.sum())
        if n and n < weak.shape[0]:  # never remove every anchor
            ops.remove(params, optimizers, state, weak)
            return n
        return 0



class OctreeStrategy(AnchorStrategy):
    """Octree-GS anchor growing and Scaffold-GS's pruning.

    For each level l of the octree (``info["octree"]``), with u = fork^update_ratio and
    t_l = grad_threshold u^l: the judged neural Gaussians of level-l anchors whose mean
    gradient is in [t_l, t_l u) seed new level-l anchors (cell size of level l, feature
    the max over the seeds' anchors' features), those above t_l u seed level l+1 anchors
    (zero feature); cells already holding an anchor of that level and cells that too few
    training cameras draw at that level (the octree's weeding) are skipped. Anchors whose
    mean gradient over their judged neural Gaussians exceeds t_l extra_ratio raise their
    ``extra_level`` by ``extra_up`` for every level l (the public code adds it inside its
    per-level loop; its progressive-phase guard, ``~progressive or ...``, is always true on
    a Python bool, so this happens from the first update, as does the finer-level growing).
    """

    REQUIRED = REQUIRED_KEYS + ("level", "extra_level")

    @torch.no_grad()
    def _grow(self, params, optimizers, state, info) -> int:
        cfg, tree = self.config, info["octree"]
        a0, k = params["offsets"].shape[:2]
        grads, ready = self._mean_grads(state)
        grads = grads * ready
        anchor_grads = grads.sum(dim=1) / (ready.sum(dim=1) + 1e-6)  # [A0]
        u = float(tree.fork) ** cfg.update_ratio
        level0 = params["level"][:a0].clone()
        scale = torch.exp(params["scaling"][:a0, :3])
        xyz = params["anchors"][:a0, None] + params["offsets"][:a0] * scale[:, None]  # [A0, k, 3]
        feats = params["anchor_feat"][:a0, None].expand(-1, k, -1)  # [A0, k, F]
        extra = torch.zeros(a0, device=grads.device)
        grown = 0
        for level in range(tree.levels):
            at = (level0 == level)[:, None] & ready
            if not bool(at.any()):
                continue
            low = cfg.grad_threshold * u**level
            extra += (anchor_grads >= low * cfg.extra_ratio).float() * cfg.extra_up
            same = at & (grads >= low) & (grads < low * u)
            grown += self._add_level(params, optimizers, state, tree, level, xyz[same], feats[same])
            if level + 1 < tree.levels:
                finer = at & (grads >= low * u)
                grown += self._add_level(params, optimizers, state, tree, level + 1, xyz[finer], None)
        params["extra_level"][:a0] += extra
        self._restart_grads(state, ready)
        return grown

    @staticmethod
    def _add_level(params, optimizers, state, tree, level: int, seeds: Tensor, seed_feats: Tensor | None) -> int:
        """Anchors at ``level`` in the cells of ``seeds`` [S, 3] that hold none yet and that the training
        cameras draw; features the max of ``seed_feats`` [S, F] per cell (None: zeros). How many."""
        if seeds.shape[0] == 0:
            return 0
        cells, inverse = torch.unique(tree.cells(seeds, level), dim=0, return_inverse=True)
        occupied = tree.cells(params["anchors"][params["level"] == level], level)
        new = ~_rows_in(cells, occupied)
        positions = tree.centers(cells, level)
        levels = torch.full((cells.shape[0],), float(level), device=seeds.device)
        new &= tree.keep(positions, levels)
        m = int(new.sum())
        if m == 0:
            return 0
        f = params["anchor_feat"].shape[1]
        if seed_feats is None:
            feat = seeds.new_zeros(m, f)
        else:
            feat = _cell_max(seed_feats, inverse, cells.shape[0])[new]
        k = params["offsets"].shape[1]
        ops.append(params, optimizers, state, {
            "anchors": positions[new],
            "offsets": seeds.new_zeros(m, k, 3),
            "anchor_feat": feat,
            "scaling": torch.full((m, 6), math.log(tree.size(level)), device=seeds.device),
            "level": levels[new],
            "extra_level": seeds.new_zeros(m),
        })
        return m


def _cell_max(feats: Tensor, inverse: Tensor, n_cells: int) -> Tensor:
    """[n_cells, F]: per cell, the element-wise max of the rows of ``feats`` [S, F] that ``inverse`` [S] puts in it."""
    out = torch.full((n_cells, feats.shape[1]), -torch.inf, device=feats.device)
    return out.scatter_reduce(0, inverse[:, None].expand_as(feats), feats, reduce="amax")


def _rows_in(rows: Tensor, table: Tensor) -> Tensor:
    """[R] bool: whether each row of ``rows`` [R, 3] (integer-valued) occurs in ``table`` [T, 3]."""
    both = torch.cat([table, rows])
    _, inv = torch.unique(both, dim=0, return_inverse=True)
    present = torch.zeros(int(inv.max()) + 1 if inv.numel() else 0, dtype=torch.bool, device=rows.device)
    present[inv[: table.shape[0]]] = True
    return present[inv[table.shape[0]:]]

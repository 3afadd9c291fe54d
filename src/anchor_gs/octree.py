"""Octree-GS: Scaffold-GS anchors on the levels of an octree, drawn per view by distance.

Facts from the public code (city-super/Octree-GS, ``scene/gaussian_model.py``), not
its code:

- Levels: from each training camera the distances to the initial points give a
  near and a far quantile (``dist_ratio``); over all cameras, ``d_max`` (the far
  quantile of those) is the *standard distance* and the number of levels is
  ``round(log_fork(d_max / d_min)) + 1``; training starts at level ``levels // 2``.
- Anchors: the initial points voxelised at every level (level l: cell size
  ``voxel_size_0 / fork^l``), then *weeded*: an anchor stays only when more than
  ``visible_threshold`` of the training cameras select its level.
- Level of detail per view: an anchor at distance d from the camera is drawn when
  its level is <= ``round(log_fork(standard_dist / d) + extra_level)`` (clamped to the
  levels open). With progressive training the levels above ``init_level`` open one by
  one over ``coarse_iter`` iterations, at the partial sums of a geometric series of
  ratio ``1 / coarse_factor``.
- Decoding, losses and pruning are Scaffold-GS's (appearance embedding off, as in the
  public code's ``single_train.sh``).

Grid geometry differs in one documented point: the public code sizes its voxels from a
hard-coded 0.02 world units (``base_layer``), a per-scene-scale constant. Here the
initial level takes Scaffold-GS's rule (the median distance of the initial points to
their 3 nearest neighbours), so the grid follows the scene's scale; levels coarser and
finer scale by ``fork``. The grid's origin is the initial points' minimum corner.

Per-row parameters beyond Scaffold-GS's: ``level`` [A] (float, fixed) and
``extra_level`` [A] (fixed by Adam, raised by the strategy).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .model import ScaffoldModel


@dataclass
class Octree:
    """The octree's geometry, shared by the model (level of detail) and the strategy (growing)."""

    fork: int
    levels: int
    init_level: int
    base_size: float
    """Voxel size at ``init_level``."""
    origin: Tensor
    """[3] grid origin."""
    standard_dist: float
    camera_centers: Tensor
    """[C, 3] training camera centres (weeding)."""
    visible_threshold: float

    def size(self, level: int) -> float:
        """Voxel size of ``level``."""
        return self.base_size * float(self.fork) ** (self.init_level - level)

    def pred_level(self, positions: Tensor, center: Tensor) -> Tensor:
        """[N] fractional level of detail wanted at ``positions`` [N, 3] seen from ``center`` [3]."""
        dist = (positions - center.to(positions)).norm(dim=-1).clamp_min(1e-9)
        return torch.log2(self.standard_dist / dist) / math.log2(self.fork)

    def cells(self, positions: Tensor, level: int) -> Tensor:
        """[N, 3] integer cell coordinates of ``positions`` at ``level``."""
        return torch.round((positions - self.origin.to(positions)) / self.size(level))

    def centers(self, cells: Tensor, level: int) -> Tensor:
        """[N, 3] positions of the cells ``cells`` (from :meth:`cells`) at ``level``."""
        return cells * self.size(level) + self.origin.to(cells)

    def keep(self, positions: Tensor, levels: Tensor) -> Tensor:
        """[N] bool: anchors at ``positions`` [N, 3] on ``levels`` [N] that more than
        ``visible_threshold`` of the training cameras draw."""
        count = torch.zeros(positions.shape[0], device=positions.device)
        for c in self.camera_centers:
            wanted = torch.round(self.pred_level(positions, c)).clamp(0, self.levels - 1)
            count += (levels <= wanted).float()
        return count / max(len(self.camera_centers), 1) > self.visible_threshold

    def state(self) -> dict:
        return {k: (v.detach().cpu() if torch.is_tensor(v) else v) for k, v in vars(self).items()}


def build_octree(cfg, points: Tensor, camera_centers: Tensor, base_size: float) -> Octree:
    """The octree of ``points`` [N, 3] seen by cameras at ``camera_centers`` [C, 3] (module docstring)."""
    dist = torch.cdist(camera_centers.to(points), points)  # [C, N]
    r = cfg.dist_ratio
    near_far = torch.cat([torch.quantile(dist, 1 - r, dim=1), torch.quantile(dist, r, dim=1)])
    d_max, d_min = float(torch.quantile(near_far, r)), float(torch.quantile(near_far, 1 - r))
    levels = cfg.levels or int(round(math.log2(d_max / max(d_min, 1e-9)) / math.log2(cfg.fork))) + 1
    levels = max(levels, 1)
    init_level = cfg.init_level if cfg.init_level >= 0 else levels // 2
    if init_level >= levels:
        raise ValueError(f"model.init_level {init_level} must be below the number of levels ({levels})")
    return Octree(fork=cfg.fork, levels=levels, init_level=init_level, base_size=base_size,
                  origin=points.min(dim=0).values, standard_dist=d_max, camera_centers=camera_centers.to(points),
                  visible_threshold=cfg.visible_threshold)


def coarse_intervals(levels: int, init_level: int, coarse_iter: int, coarse_factor: float) -> list[float]:
    """Iterations at which the levels above ``init_level`` open: the partial sums of a geometric series
    of ratio 1 / coarse_factor summing to ``coarse_iter``."""
    n = levels - 1 - init_level
    if n <= 0:
        return []
    q = 1.0 / coarse_factor
    first = coarse_iter * (1 - q) / (1 - q**n) if q != 1 else coarse_iter / n
    return [first * (1 - q ** (i + 1)) / (1 - q) if q != 1 else first * (i + 1) for i in range(n)]


class OctreeModel(ScaffoldModel):
    """Octree-GS (see the module docstring)."""

    FIXED = ("anchors", "level", "extra_level")

    def __init__(self, config, run, scene_scale: float, points: Tensor | None, colors: Tensor | None,
                 camera_centers: Tensor | None = None, *, rows=None):
        if camera_centers is None and rows is None:
            raise ValueError("OctreeModel needs the training camera centres")
        self._camera_centers = camera_centers
        self.step = None  # a model rebuilt from a checkpoint opens every level (its octree comes with its extra state)
        super().__init__(config, run, scene_scale, points, colors, camera_centers, rows=rows)

    def init_params(self, points: Tensor, colors: Tensor) -> dict[str, nn.Parameter]:
        points = points.float()
        self.octree = tree = build_octree(self.config, points, self._camera_centers.float(), self.voxel_size)
        positions, levels = [], []
        for level in range(tree.levels):
            cells = torch.unique(tree.cells(points, level), dim=0)
            positions.append(tree.centers(cells, level))
            levels.append(torch.full((cells.shape[0],), float(level), device=points.device))
        positions, levels = torch.cat(positions), torch.cat(levels)
        keep = tree.keep(positions, levels)
        if not bool(keep.any()):
            raise ValueError("Octree-GS: no anchor is drawn by any training camera (model.visible_threshold too high?)")
        params = self.anchor_params(positions[keep].contiguous())
        params["level"] = nn.Parameter(levels[keep], requires_grad=False)
        params["extra_level"] = nn.Parameter(torch.zeros_like(levels[keep]), requires_grad=False)
        return params

    @classmethod
    def from_data(cls, config, run, datamanager, generator):
        model = super().from_data(config, run, datamanager, generator)
        model.init_stats = dict(model.init_stats) | {"levels": model.octree.levels, "init_level": model.octree.init_level}
        return model

    # ------------------------------------------------------- level of detail
    def on_step_start(self, step: int) -> None:
        """Remember the training step: progressive training caps the levels drawn until coarse_iter."""
        self.step = step

    def max_level(self) -> int:
        """The finest level open now: all of them unless training progressively (a model rebuilt from a
        checkpoint, not training, opens all)."""
        cfg, tree = self.config, self.octree
        if not cfg.progressive or self.step is None:
            return tree.levels - 1
        opened = bisect.bisect_left(coarse_intervals(tree.levels, tree.init_level, cfg.coarse_iter, cfg.coarse_factor),
                                    self.step)
        return min(tree.init_level + opened, tree.levels - 1)

    def lod_mask(self, center: Tensor) -> Tensor:
        """[A] bool: anchors whose level is at most the level of detail wanted at their distance from
        ``center`` [3] (plus their extra_level), within the levels open."""
        p = self.params
        wanted = self.octree.pred_level(p["anchors"].detach(), center) + p["extra_level"]
        return p["level"] <= torch.round(wanted).clamp(0, self.max_level())

    def render_meta(self) -> dict:
        return {"octree": self.octree}

    # ----------------------------------------------------------------- state
    def extra_state(self) -> dict:
        return super().extra_state() | {"octree": self.octree.state()}

    def load_extra_state(self, state: dict) -> None:
        super().load_extra_state(state)
        dev = self.params["anchors"].device
        fields = dict(state["octree"])
        fields["origin"] = torch.as_tensor(fields["origin"]).float().to(dev)
        fields["camera_centers"] = torch.as_tensor(fields["camera_centers"]).float().to(dev)
        self.octree = Octree(**fields)

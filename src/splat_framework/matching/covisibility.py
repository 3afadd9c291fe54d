"""Which training views the matching prior pairs, once their poses are known: each view with its few
best partners by how much of what it sees the other sees too, not every pair.

The score of a pair is the overlap of the two cameras' frusta, measured both ways on sample points
(a pixel grid at depths spread evenly in disparity between each camera's near and far bounds),
times the cosine of the angle between their optical axes (zero past 90 degrees: two cameras facing
each other across an object see its two sides). It needs the poses and bounds only, so it serves
every dataset alike; the rule and its measurements are in docs/decisions.md ("The prior pairs each
view with its best partners").
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from ..cameras import Camera

ALL_PAIRS_MAX_VIEWS = 8
"""Up to this many training views the prior matches every pair (``partners`` None: the default)."""
PARTNERS = 3
"""Beyond :data:`ALL_PAIRS_MAX_VIEWS`, each training view's partners by default."""
GRID = 12
"""Pixels per image side sampled for the overlap (GRID x GRID rays)."""
DEPTHS = 8
"""Depths sampled along each ray, evenly in disparity between the camera's near and far."""


def sample_points(cam: Camera) -> Tensor:
    """[GRID * GRID * DEPTHS, 3] world points spread through ``cam``'s frustum."""
    u = (torch.arange(GRID, dtype=torch.float64) + 0.5) / GRID * cam.width
    v = (torch.arange(GRID, dtype=torch.float64) + 0.5) / GRID * cam.height
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    near, far = max(float(cam.near), 1e-6), max(float(cam.far), float(cam.near) * 1.0001)
    disparity = torch.linspace(1.0 / near, 1.0 / far, DEPTHS, dtype=torch.float64)
    z = (1.0 / disparity)[:, None].expand(DEPTHS, uv.shape[0])
    return _float64(cam).unproject_depth(uv[None].expand(DEPTHS, -1, -1), z).reshape(-1, 3)


def _float64(cam: Camera) -> Camera:
    """``cam`` with its matrices in float64 on the CPU."""
    return replace(cam, K=cam.K.double().cpu(), world_to_cam=cam.world_to_cam.double().cpu())


def seen_fraction(cam: Camera, points: Tensor) -> float:
    """The fraction of ``points`` [N, 3] in front of ``cam`` and inside its image."""
    uv, z = _float64(cam).project(points)
    inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
    return float(inside.double().mean())


def covisibility(cameras: list[Camera]) -> Tensor:
    """[n, n] symmetric scores in [0, 1] (the diagonal 0): the smaller of the two frustum overlaps
    (each camera's sample points the other sees), times the cosine of the angle between the optical
    axes, clamped at 0."""
    n = len(cameras)
    points = [sample_points(c) for c in cameras]
    axes = torch.stack([c.world_to_cam[2, :3].double().cpu() for c in cameras])  # each camera's +z in world
    axes = axes / axes.norm(dim=-1, keepdim=True)
    score = torch.zeros(n, n, dtype=torch.float64)
    for i in range(n):
        for j in range(i + 1, n):
            overlap = min(seen_fraction(cameras[j], points[i]), seen_fraction(cameras[i], points[j]))
            score[i, j] = score[j, i] = overlap * max(float(axes[i] @ axes[j]), 0.0)
    return score


def partner_pairs(cameras: list[Camera], ids: list[int], partners: int) -> list[tuple[int, int]]:
    """The pairs (view id a < view id b) of each view with its ``partners`` best-scoring others
    (:func:`covisibility`; ties to the lower index), united: every pair when there are at most
    ``partners + 1`` views, and at most ``len(ids) * partners`` pairs beyond."""
    n = len(ids)
    score = covisibility(cameras)
    chosen = set()
    for i in range(n):
        others = sorted((j for j in range(n) if j != i), key=lambda j: (-float(score[i, j]), j))
        for j in others[:partners]:
            chosen.add((min(ids[i], ids[j]), max(ids[i], ids[j])))
    return sorted(chosen)


def partners_for(partners: int | None, n_views: int) -> int | None:
    """The partners each of ``n_views`` training views takes: ``partners`` as set (0: every pair,
    None), else every pair up to :data:`ALL_PAIRS_MAX_VIEWS` views and :data:`PARTNERS` beyond."""
    if partners is None:
        return None if n_views <= ALL_PAIRS_MAX_VIEWS else PARTNERS
    return partners or None


__all__ = ["ALL_PAIRS_MAX_VIEWS", "PARTNERS", "covisibility", "partner_pairs", "partners_for"]

"""SCGaussian's init, one named step each, in the order :meth:`SCGaussianModel.from_data` runs them.

1. :func:`ray_prior`: match every pair of training views
   (:func:`splat_framework.plugin.compute_match_set`, cached on disk) and bind two ray-based Gaussians to each verified match
   (:class:`~scg_plugin.ray_gaussians.RayBundle`); None when fewer than
   ``min_matches`` were found (one warning).
2. :func:`warm_up_prior`: the first stage of the two-stage schedule: optimise the
   depths ``z`` alone with L_gp, keep each match's best depths and drop the
   matches whose reprojection error stays above ``filter_eta_px`` (cache and filter).
3. :func:`ordinary_points`: the ordinary (free) Gaussians to start with:
   ``init.num_points`` random ones, or at least ``FALLBACK_POINTS`` when the
   prior is missing or sparse (one warning); a start with points of its own
   (``--model.init.kind ply``) gives them all, whatever the prior.
4. :func:`thin_prior`: whether the prior is missing or sparse; the pipeline
   (:class:`~scg_plugin.pipeline.SCGaussianPipeline`) then trains the run with the 3dgs baseline's
   densification and SH schedules (the framework's ``baseline_schedule``, ``thin_prior_baseline``),
   the run's one config unchanged.

Each step returns what the next needs and records its own wall time.
"""

from __future__ import annotations

import time
import warnings

import torch
from torch import Tensor

from splat_framework.plugin import FALLBACK_POINTS, Camera, compute_match_set, initial_points, match_pairs, phase

from .ray_gaussians import MatchCache, RayBundle, build_ray_bundle, warm_up, warmup_step_size


def ray_prior(cfg, datamanager, generator: torch.Generator, timing: dict, stats: dict) -> tuple[RayBundle | None, int]:
    """Step 1: (the ray bundle of the verified matches or None, the number of matches found);
    ``cfg``: the model's config.

    ``timing["matching_s"]`` and ``stats["matches_digest"]`` (``MatchSet.digest``: which matches the
    run trained on) are set."""
    views = datamanager.train_views()
    ids = [int(b["index"]) for _, b in views]
    t0 = time.perf_counter()
    match_set = compute_match_set(cfg.matching, datamanager)
    timing["matching_s"] = time.perf_counter() - t0
    stats["matches_digest"] = match_set.digest()
    bundle = build_ray_bundle(match_pairs(match_set, ids), [c.to("cpu") for c, _ in views], generator)
    n_matches = len(bundle) // 2
    if n_matches < cfg.min_matches:
        fill = random_fill(cfg)
        warnings.warn(
            f"only {n_matches} verified matches between the {len(ids)} training views "
            f"(fewer than min_matches={cfg.min_matches}): falling back to "
            + (f"{fill} random ordinary Gaussians" if fill is not None else
               f"the ordinary Gaussians of the {cfg.init.kind} start alone"),
            stacklevel=3,
        )
        return None, n_matches
    return bundle, n_matches


def warm_up_prior(bundle: RayBundle | None, cameras: list[Camera], cfg, timing: dict, stats: dict) -> RayBundle | None:
    """Step 2: the bundle after the z warm-up and cache-and-filter (two-stage schedule only).

    ``cameras`` are the training cameras on the CPU; ``timing["warmup_s"]`` and
    (when filtering) ``stats["filtered_matches"]`` are set."""
    t0 = time.perf_counter()
    if bundle is not None and cfg.schedule == "two-stage" and cfg.warmup_steps > 0:
        cache = MatchCache(bundle) if cfg.cache_filter else None
        with phase("SCGaussian warm-up", cfg.warmup_steps, unit="iterations") as progress:
            lr = warmup_step_size(cfg.warmup_lr, cfg.warmup_lr_unit, bundle)
            z = warm_up(bundle, cameras, cfg.warmup_steps, lr, cfg.warmup_lr_halve_every, cache, on_step=progress.advance)
        if cache is not None:
            bundle.z = cache.best_z
            keep = cache.keep_mask(cfg.filter_eta_px)
            stats["filtered_matches"] = int((~keep).sum()) // 2
            bundle = bundle.select(keep)
        else:
            bundle.z = z
    timing["warmup_s"] = time.perf_counter() - t0
    return bundle


def thin_prior(cfg, bundle: RayBundle | None, n_matches: int) -> bool:
    """Whether the prior is missing (None: fewer than ``min_matches``) or sparse (fewer than ``sparse_matches``)."""
    return bundle is None or n_matches < cfg.sparse_matches


def random_fill(cfg) -> int | None:
    """Random ordinary Gaussians that a missing or sparse prior is filled with:
    ``max(init.num_points, FALLBACK_POINTS)``; None for a start with points of its own (a PLY's)."""
    return max(cfg.init.num_points, FALLBACK_POINTS) if hasattr(cfg.init, "num_points") else None


def ordinary_points(
    cfg, datamanager, bundle: RayBundle | None, n_matches: int, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Step 3: (points [N, 3], colours [N, 3]) of the ordinary Gaussians to start with, on the images' device.

    ``init.num_points`` random ones placed by ``init.kind`` (none for the only-ray variant), or
    ``max(init.num_points, FALLBACK_POINTS)`` when there is no prior or fewer
    than ``sparse_matches`` matches (one warning); the points of a start that has its own
    (a PLY's, whatever the prior)."""
    views = datamanager.train_views()
    n_fill = random_fill(cfg)
    if n_fill is None:
        start = initial_points(cfg.init, datamanager, generator)
        return start.points, start.colors
    sparse = bundle is not None and thin_prior(cfg, bundle, n_matches)
    if sparse:
        warnings.warn(
            f"only {n_matches} verified matches between the {len(views)} training views "
            f"(fewer than sparse_matches={cfg.sparse_matches}): adding {n_fill} random ordinary Gaussians",
            stacklevel=3,
        )
    n_rand = n_fill if bundle is None or sparse else cfg.init.num_points
    if n_rand > 0:
        start = initial_points(cfg.init.model_copy(update={"num_points": n_rand}), datamanager, generator)
        return start.points, start.colors
    empty = torch.zeros(0, 3, device=views[0][1]["image"].device)
    return empty, empty.clone()

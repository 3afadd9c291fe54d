"""The matching prior of a scene's training views, and points triangulated from it.

Every method can start from it: SCGaussian binds Gaussians to the matched rays,
``3dgs-triang`` (and any plugin's ``-triang`` variant) starts ordinary Gaussians at
the matches triangulated with the known poses (:func:`triangulated_points`; the init kind
"triangulated" is :func:`triangulated_init`).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from torch import Tensor

from ..cameras import Camera
from ..config.matching import MatchConfig
from ..console import say
from ..data.cache_dir import user_cache_dir
from ..model.init import StartPoints, initial_points
from .matchset import MatchSet
from .report import view_names, warn_empty

MIN_TRIANGULATED = 50
"""Fewer triangulated points than this: the run warns and starts from the kind's fallback instead."""


def compute_match_set(matching: MatchConfig, datamanager) -> MatchSet:
    """Matches between all pairs of training views (cached on disk unless ``matching.cache`` is off), with
    a line naming the pairs left empty (for photos posed by splat, saying whether the poses lack any:
    an information line when every photo registered) and a warning naming the views without any
    verified match (each view by its image's name, :func:`~.report.warn_empty`; also when the matches
    come from the cache)."""
    from ..sfm.posing_record import posing_record
    from .pipeline import compute_matches

    views = datamanager.train_views()
    images = [b["image"].cpu().numpy() for _, b in views]
    cameras = [c.to("cpu") for c, _ in views]
    ids = [int(b["index"]) for _, b in views]
    cache_dir = user_cache_dir() / "matches" if matching.cache else None
    masks = [datamanager.alpha(i) for i in ids] if matching.alpha_mask else None
    known, origin = posing_matches(matching, datamanager, ids, cameras)
    if origin and known:  # what is reused, said before the phase that reuses it
        say(origin)
    pairs = prior_pairs(matching, cameras, ids)
    label = f"matching the training views for the prior ({matching.kind}{', sparse matches reused from the posing' if known else ''})"
    match_set = compute_matches(images, cameras, ids, matching, cache_dir, masks, known=known, label=label, pairs=pairs)
    if origin and not known:
        warnings.warn(origin)
    warn_empty(match_set, view_names(ids, cameras), posing_record(Path(datamanager.scene.root)))
    return match_set


def prior_pairs(matching: MatchConfig, cameras: list[Camera], ids: list[int]) -> list[tuple[int, int]] | None:
    """The pairs of training views the prior matches: each view's best partners
    (:func:`~.covisibility.partner_pairs`, as many as :func:`~.covisibility.partners_for` says),
    said in one line; None for every pair (then the cache key is that of every pair, as before)."""
    from .covisibility import partner_pairs, partners_for

    partners = partners_for(matching.partners, len(ids))
    if partners is None:
        return None
    pairs = partner_pairs(cameras, ids, partners)
    every = len(ids) * (len(ids) - 1) // 2
    if len(pairs) == every:
        return None
    say(f"matching: {len(pairs)} of the {every} pairs of training views, each view with its "
        f"{partners} best partners by frustum overlap (matching.partners)")
    return pairs


def posing_matches(matching: MatchConfig, datamanager, ids: list[int], cameras: list[Camera]):
    """The training pairs' sparse matches kept by the posing of the data manager's scene (photos posed
    by splat-process or ``--data PHOTOS``), for the learned matcher ``matching`` would run, with a
    line saying where they came from or why none were taken (:mod:`splat_framework.sfm.pose_matches`)."""
    from ..sfm.pose_matches import known_sparse_matches, reused_matcher

    learned = reused_matcher(matching)
    scene = datamanager.scene
    if learned is None or scene.undistort is not None:  # the file's pixels are those of pinhole photos
        return {}, ""
    paths = [Path(scene.image_paths[i]) for i in ids]
    return known_sparse_matches(Path(scene.root), paths, [(c.width, c.height) for c in cameras], ids, learned, matching)


def match_pairs(match_set: MatchSet, view_ids: list[int]) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """(i, j, uv_i [M, 2], uv_j [M, 2]) per pair, with i, j positions in ``view_ids``."""
    pos = {v: k for k, v in enumerate(view_ids)}
    for i, j in match_set.pairs():
        uv_i, uv_j = match_set.get(i, j)
        yield pos[i], pos[j], uv_i, uv_j


def triangulate(cam_a: Camera, cam_b: Camera, uv_a: Tensor, uv_b: Tensor) -> tuple[Tensor, Tensor]:
    """Midpoint triangulation of matched pixels [M, 2] with known poses.

    Returns:
        points [M, 3] and the worse-of-both reprojection error [M] in pixels
        (inf where a point lies behind either camera).
    """
    oa, da = cam_a.pixel_rays(uv_a.double())
    ob, db = cam_b.pixel_rays(uv_b.double())
    w0 = oa - ob
    a = (da * da).sum(-1)
    b = (da * db).sum(-1)
    c = (db * db).sum(-1)
    d = (da * w0).sum(-1)
    e = (db * w0).sum(-1)
    den = (a * c - b * b).clamp_min(1e-12)
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    pts = 0.5 * ((oa + s[:, None] * da) + (ob + t[:, None] * db))
    err = torch.zeros(pts.shape[0], dtype=pts.dtype)
    for cam, uv in ((cam_a, uv_a), (cam_b, uv_b)):
        p, z = cam.project(pts)
        e_ = (p - uv.double()).norm(dim=-1)
        err = torch.maximum(err, torch.where(z > 0, e_, torch.full_like(e_, float("inf"))))
    return pts.float(), err.float()


def triangulated_points(matching: MatchConfig, max_reprojection_px: float, datamanager) -> tuple[Tensor, Tensor, dict, str]:
    """The training views' matches triangulated with their poses: (points [N, 3], colours [N, 3] of
    the first view's pixel, on the images' device; ``{"matching_s": seconds}``; the matches'
    ``MatchSet.digest``). Points whose reprojection error exceeds ``max_reprojection_px`` in either
    view are dropped; N may be 0."""
    views = datamanager.train_views()
    cameras = [c.to("cpu") for c, _ in views]
    images = [b["image"] for _, b in views]
    ids = [int(b["index"]) for _, b in views]
    t0 = time.perf_counter()
    match_set = compute_match_set(matching, datamanager)
    timing = {"matching_s": time.perf_counter() - t0}
    pts, cols = [torch.zeros(0, 3)], [torch.zeros(0, 3)]
    for i, j, uv_i, uv_j in match_pairs(match_set, ids):
        uv_i = torch.as_tensor(uv_i, dtype=torch.float32)
        uv_j = torch.as_tensor(uv_j, dtype=torch.float32)
        if uv_i.shape[0] == 0:
            continue
        p, err = triangulate(cameras[i], cameras[j], uv_i, uv_j)
        ok = err <= max_reprojection_px
        img = images[i].cpu()
        x = uv_i[ok, 0].long().clamp(0, img.shape[1] - 1)
        y = uv_i[ok, 1].long().clamp(0, img.shape[0] - 1)
        pts.append(p[ok])
        cols.append(img[y, x])
    dev = images[0].device
    return torch.cat(pts).to(dev), torch.cat(cols).to(dev), timing, match_set.digest()


def triangulated_init(init, datamanager, generator: torch.Generator) -> StartPoints:
    """Init kind "triangulated" (``init``: a :class:`~splat_framework.config.init.TriangulatedInitConfig`):
    the training views' matches (``init.matching``) triangulated with their poses, points whose
    reprojection error exceeds ``init.max_reprojection_px`` dropped; with fewer than
    ``MIN_TRIANGULATED`` of them (texture-less views), the ``init.fallback`` start (one warning).
    Timing: ``matching_s``; stats: ``matches_digest``."""
    points, colors, timing, digest = triangulated_points(init.matching, init.max_reprojection_px, datamanager)
    if points.shape[0] < MIN_TRIANGULATED:
        warnings.warn("too few triangulated matches: falling back to random initialisation", stacklevel=3)
        fallback = initial_points(init.fallback, datamanager, generator)
        points, colors = fallback.points, fallback.colors
    return StartPoints(points, colors, timing, {"matches_digest": digest})


__all__ = ["MIN_TRIANGULATED", "compute_match_set", "match_pairs", "triangulate", "triangulated_init",
           "triangulated_points"]

"""The initial points of every method, one function per kind of ``model.init``
(:mod:`splat_framework.config.init`), called through :func:`initial_points`: here the kinds that
need nothing but the training views or a file (random, frustum, ply); the triangulated start is
:func:`splat_framework.matching.prior.triangulated_init`, the SfM start
:func:`splat_framework.sfm.points.sfm_points`, registered as a plugin's kinds are.

Each function takes ``(config, datamanager, generator)`` and returns a :class:`StartPoints`,
which :func:`initial_points` puts on the training images' device. The generator is the run's
(seeded), so a start is a pure function of the config, the data and the seed.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from ..cameras import Camera
from ..data.scene import SceneData
from ..errors import DataError
from ..export.ply import load_ply
from ..render import sh_to_rgb


@dataclass
class StartPoints:
    """Where a model starts: points [N, 3] and colours [N, 3] in [0, 1] (on the training images'
    device once :func:`initial_points` returns them), seconds per named set-up phase
    (metrics.json's timing, e.g. ``matching_s``) and what the start was built from (metrics.json's
    init_stats, e.g. ``matches_digest``: ``MatchSet.digest`` of the matches it triangulated)."""

    points: Tensor
    colors: Tensor
    timing: dict[str, float] = field(default_factory=dict)
    stats: dict[str, object] = field(default_factory=dict)


def initial_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """The start that ``init`` (an :class:`~splat_framework.config.init.InitConfig`) describes, built
    by the function its ``points_fn`` names, on the training images' device (``datamanager.device``:
    a plugin's function need not know it)."""
    module, _, name = init.points_fn.partition(":")
    start = getattr(importlib.import_module(module), name)(init, datamanager, generator)
    return replace(start, points=start.points.to(datamanager.device), colors=start.colors.to(datamanager.device))


def _train_views(datamanager) -> tuple[list[Camera], list[Tensor]]:
    views = datamanager.train_views()
    return [c for c, _ in views], [b["image"] for _, b in views]


# ------------------------------------------------------------------ random
def scene_box(datamanager) -> Tensor:
    """[2, 3] min and max corner (CPU) of where a scene's content is: the dataset's content box when it
    has one, else the box of the training frusta (:func:`frustum_box`)."""
    scene: SceneData = datamanager.scene
    if scene.content_box is not None:
        return torch.tensor(scene.content_box, dtype=torch.float32)
    return frustum_box(_train_views(datamanager)[0])


def box_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """Kind "random": ``init.num_points`` points uniform in :func:`scene_box`, grey."""
    device = _train_views(datamanager)[1][0].device
    points, colors = sample_box_points(scene_box(datamanager), init.num_points, generator)
    return StartPoints(points.to(device), colors.to(device))


def frustum_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """Kind "frustum": ``init.num_points`` points of :func:`sample_frustum_points`."""
    cameras, images = _train_views(datamanager)
    return StartPoints(*sample_frustum_points(cameras, images, init.num_points, generator))


def sample_frustum_points(
    cameras: list[Camera], images: list[Tensor], n: int, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Random points inside the training frusta, with the colour of the pixel they lie on.

    A camera is picked uniformly, then a pixel, then a depth uniform in inverse
    depth between the camera's near and far (so that near content is not starved).

    Returns:
        points [n, 3], colors [n, 3].
    """
    device = images[0].device
    cam_ids = torch.randint(len(cameras), (n,), generator=generator)
    pts, cols = [], []
    for ci, (cam, img) in enumerate(zip(cameras, images)):
        m = int((cam_ids == ci).sum())
        if m == 0:
            continue
        u = torch.rand(m, generator=generator) * cam.width
        v = torch.rand(m, generator=generator) * cam.height
        t = torch.rand(m, generator=generator)
        inv = 1.0 / cam.near + t * (1.0 / cam.far - 1.0 / cam.near)
        z = 1.0 / inv
        uv = torch.stack([u, v], -1).to(device)
        pts.append(cam.unproject_depth(uv, z.to(device)))
        cols.append(img[v.long().clamp_max(cam.height - 1), u.long().clamp_max(cam.width - 1)])
    return torch.cat(pts), torch.cat(cols)


def frustum_box(cameras: list[Camera]) -> Tensor:
    """[2, 3] min and max corner of the axis-aligned box around the cameras' frusta cut at near and far."""
    corners = []
    for cam in (c.to("cpu") for c in cameras):
        uv = torch.tensor([[0.0, 0.0], [cam.width, 0.0], [0.0, cam.height], [cam.width, cam.height]]).repeat(2, 1)
        z = torch.tensor([cam.near] * 4 + [cam.far] * 4)
        corners.append(cam.unproject_depth(uv, z))
    pts = torch.cat(corners)
    return torch.stack([pts.amin(0), pts.amax(0)])


def sample_box_points(box: Tensor, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """The 3DGS reference's random initialisation: points uniform in a box, grey colours.

    Args:
        box: [2, 3] min and max corner.

    Returns:
        points [n, 3], colors [n, 3] (0.5: the reference's SH values are U(0, 1) / 255, i.e. grey).
    """
    lo, hi = box[0].float().cpu(), box[1].float().cpu()
    points = lo + torch.rand(n, 3, generator=generator) * (hi - lo)
    return points, torch.full((n, 3), 0.5)


# ------------------------------------------------------------- from a file
def ply_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """Kind "ply": the means and degree-0 colours of the Gaussians of ``init.path`` (a 3DGS-layout
    PLY, :func:`splat_framework.export.ply.load_ply`); DataError for a file without a Gaussian or with
    a non-finite position."""
    _, images = _train_views(datamanager)
    gaussians = load_ply(init.path)
    points = gaussians["means"]
    if points.shape[0] == 0:
        raise DataError(f"{init.path}: the PLY holds no Gaussian to start from")
    if not bool(torch.isfinite(points).all()):
        raise DataError(f"{init.path}: the PLY holds non-finite positions")
    colors = sh_to_rgb(gaussians["sh0"][:, 0]).clamp(0.0, 1.0)
    return StartPoints(points.to(images[0].device), colors.to(images[0].device))

"""Ray-based Gaussians bound to matched rays, and the position warm-up.

Each match (pixel p_a in view a, p_b in view b) gives two ray-based Gaussians,
one on each view's ray: position = o + z * d with o the camera centre, d the
unit ray direction through the pixel and z (the distance along the ray) the
only learnable coordinate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from splat_framework.plugin import Camera


@dataclass
class RayBundle:
    """The ray-based Gaussians of a MatchSet (2 per match, match m -> rows 2m and 2m+1).

    Attributes:
        origins: [G, 3] camera centres.
        dirs: [G, 3] unit ray directions.
        z: [G] distance along the ray.
        view: [G] training-view position (index into the training cameras) of each Gaussian's own view.
        partner_view: [G] the other view of its match.
        uv: [G, 2] its pixel in its own view.
        partner_uv: [G, 2] the matched pixel in the partner view.
        near, far: [G] depth bounds of its own view (camera z).
    """

    origins: Tensor
    dirs: Tensor
    z: Tensor
    view: Tensor
    partner_view: Tensor
    uv: Tensor
    partner_uv: Tensor
    near: Tensor
    far: Tensor

    def __len__(self) -> int:
        return self.z.shape[0]

    def positions(self, z: Tensor | None = None) -> Tensor:
        z = self.z if z is None else z
        return self.origins + z[:, None] * self.dirs

    def select(self, keep: Tensor) -> "RayBundle":
        return RayBundle(**{k: getattr(self, k)[keep] for k in self.__dataclass_fields__})

    def to_dict(self) -> dict[str, Tensor]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def build_ray_bundle(match_pairs, cameras: list[Camera], generator: torch.Generator) -> RayBundle:
    """Two ray-based Gaussians per match, z drawn so that camera depth is uniform in [near, far].

    Args:
        match_pairs: iterable of (i, j, uv_i [M, 2], uv_j [M, 2]) with i, j positions in ``cameras``.
        cameras: the training cameras.
    """
    cols = {k: [] for k in RayBundle.__dataclass_fields__}
    for i, j, uv_i, uv_j in match_pairs:
        uv_i = torch.as_tensor(uv_i, dtype=torch.float32)
        uv_j = torch.as_tensor(uv_j, dtype=torch.float32)
        m = uv_i.shape[0]
        if m == 0:
            continue
        # interleave: row 2k is view i's Gaussian of match k, row 2k+1 view j's
        own = torch.stack([uv_i, uv_j], 1).reshape(-1, 2)
        other = torch.stack([uv_j, uv_i], 1).reshape(-1, 2)
        views = torch.tensor([i, j]).repeat(m)
        partners = torch.tensor([j, i]).repeat(m)
        o = torch.empty(2 * m, 3)
        d = torch.empty(2 * m, 3)
        near = torch.empty(2 * m)
        far = torch.empty(2 * m)
        for v in (i, j):
            sel = views == v
            cam = cameras[v].to("cpu")
            o[sel], d[sel] = cam.pixel_rays(own[sel])
            near[sel], far[sel] = cam.near, cam.far
        # camera-z uniform in [near, far]; convert to distance along the ray
        fwd = torch.stack([cameras[int(v)].to("cpu").world_to_cam[2, :3] for v in views]).float()
        cos = (d * fwd).sum(-1).clamp_min(1e-3)
        t = torch.rand(2 * m, generator=generator)
        z = (near + t * (far - near)) / cos
        for k, val in zip(
            ("origins", "dirs", "z", "view", "partner_view", "uv", "partner_uv", "near", "far"),
            (o, d, z, views, partners, own, other, near, far),
        ):
            cols[k].append(val)
    if not cols["z"]:
        empty = {k: torch.zeros(0, 3) for k in ("origins", "dirs")}
        return RayBundle(
            **empty, z=torch.zeros(0), view=torch.zeros(0, dtype=torch.long),
            partner_view=torch.zeros(0, dtype=torch.long), uv=torch.zeros(0, 2), partner_uv=torch.zeros(0, 2),
            near=torch.zeros(0), far=torch.zeros(0),
        )
    return RayBundle(**{k: torch.cat(v) for k, v in cols.items()})


def partner_projections(bundle: RayBundle, cameras: list[Camera]) -> tuple[Tensor, Tensor]:
    """Per Gaussian, its partner view's [3, 4] projection K [R | t] and (W, H).

    Returns:
        P [G, 3, 4] and size [G, 2], on the bundle's device.
    """
    dev = bundle.z.device
    Ps = torch.stack([(c.K.double() @ c.world_to_cam[:3].double()) for c in cameras]).float().to(dev)
    sizes = torch.tensor([[c.width, c.height] for c in cameras], dtype=torch.float32, device=dev)
    return Ps[bundle.partner_view], sizes[bundle.partner_view]


def _project_rows(positions: Tensor, P: Tensor) -> tuple[Tensor, Tensor]:
    """[G, 3] points through per-row [G, 3, 4] projections -> uv [G, 2], z [G]."""
    h = (P[:, :, :3] * positions[:, None, :]).sum(-1) + P[:, :, 3]
    return _dehomogenise(h)


def _dehomogenise(h: Tensor) -> tuple[Tensor, Tensor]:
    z = h[:, 2]
    zs = torch.where(z.abs() < 1e-9, torch.full_like(z, 1e-9), z)
    return h[:, :2] / zs[:, None], z


def position_errors(positions: Tensor, bundle: RayBundle, cameras: list[Camera], proj=None) -> Tensor:
    """[G] normalised L1 reprojection error of each Gaussian in its partner view (the L_gp terms).

    ``proj`` is :func:`partner_projections`' result, to reuse it across steps.
    A Gaussian behind the partner camera gets its (detached) error plus a push forward.
    """
    P, size = proj if proj is not None else partner_projections(bundle, cameras)
    uv, z = _project_rows(positions, P)
    return _normalised_error(uv, z, bundle, size)


def _normalised_error(uv: Tensor, z: Tensor, bundle: RayBundle, size: Tensor) -> Tensor:
    err = ((uv - bundle.partner_uv.to(uv)) / size).abs().sum(-1)
    behind = z <= 1e-6
    return torch.where(behind, err.detach() + 1.0 - z, err)


def gaussian_position_loss(positions: Tensor, bundle: RayBundle, cameras: list[Camera], proj=None) -> Tensor:
    """L_gp: mean over both directions of every match of the normalised reprojection error."""
    if positions.shape[0] == 0:
        return positions.sum() * 0.0
    return position_errors(positions, bundle, cameras, proj).mean()


def pixel_errors(positions: Tensor, bundle: RayBundle, cameras: list[Camera], proj=None) -> Tensor:
    """[M] worse-of-both-directions reprojection error in pixels for each match (rows 2m, 2m+1)."""
    P, _ = proj if proj is not None else partner_projections(bundle, cameras)
    uv, z = _project_rows(positions, P)
    return _match_pixel_errors((uv - bundle.partner_uv.to(uv)).T, z)


def _match_pixel_errors(d: Tensor, z: Tensor) -> Tensor:
    """[M] the worse of each match's two rows' distances d [2, G] (component-major) from their
    partner pixels, at camera depth z [G]; inf where a row is behind its partner camera."""
    e = torch.hypot(d[0], d[1])
    e = torch.where(z > 0, e, torch.full_like(e, float("inf")))
    return e.view(-1, 2).amax(dim=1)


class MatchCache:
    """Per match, the z pair with the lowest reprojection error seen so far (cache-and-filter)."""

    def __init__(self, bundle: RayBundle):
        m = len(bundle) // 2
        self.best_err = torch.full((m,), float("inf"))
        self.best_z = bundle.z.detach().clone()

    @torch.no_grad()
    def update(self, z: Tensor, bundle: RayBundle, cameras: list[Camera], proj=None) -> None:
        self.keep_best(pixel_errors(bundle.positions(z.detach()), bundle, cameras, proj), z)

    @torch.no_grad()
    def keep_best(self, err: Tensor, z: Tensor) -> None:
        """Keep z [G] for the matches whose pixel error err [M] is below their best so far."""
        err = err.cpu()
        better = err < self.best_err
        self.best_err = torch.where(better, err, self.best_err)
        rows = better.repeat_interleave(2)
        self.best_z = torch.where(rows, z.detach().cpu(), self.best_z)

    def keep_mask(self, eta_px: float) -> Tensor:
        """[G] rows whose match's best error is within ``eta_px``."""
        return (self.best_err <= eta_px).repeat_interleave(2)


def warmup_step_size(lr: float, unit: str, bundle: RayBundle) -> float:
    """The warm-up's Adam step size of z in scene units: ``lr`` itself (``unit`` "scene", the official
    code's), or ``lr`` times the median depth range (far - near) of the bundle's rays ("depth-range")."""
    if unit == "scene":
        return lr
    return lr * float((bundle.far - bundle.near).median()) if len(bundle) else lr


def warm_up(
    bundle: RayBundle,
    cameras: list[Camera],
    steps: int,
    lr: float,
    halve_every: int,
    cache: MatchCache | None,
    on_step: Callable[[], None] | None = None,
) -> Tensor:
    """Stage 1 of the public code: optimise only z with L_gp.

    The Adam step size is ``lr`` (scene units, see :func:`warmup_step_size`), halved every
    ``halve_every`` iterations. Returns the final z [G] (the cache, when given,
    holds the best z per match, seen after each iteration). ``on_step`` is called after each
    iteration (progress).

    Each L_gp term depends on its own row's z alone, and the projection is affine in z, so the
    gradient is taken in closed form (:func:`_position_error_grad`) from the same projection
    that gives the cache its pixel errors: one projection an iteration, no autograd graph.
    """
    z = torch.nn.Parameter(bundle.z.clone())
    if steps <= 0 or len(bundle) == 0:
        return z.detach()
    opt = torch.optim.Adam([z], lr=lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=max(halve_every, 1), gamma=0.5)
    P, size = partner_projections(bundle, cameras)
    # projection is affine in z: h = (P o + P_4) + z (P d), precomputed once; component-major
    # [3, G] (rows of length G vectorise; an inner dimension of 3 does not)
    h0 = ((P[:, :, :3] * bundle.origins[:, None, :]).sum(-1) + P[:, :, 3]).T.contiguous()
    h1 = (P[:, :, :3] * bundle.dirs[:, None, :]).sum(-1).T.contiguous()
    target = bundle.partner_uv.to(h0).T.contiguous()
    inv_size = size.reciprocal().T.contiguous()
    with torch.no_grad():
        for it in range(steps + 1):
            h = torch.addcmul(h0, z, h1)  # at z after `it` iterations
            uv = h[:2] / h[2].clamp(min=1e-9)
            d = uv - target
            if cache is not None and it > 0:
                cache.keep_best(_match_pixel_errors(d, h[2]), z)
            if it == steps:
                break
            z.grad = _position_error_grad(uv, d, h[2], h1, inv_size).div_(len(bundle))
            opt.step()
            sched.step()
            z.clamp_(min=1e-3)
            if on_step is not None:
                on_step()
    return z.detach()


def _position_error_grad(uv: Tensor, d: Tensor, zc: Tensor, h1: Tensor, inv_size: Tensor) -> Tensor:
    """[G] d/dz of each row's L_gp term (:func:`_normalised_error`), component-major: at uv [2, G]
    (camera depth zc [G]), d = uv - its partner pixel [2, G], with h1 [3, G] = d h / dz and
    1 / image size inv_size [2, G]: the sum over u, v of sign(d) / size * d uv / dz,
    where d uv / dz = (h1_uv - uv h1_z) / zc; -h1_z for a row behind its partner camera (the
    term 1 - zc)."""
    duv = (h1[:2] - uv * h1[2]) * (torch.sign(d) * inv_size)
    grad = duv.sum(0) / zc.clamp(min=1e-6)
    return torch.where(zc <= 1e-6, -h1[2], grad)

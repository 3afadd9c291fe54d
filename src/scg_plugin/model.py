"""SCGaussian model: hybrid ray-based + ordinary Gaussians with matching-prior losses.

Rows ``[0, G)`` of the parameter dict are the Gaussians of matches (two per
match, rows 2m and 2m+1). They are never pruned (:class:`RayGaussianStrategy`)
and densification appends children at the end, so these
rows keep their order for the whole run. While ``is_ray`` is set a row's
position is ``ray_o + z * ray_d`` and only ``z`` moves it; children of such
rows are ordinary Gaussians (the strategy's ``child_values``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from splat_framework.plugin import Camera, GaussianModel, log_lerp, ops, run_fraction, section

from .losses import rendering_geometry_loss
from .ray_gaussians import MatchCache, RayBundle, gaussian_position_loss, pixel_errors, warmup_step_size
from .startup import ordinary_points, ray_prior, thin_prior, warm_up_prior

RAY_KEYS = ("z", "ray_o", "ray_d", "is_ray", "is_match")


class SCGaussianModel(GaussianModel):
    """SCGaussian (NeurIPS 2024): structure-consistent Gaussians from a matching prior."""

    FIXED = ("ray_o", "ray_d", "is_ray", "is_match")

    def __init__(
        self, config, run, scene_scale, points, colors, bundle: RayBundle | None = None, cameras: list[Camera] = (),
        images: list[Tensor] = (), *, rows=None,
    ):
        """``bundle``: the rays of the matches; ``cameras``, ``images``: the training views (the
        position loss and the match cache use them; a model rebuilt from a checkpoint has none)."""
        self.bundle = bundle if bundle is not None and len(bundle) > 0 else None
        self.train_cameras = list(cameras)
        self.train_images = list(images)
        self.cache: MatchCache | None = None
        self._groups: tuple[RayBundle, dict] | None = None  # _match_groups' bundle and its groups
        self.thin_prior = False
        """Whether its init found the matching prior missing or sparse (``from_data``): the pipeline
        then trains it on the 3dgs baseline's schedule (:class:`~scg_plugin.pipeline.SCGaussianPipeline`)."""
        super().__init__(config, run, scene_scale, points, colors, rows=rows)
        if self.bundle is not None and config.schedule == "single-stage" and config.cache_filter and config.cache_until > 0:
            self.cache = MatchCache(self.bundle)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_data(cls, config, run, datamanager, generator):
        """The init steps of :mod:`scg_plugin.startup` (prior, warm-up, ordinary Gaussians; whether
        the prior is thin), then the model."""
        views = datamanager.train_views()
        cameras = [c for c, _ in views]
        images = [b["image"] for _, b in views]
        timing, stats = {}, {}
        bundle, n_matches = ray_prior(config, datamanager, generator, timing, stats)
        bundle = warm_up_prior(bundle, [c.to("cpu") for c in cameras], config, timing, stats)
        pts, cols = ordinary_points(config, datamanager, bundle, n_matches, generator)
        model = cls(config, run, datamanager.scene.scene_radius, pts, cols, bundle, cameras, images)
        model.thin_prior = thin_prior(config, bundle, n_matches)
        model.init_timing = timing
        model.init_stats = stats | {"num_matches": len(bundle) // 2 if bundle is not None else 0}
        return model

    def init_params(self, points: Tensor, colors: Tensor) -> dict[str, nn.Parameter]:
        dev = points.device
        b = self.bundle
        n_free = points.shape[0]
        if b is not None:
            b = self.bundle = RayBundle(**{k: v.to(dev) for k, v in b.to_dict().items()})
            ray_pos = b.positions()
            ray_cols = self._pixel_colours(b)
            all_pts = torch.cat([ray_pos, points.float()])
            all_cols = torch.cat([ray_cols, colors.float()])
        else:
            all_pts, all_cols = points.float(), colors.float()
        params = super().init_params(all_pts, all_cols)
        g = len(b) if b is not None else 0
        n = g + n_free
        flag = torch.zeros(n, device=dev)
        flag[:g] = 1.0
        z = torch.zeros(n, device=dev)
        o = torch.zeros(n, 3, device=dev)
        d = torch.zeros(n, 3, device=dev)
        if g:
            z[:g], o[:g], d[:g] = b.z, b.origins, b.dirs
        ray_bound = flag if self.config.ray_binding else torch.zeros_like(flag)
        params.update(
            z=nn.Parameter(z),
            ray_o=nn.Parameter(o, requires_grad=False),
            ray_d=nn.Parameter(d, requires_grad=False),
            is_ray=nn.Parameter(ray_bound, requires_grad=False),
            is_match=nn.Parameter(flag, requires_grad=False),
        )
        return params

    def _pixel_colours(self, b: RayBundle) -> Tensor:
        cols = torch.empty(len(b), 3, device=b.uv.device)
        for v in torch.unique(b.view).tolist():
            sel = b.view == v
            img = self.train_images[v]
            uv = b.uv[sel]
            x = uv[:, 0].long().clamp(0, img.shape[1] - 1)
            y = uv[:, 1].long().clamp(0, img.shape[0] - 1)
            cols[sel] = img[y, x].to(cols)
        return cols

    @property
    def num_match_gaussians(self) -> int:
        return 0 if self.bundle is None else len(self.bundle)

    # --------------------------------------------------------------- optimise
    def learning_rates(self, step: int) -> dict[str, float]:
        """3DGS's rates, and ``z``'s: while the single stage caches, the warm-up step size halving
        every ``warmup_lr_halve_every`` steps; else ``z_lr`` decaying to ``z_lr_final`` over the run
        as the position rate decays (without ``z_lr_final``, following the position rate's decay)."""
        lrs = super().learning_rates(step)
        cfg = self.config
        if self.bundle is None:
            lrs["z"] = cfg.z_lr * self.scene_scale
        elif cfg.schedule == "single-stage" and step < max(cfg.cache_until, 1):
            # the paper's single stage: z moves with the warm-up step size while caching
            lr = warmup_step_size(cfg.warmup_lr, cfg.warmup_lr_unit, self.bundle)
            lrs["z"] = lr * 0.5 ** (step // max(cfg.warmup_lr_halve_every, 1))
        elif cfg.z_lr_final is not None:
            lrs["z"] = log_lerp(cfg.z_lr, cfg.z_lr_final, run_fraction(step, self.run.total_steps)) * self.scene_scale
        else:
            ratio = lrs["means"] / max(self.run.optim.means_lr * self.scene_scale, 1e-30)
            lrs["z"] = cfg.z_lr * self.scene_scale * ratio
        return lrs

    def prepare_for_strategy(self) -> None:
        if self.bundle is not None:  # one select, not a masked write (a nonzero and a scatter a step)
            with torch.no_grad():
                self.params["means"].copy_(self.positions())

    def positions(self) -> Tensor:
        p = self.params
        if self.bundle is None:
            return p["means"]
        ray_pos = p["ray_o"] + p["z"][:, None] * p["ray_d"]
        return torch.where(p["is_ray"][:, None] > 0.5, ray_pos, p["means"])

    def get_loss_dict(self, outputs, batch, camera: Camera, step: int) -> dict[str, Tensor]:
        losses = super().get_loss_dict(outputs, batch, camera, step)
        if self.bundle is None:
            return losses
        cfg = self.config
        g = len(self.bundle)
        if cfg.lambda_gp > 0:
            pos = self.positions()[:g]
            with section("gaussian position"):
                losses["gp"] = cfg.lambda_gp * gaussian_position_loss(pos, self.bundle, self.train_cameras)
        if cfg.lambda_rg > 0 and step >= cfg.rg_start:
            with section("rendering geometry"):
                losses["rg"] = cfg.lambda_rg * self._rg_loss(outputs, camera, batch.get("train_position"))
        return losses

    def _rg_loss(self, outputs, camera: Camera, view: int | None) -> Tensor:
        """L_rg for the matches seen from the rendered training view, at ``view`` in the training
        split (the batch's ``train_position``; None: not a training view, no term). ``camera`` may
        be the view's camera resized (the trainer's coarse steps): the matched pixels, kept at the
        view's own size, are scaled to it."""
        b = self.bundle
        total, count = outputs.depth.sum() * 0.0, 0
        if view is None:
            return total
        depth = outputs.expected_depth
        own = self.train_cameras[view]
        to_render = b.uv.new_tensor([camera.width / own.width, camera.height / own.height])
        for partner, rows in self._match_groups().get(view, []):
            total = total + rendering_geometry_loss(
                depth, camera, b.uv[rows] * to_render, self.train_cameras[partner], b.partner_uv[rows]
            )
            count += 1
        return total / max(count, 1)

    def _match_groups(self) -> dict[int, list[tuple[int, Tensor]]]:
        """view -> [(partner view, [M] rows of the bundle whose match joins the two)], partners in
        increasing order: read from the device once per bundle (a step's L_rg then reads nothing)."""
        if self._groups is None or self._groups[0] is not self.bundle:
            b = self.bundle
            pairs = torch.stack([b.view, b.partner_view], 1).cpu()
            groups: dict[int, list[tuple[int, Tensor]]] = {}
            for view, partner in torch.unique(pairs, dim=0).tolist():
                rows = torch.nonzero((pairs[:, 0] == view) & (pairs[:, 1] == partner)).squeeze(1)
                groups.setdefault(view, []).append((partner, rows.to(b.view.device)))
            self._groups = (self.bundle, groups)
        return self._groups[1]

    def after_optimizer_step(self, step: int, losses, optimizers) -> ops.RowChange | None:
        """Cache-and-filter: each match's z and reprojection error recorded until ``cache_until``,
        then applied at its last step (:meth:`_apply_cache`; the rows it drops are the change)."""
        cfg = self.config
        if self.cache is None or self.bundle is None:
            return None
        g = len(self.bundle)
        z = self.params["z"][:g].detach().cpu()
        if step < cfg.cache_until:
            self.cache.update(z, RayBundle(**{k: v.cpu() for k, v in self.bundle.to_dict().items()}), [c.to("cpu") for c in self.train_cameras])
        if step == cfg.cache_until - 1:
            return self._apply_cache(optimizers)
        return None

    @torch.no_grad()
    def _apply_cache(self, optimizers) -> ops.RowChange | None:
        """Move every match to its best cached z and drop matches above eta (single-stage); the
        rows dropped, as a change (None when every match stays)."""
        cfg = self.config
        g = len(self.bundle)
        dev = self.params["z"].device
        self.params["z"].data[:g] = self.cache.best_z.to(dev)
        keep = self.cache.keep_mask(cfg.filter_eta_px).to(dev)
        drop = torch.zeros(self.num_gaussians, dtype=torch.bool, device=dev)
        drop[:g] = ~keep
        change = ops.remove(self.params, optimizers, {}, drop) if drop.any() else None
        self.bundle = self.bundle.select(keep)
        self.bundle.z = self.params["z"].data[: len(self.bundle)].clone()
        self.cache = None
        return change

    # ---------------------------------------------------------------- report
    def extra_state(self) -> dict:
        state = {"bundle": {k: v.cpu() for k, v in self.bundle.to_dict().items()} if self.bundle is not None else None}
        if self.cache is not None:
            state["cache"] = {"best_err": self.cache.best_err, "best_z": self.cache.best_z}
        return state

    def load_extra_state(self, state: dict) -> None:
        dev = self.params["means"].device
        b = state.get("bundle")
        self.bundle = RayBundle(**{k: v.to(dev) for k, v in b.items()}) if b is not None else None
        c = state.get("cache")
        if c is not None and self.bundle is not None:
            self.cache = MatchCache(self.bundle)
            self.cache.best_err, self.cache.best_z = c["best_err"], c["best_z"]
        else:
            self.cache = None

    @torch.no_grad()
    def report(self, datamanager) -> dict:
        """Structure statistics of the ray (match) Gaussians, rows ``[0, G)``.

        Always: their count and the median reprojection error of the matches.
        With GT depth for the training views (built-in synthetic scenes), the
        distance of each to the true surface along its own view, as a relative
        depth error |camera z - GT depth at its pixel| / GT depth (pixels with
        GT depth > 0 only): median, 90th percentile, fraction within 1% and 5%.
        """
        out = {"num_match_gaussians": self.num_match_gaussians}
        if self.bundle is None:
            return out
        b = self.bundle
        g = len(b)
        views = datamanager.train_views()
        cameras = [c for c, _ in views]
        pos = self.positions()[:g]
        err = pixel_errors(pos, b, cameras)
        out["match_reprojection_px_median"] = float(err.median()) if err.numel() else None
        if g == 0 or any("depth" not in batch for _, batch in views):
            return out
        rel_all = []
        for v, (cam, batch) in enumerate(views):
            sel = b.view == v
            if not bool(sel.any()):
                continue
            gt_map = batch["depth"][..., 0]
            h, w = gt_map.shape
            uv = b.uv[sel].to(gt_map.device)
            x = uv[:, 0].floor().long().clamp(0, w - 1)
            y = uv[:, 1].floor().long().clamp(0, h - 1)
            gt = gt_map[y, x].double()
            z = cam.world_to_camera_points(pos[sel].to(gt_map.device).double())[:, 2]
            ok = gt > 0
            rel_all.append(((z - gt).abs() / gt)[ok].cpu())
        rel = torch.cat(rel_all) if rel_all else torch.zeros(0, dtype=torch.float64)
        out["ray_depth_evaluated"] = int(rel.numel())
        if rel.numel():
            out["ray_depth_rel_err_median"] = float(rel.median())
            out["ray_depth_rel_err_p90"] = float(torch.quantile(rel, 0.9))
            out["ray_depth_within_1pct"] = float((rel < 0.01).double().mean())
            out["ray_depth_within_5pct"] = float((rel < 0.05).double().mean())
        return out

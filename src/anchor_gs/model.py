"""Scaffold-GS: anchors decoded per view into neural Gaussians.

Per-row parameters (one row per anchor, ``params``):

- ``anchors`` [A, 3] voxel centres (fixed: the public code's anchor learning rate is 0),
- ``offsets`` [A, k, 3] neural Gaussians' offsets in units of the anchor's first 3 scales,
- ``anchor_feat`` [A, F] features,
- ``scaling`` [A, 6] log-scales: 3 for the offsets, 3 for the neural Gaussians' scales.

Model-wide (``networks``): ``mlp_opacity`` (F + 3 -> F -> k, tanh), ``mlp_cov``
(F + 3 -> F -> 7k: scale factors and quaternion) and ``mlp_color`` (F + 3 -> F -> 3k,
sigmoid), fed the anchor feature and the unit view direction from the camera
centre. Per view, the anchors in front of the camera and near its image are decoded;
neural Gaussians whose opacity is <= 0 are dropped before rasterising. The
renderer's ``meta`` carries what :class:`anchor_gs.strategy.AnchorStrategy` needs:
``anchor_visible`` [A] bool, ``neural_opacity`` [A_vis, k] and ``neural_kept``
[A_vis * k] bool (rows of ``means2d``).

Not carried over from the public code: the per-view appearance embedding (each of
the few training views would get its own colour correction that test views cannot
use) and the feature bank.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from splat_framework.plugin import (
    Camera,
    GaussianModel,
    RenderOutput,
    adam,
    initial_points,
    knn_scale,
    log_lerp,
    photometric_loss,
    rasterize,
    rgb_to_sh,
    run_fraction,
)

VIEW_MARGIN = 0.5
"""Anchors are decoded when they project within the image widened by this fraction on every side."""


def voxelize(points: Tensor, voxel_size: float) -> Tensor:
    """[A, 3] centres of the occupied cells of a grid of ``voxel_size`` (unique, sorted)."""
    return torch.unique(torch.round(points / voxel_size), dim=0) * voxel_size


def _mlp(width: int, out: int, last: nn.Module | None) -> nn.Sequential:
    layers = [nn.Linear(width + 3, width), nn.ReLU(True), nn.Linear(width, out)]
    return nn.Sequential(*layers, *([last] if last is not None else []))


class ScaffoldModel(GaussianModel):
    """Scaffold-GS (see the module docstring)."""

    FIXED = ("anchors",)

    def __init__(self, config, run, scene_scale: float, points: Tensor | None, colors: Tensor | None,
                 camera_centers: Tensor | None = None, *, rows=None):
        cfg = config
        # a model rebuilt from ``rows`` gets its voxel size back with its extra state
        self.voxel_size = float(cfg.voxel_size) or (float(knn_scale(points).median()) if rows is None else 0.0)
        super().__init__(config, run, scene_scale, points, colors, rows=rows)

    @classmethod
    def from_data(cls, config, run, datamanager, generator):
        """Anchors voxelised from the init ``config.init`` describes (as every method's)."""
        start = initial_points(config.init, datamanager, generator)
        points, colors = start.points, start.colors
        centers = torch.stack([c.center.detach().float() for c in datamanager.train_cameras]).to(points.device)
        model = cls(config, run, datamanager.scene.scene_radius, points, colors, centers)
        model.reference_center = centers[0].cpu()
        model.keep_training_views(datamanager)
        model.init_timing = start.timing
        model.init_stats = {"num_points": int(points.shape[0]), "num_anchors": model.num_anchors,
                            "voxel_size": model.voxel_size} | start.stats
        return model

    def init_params(self, points: Tensor, colors: Tensor) -> dict[str, nn.Parameter]:
        return self.anchor_params(voxelize(points.float(), self.voxel_size))

    def anchor_params(self, anchors: Tensor) -> dict[str, nn.Parameter]:
        """Fresh per-row parameters of anchors at ``anchors`` [A, 3]: zero offsets and features, scaling
        the mean distance to the 3 nearest anchors."""
        cfg = self.config
        a, dev = anchors.shape[0], anchors.device
        scaling = torch.log(knn_scale(anchors))[:, None].repeat(1, 6)
        return {
            "anchors": nn.Parameter(anchors.contiguous(), requires_grad=False),
            "offsets": nn.Parameter(torch.zeros(a, cfg.n_offsets, 3, device=dev)),
            "anchor_feat": nn.Parameter(torch.zeros(a, cfg.feat_dim, device=dev)),
            "scaling": nn.Parameter(scaling.float()),
        }

    def build_networks(self) -> nn.ModuleDict:
        cfg = self.config
        k, f = cfg.n_offsets, cfg.feat_dim
        nets = nn.ModuleDict({
            "mlp_opacity": _mlp(f, k, nn.Tanh()),
            "mlp_cov": _mlp(f, 7 * k, None),
            "mlp_color": _mlp(f, 3 * k, nn.Sigmoid()),
        })
        return nets.to(self.params["anchors"].device)

    # ---------------------------------------------------------------- sizes
    @property
    def num_anchors(self) -> int:
        return self.params["anchors"].shape[0]

    @property
    def num_gaussians(self) -> int:
        """Neural Gaussians the anchors can decode into (A x k; those with opacity <= 0 are not drawn)."""
        return self.num_anchors * self.config.n_offsets

    # ------------------------------------------------------------- optimise
    def learning_rates(self, step: int) -> dict[str, float]:
        """The public code's rates at ``step``; offsets and the opacity and colour MLPs decay
        exponentially over the run (its ``get_expon_lr_func``)."""
        cfg = self.run.optim
        start = {"offsets": cfg.offset_lr * self.scene_scale, "anchor_feat": cfg.feature_lr, "scaling": cfg.scaling_lr,
                 "mlp_opacity": cfg.mlp_opacity_lr, "mlp_cov": cfg.mlp_cov_lr, "mlp_color": cfg.mlp_color_lr}
        finals = {"offsets": cfg.offset_lr_final * self.scene_scale, "mlp_opacity": cfg.mlp_opacity_lr * 0.01,
                  "mlp_color": cfg.mlp_color_lr * 0.00625}
        t = run_fraction(step, self.run.total_steps)
        return start | {k: log_lerp(start[k], final, t) for k, final in finals.items()}

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """One Adam per per-row parameter and one per MLP (as the public code's param groups)."""
        lrs = self.learning_rates(0)
        tensors = {k: [p] for k, p in self.params.items() if p.requires_grad}
        tensors |= {k: list(m.parameters()) for k, m in self.networks.items()}
        return {k: adam([{"params": ps, "lr": lrs[k], "name": k}], lr=lrs[k])
                for k, ps in tensors.items()}

    def positions(self) -> Tensor:
        """[A, 3] anchor positions."""
        return self.params["anchors"]

    # --------------------------------------------------------------- decode
    def visible_anchors(self, camera: Camera) -> Tensor:
        """[A] bool: anchors in front of ``camera`` projecting within its image widened by ``VIEW_MARGIN``."""
        uv, z = camera.project(self.params["anchors"].detach())
        w, h = camera.width, camera.height
        mx, my = VIEW_MARGIN * w, VIEW_MARGIN * h
        return (z > 0.01) & (uv[:, 0] > -mx) & (uv[:, 0] < w + mx) & (uv[:, 1] > -my) & (uv[:, 1] < h + my)

    def decode(self, center: Tensor, visible: Tensor) -> dict[str, Tensor]:
        """The neural Gaussians of the ``visible`` anchors seen from the camera centre ``center`` [3]: ``means`` [M, 3],
        ``quats`` [M, 4], ``scales`` [M, 3], ``opacities`` [M], ``colors`` [M, 3] (M: those with opacity
        > 0), ``neural_opacity`` [A_vis, k] and ``kept`` [A_vis * k] bool."""
        p, k = self.params, self.config.n_offsets
        anchors, feat = p["anchors"][visible], p["anchor_feat"][visible]
        offsets, scaling = p["offsets"][visible], torch.exp(p["scaling"][visible])
        view = anchors - center.to(anchors)
        view = view / view.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        x = torch.cat([feat, view], dim=-1)  # [A_vis, F + 3]
        opacity = self.networks["mlp_opacity"](x)  # [A_vis, k]
        kept = (opacity > 0).reshape(-1)
        colors = self.networks["mlp_color"](x).reshape(-1, 3)[kept]
        scale_rot = self.networks["mlp_cov"](x).reshape(-1, 7)[kept]
        scale_rep = scaling.repeat_interleave(k, dim=0)[kept]  # [M, 6]
        means = anchors.repeat_interleave(k, dim=0)[kept] + offsets.reshape(-1, 3)[kept] * scale_rep[:, :3]
        return {
            "means": means,
            "quats": F.normalize(scale_rot[:, 3:7], dim=-1),
            "scales": scale_rep[:, 3:] * torch.sigmoid(scale_rot[:, :3]),
            "opacities": opacity.reshape(-1)[kept],
            "colors": colors,
            "neural_opacity": opacity,
            "kept": kept,
        }

    def lod_mask(self, center: Tensor) -> Tensor:
        """[A] bool: the anchors whose level of detail is drawn from ``center`` [3] (Scaffold-GS: all)."""
        return torch.ones(self.num_anchors, dtype=torch.bool, device=self.params["anchors"].device)

    def render_meta(self) -> dict:
        """What the anchor strategy needs from the model beside the decoded Gaussians (``meta``)."""
        return {"voxel_size": self.voxel_size}

    def get_outputs(self, camera: Camera, background: Tensor | None = None, step: int | None = None) -> RenderOutput:
        visible = self.visible_anchors(camera) & self.lod_mask(camera.center)
        g = self.decode(camera.center, visible)
        out = rasterize(g["means"], g["quats"], g["scales"], self.drop_opacities(g["opacities"], step), g["colors"],
                        camera.world_to_cam.float(), camera.K.float(), camera.width, camera.height,
                        background=background, near_plane=0.01, depth_mode=self.config.depth_mode,
                        settings=self.render_settings, absgrad=self.absgrad and step is not None)
        out.meta.update(anchor_visible=visible, neural_opacity=g["neural_opacity"].detach(), neural_kept=g["kept"],
                        neural_scales=g["scales"], **self.render_meta())
        return out

    def get_loss_dict(self, outputs: RenderOutput, batch: dict, camera: Camera, step: int) -> dict[str, Tensor]:
        """L1 + D-SSIM, the opt-in regularisers' terms (``model.reg``), and the volume regulariser on
        the rendered neural Gaussians' scales."""
        cfg = self.config
        target, terms = self.regulariser_terms(outputs, batch, camera, step)
        losses = {"photometric": photometric_loss(outputs.rgb, target, lambda_dssim=cfg.lambda_dssim,
                                                   settings=self.render_settings)} | terms
        scales = outputs.meta["neural_scales"]
        if cfg.lambda_scaling > 0 and scales.shape[0] > 0:
            losses["scaling"] = cfg.lambda_scaling * scales.prod(dim=-1).mean()
        return losses

    def gaussian_log_scales(self, outputs: RenderOutput) -> Tensor:
        """[M, 3] log-scales of the neural Gaussians drawn in ``outputs``."""
        return torch.log(outputs.meta["neural_scales"])

    def on_step_start(self, step: int) -> None:
        """No spherical harmonics: colours come from the colour MLP."""

    def on_loaded(self) -> None:
        """No spherical harmonics to raise."""

    @torch.no_grad()
    def export_gaussians(self, camera: Camera | None = None) -> dict[str, Tensor]:
        """The neural Gaussians drawn for ``camera`` (its visible anchors and level of detail); without
        one, those of every anchor drawn from the first training camera's centre (the reference view:
        all levels of detail it selects). Colours as SH degree 0."""
        if camera is None:
            center = self.reference_center.to(self.params["anchors"].device)
            g = self.decode(center, self.lod_mask(center))
        else:
            g = self.decode(camera.center, self.visible_anchors(camera) & self.lod_mask(camera.center))
        m = g["means"].shape[0]
        return {"means": g["means"], "quats": g["quats"], "scales": torch.log(g["scales"]),
                "opacities": torch.logit(g["opacities"].clamp(1e-6, 1 - 1e-6)),
                "sh0": rgb_to_sh(g["colors"])[:, None], "shN": g["colors"].new_zeros(m, 0, 3)}

    def extra_state(self) -> dict:
        return {"voxel_size": self.voxel_size, "reference_center": self.reference_center.detach().cpu()}

    def load_extra_state(self, state: dict) -> None:
        self.voxel_size = float(state["voxel_size"])
        self.reference_center = torch.as_tensor(state["reference_center"]).float()

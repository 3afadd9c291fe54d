"""The 3DGS Gaussian model: parameters, activations, optimizers, outputs, loss.

Parameters live in one ``nn.ParameterDict`` with N rows each:

- ``means`` [N, 3] world positions,
- ``quats`` [N, 4] rotations (wxyz, unnormalised),
- ``scales`` [N, 3] log-scales,
- ``opacities`` [N] opacity logits,
- ``sh0`` [N, 1, 3] and ``shN`` [N, K-1, 3] spherical-harmonics coefficients.

Subclasses may add keys (one leading dimension N); the densification strategy
handles them generically. Parameters that are not per row (the MLPs of an
anchor-based method, an appearance embedding) live in ``networks`` (an
``nn.ModuleDict`` built by :meth:`GaussianModel.build_networks`), may have their own
optimizers under their own names in :meth:`make_optimizers`, and are checkpointed
with the rows. Methods customise training through the hooks of
:class:`GaussianModel` (its docstring lists them in the order the trainer calls
them) instead of forking the trainer.
"""

from __future__ import annotations

import inspect
import math
from contextlib import nullcontext
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import torch
from torch import Tensor, nn

from ..cameras import Camera, view_angle
from ..config import GaussianModelConfig, RunFacts
from ..console import phase
from ..losses import photometric_loss
from ..render import RenderOutput, RenderSettings, rasterize, rgb_to_sh
from ..runtime.profiling import section
from ..runtime.rng import keyed_generator
from .init import initial_points
from .ops import RowChange
from .optim import adam
from .regularisers import regulariser_terms


def knn_scale(points: Tensor, k: int = 3) -> Tensor:
    """[N] root-mean-square distance of each point to its ``k`` nearest neighbours (3DGS init scale).

    An exact k-d tree search (OpenCV's FLANN, single tree, unlimited checks): O(N log N),
    where all pairwise distances would be O(N^2) (about 10 s at 50k points on 2 cores)."""
    import cv2
    import numpy as np

    n = points.shape[0]
    if n <= 1:
        return torch.full((n,), 0.01, device=points.device, dtype=points.dtype)
    k = min(k, n - 1)
    data = np.ascontiguousarray(points.detach().cpu().numpy(), dtype=np.float32)
    index = cv2.flann_Index(data, {"algorithm": 4})  # FLANN_INDEX_KDTREE_SINGLE
    _, d2 = index.knnSearch(data, k + 1, params={"checks": -1})  # squared distances, self first
    rms = np.sqrt(np.sort(d2, axis=1)[:, 1:].mean(axis=1, dtype=np.float64))
    return torch.from_numpy(rms).to(device=points.device, dtype=points.dtype).clamp_min(1e-7)


def run_fraction(step: int, total_steps: int) -> float:
    """``step / total_steps`` clamped to [0, 1]: how far a schedule over the run has gone."""
    return min(max(step / max(total_steps, 1), 0.0), 1.0)


def log_lerp(start: float, final: float, t: float) -> float:
    """The exponential decay of a learning rate from ``start`` (t = 0) to ``final`` (t = 1)."""
    return math.exp(math.log(start) * (1 - t) + math.log(final) * t)


class GaussianModel(nn.Module):
    """Vanilla 3D Gaussian Splatting, and the lifecycle every method's model follows.

    Every hook the framework calls, in the order it calls them (the pipeline,
    :class:`splat_framework.pipeline.Pipeline`, builds the model and asks for each step's render and
    loss; the trainer, :class:`splat_framework.engine.trainer.Trainer`, runs the rest):

    ==========================================================  =====================================
    hook (receives)                                             returns / does
    ==========================================================  =====================================
    **set-up** (the pipeline)
    ``batch_fields(config)`` (classmethod, before the data)     the optional batch fields its loss
                                                                reads (``backdrop``), so the data
                                                                manager makes them
    ``from_data(config, run, datamanager, generator)``          the model; builds it with ``__init__``,
    (classmethod)                                               which calls ``init_params(points,
                                                                colors)`` (Gaussians) and
                                                                ``build_networks()``; then
                                                                ``keep_training_views(datamanager)``
                                                                (the multi-view regulariser's partners)
    ``init_timing``, ``init_stats`` (attributes)                seconds and numbers for metrics.json
    **set-up** (the trainer)
    ``make_optimizers()``                                       {name: Optimizer}
    ``restore(checkpoint, device)`` (``--resume``, a restore    loads Gaussians, ``networks``, then
    after faults)                                               ``load_extra_state(state)``; the
                                                                trainer then calls ``make_optimizers()``
    **each step**
    ``on_step_start(step)``                                     None (SH degree, levels open, ...)
    ``learning_rates(step)``                                    {optimizer name: rate}, pure in step
    ``get_outputs(camera, background, step=step)``              RenderOutput (rgb, depth, alpha, meta;
    (a training render: DropGaussian applies)                   ``expected_depth`` on demand)
    ``get_loss_dict(outputs, batch, camera, step)``             {term: scalar Tensor}, summed; ``batch``
                                                                carries ``image``, ``index``,
                                                                ``train_position`` and the masks
    ``trainable_keys(step)``                                    optimizer names to step (None: all)
    ``after_optimizer_step(step, losses, optimizers)``          a ``ops.RowChange`` when it resized
                                                                the Gaussians (``ops.remove``,
                                                                ``append`` with an empty state), else None
    ``prepare_for_strategy()`` (when the strategy runs)         None (``params["means"]`` true)
    **checkpoint**
    ``extra_state()``                                           dict of state beyond Gaussians and networks
    **end of training**
    ``get_outputs(camera, background)`` (evaluation)            RenderOutput of a test view
    ``report(datamanager)``                                     dict for metrics.json, or None
    **loading a run** (splat-eval, -render, -export, -view)
    ``from_checkpoint(config, run, scene_scale, checkpoint)``   the model: ``__init__`` with ``rows``,
    (classmethod)                                               then ``restore(checkpoint)``, then
                                                                ``on_loaded()`` (every SH degree)
    ``export_gaussians()`` (PLY export, viewer)                 standard 3DGS Gaussians
    ==========================================================  =====================================

    The model receives its own config and the run's facts, never the run config: which strategy
    densifies it is the pipeline's choice (:meth:`Pipeline.strategy_config`).

    Args:
        config: the model's config (the run's ``config.model``, a GaussianModelConfig).
        run: what it reads of the run besides (:class:`~splat_framework.config.RunFacts`: total
            steps, seed, coarse steps, learning rates).
        scene_scale: spatial scale of the scene (position lr and size thresholds).
        points: [M, 3] initial positions (None with ``rows``).
        colors: [M, 3] initial colours in [0, 1] (None with ``rows``).
        rows: the per-Gaussian tensors of a trained model (a checkpoint's ``params``), taken as they
            are instead of initialising from ``points``; :meth:`restore` then loads the rest.
    """

    init_timing: Mapping[str, float] = MappingProxyType({})
    """Seconds per named set-up phase done in ``from_data`` (e.g. matching, warm-up), added to
    metrics.json's timing; a subclass sets its own dict on the instance."""
    init_stats: Mapping[str, Any] = MappingProxyType({})
    """Numbers about the initialisation (e.g. match counts), written to metrics.json."""

    train_cameras: Sequence[Camera] = ()
    """The training views' cameras, and below their photos [H, W, 3], in split order (``from_data``
    sets them; a model rebuilt from a checkpoint has none): the multi-view regulariser's partners."""
    train_images: Sequence[Tensor] = ()

    render_settings: RenderSettings = RenderSettings()
    """How its renders run (``rasterize(settings=)``), set by whoever builds the model (the trainer,
    the commands that load a run) from the config and the environment; default: the eager torch kernels."""
    absgrad: bool = False
    """Training renders leave ``means2d.absgrad`` (``rasterize(absgrad=)``): set by the trainer when
    the run's strategy densifies on it (``Strategy.absgrad``)."""

    FIXED: tuple[str, ...] = ()
    """Per-row tensors that are not optimised (a model rebuilt from a checkpoint keeps them so)."""

    def __init__(
        self, config: GaussianModelConfig, run: RunFacts, scene_scale: float, points: Tensor | None,
        colors: Tensor | None, *, rows: Mapping[str, Tensor] | None = None,
    ):
        super().__init__()
        self.config = config
        self.run = run
        self._partner_orders: dict[tuple[int, int, float], list[int]] = {}
        """training_partners' choices, (view, k, max_angle) -> indices into train_cameras."""
        self.scene_scale = float(scene_scale)
        self.active_sh_degree = 0
        try:
            # a phase of its own: hundreds of thousands of start points take seconds (nearest neighbours)
            with phase("building the model") if rows is None else nullcontext():
                self.params = nn.ParameterDict(self.init_params(points, colors) if rows is None else self.as_params(rows))
                self.networks = self.build_networks()
        except AttributeError as e:  # the usual cause: a subclass sets what they read after super().__init__()
            raise AttributeError(f"{e} (building {type(self).__name__}: set every attribute init_params and "
                                 "build_networks read before calling super().__init__())") from e

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A subclass's own ``__init__`` must take ``rows=`` (keyword) and hand it on: ``from_checkpoint``
        builds every model with a checkpoint's rows instead of points (TypeError naming the class)."""
        super().__init_subclass__(**kwargs)
        if "__init__" in vars(cls):
            params = inspect.signature(cls.__init__).parameters
            if "rows" not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
                raise TypeError(f"{cls.__module__}.{cls.__qualname__}.__init__ takes no rows=: from_checkpoint builds "
                                "the model with a checkpoint's rows (pass rows=rows on to super().__init__)")

    # ------------------------------------------------------------------ build
    @classmethod
    def batch_fields(cls, config: GaussianModelConfig) -> frozenset[str]:
        """The optional fields this model's training batches must carry, so the data manager makes
        them (``image``, ``index``, ``train_position`` and a scene's masks and depths are always
        there): ``backdrop`` when ``reg.backdrop_weight`` > 0. Called before the data is loaded."""
        return frozenset({"backdrop"} if config.reg.backdrop_weight > 0 else ())

    @classmethod
    def from_data(cls, config: GaussianModelConfig, run: RunFacts, datamanager,
                  generator: torch.Generator) -> "GaussianModel":
        """Build the model for a dataset, from the init ``config.init`` describes
        (:func:`~splat_framework.model.init.initial_points`)."""
        start = initial_points(config.init, datamanager, generator)
        model = cls(config, run, datamanager.scene.scene_radius, start.points, start.colors)
        model.keep_training_views(datamanager)
        model.init_timing = start.timing
        model.init_stats = {"num_points": int(start.points.shape[0])} | start.stats
        return model

    def keep_training_views(self, datamanager) -> None:
        """Keep the training views' cameras and photos (``train_cameras``, ``train_images``), which
        the multi-view regulariser compares each render with; ``from_data`` calls it."""
        views = datamanager.train_views()
        self.train_cameras, self.train_images = [c for c, _ in views], [b["image"] for _, b in views]
        self._partner_orders = {}

    def build_networks(self) -> nn.ModuleDict:
        """The model-wide (not per-row) modules, freshly initialised (3DGS: none). Called when the
        model is built and when it is rebuilt from a checkpoint (whose weights are then loaded)."""
        return nn.ModuleDict()

    def init_params(self, points: Tensor, colors: Tensor) -> dict[str, nn.Parameter]:
        cfg = self.config
        n = points.shape[0]
        dev = points.device
        scales = torch.log(knn_scale(points) * cfg.init_scale)[:, None].repeat(1, 3)
        quats = torch.zeros(n, 4, device=dev)
        quats[:, 0] = 1.0
        k = (cfg.sh_degree + 1) ** 2
        sh0 = rgb_to_sh(colors.clamp(0, 1))[:, None, :]
        shN = torch.zeros(n, k - 1, 3, device=dev)
        opac = torch.logit(torch.full((n,), cfg.init_opacity, device=dev))
        return {
            "means": nn.Parameter(points.float().contiguous()),
            "quats": nn.Parameter(quats),
            "scales": nn.Parameter(scales.float()),
            "opacities": nn.Parameter(opac),
            "sh0": nn.Parameter(sh0.float()),
            "shN": nn.Parameter(shN),
        }

    @property
    def num_gaussians(self) -> int:
        return self.params["means"].shape[0]

    # --------------------------------------------------------------- optimise
    def learning_rates(self, step: int) -> dict[str, float]:
        """The learning rate of every optimizer at ``step``, a pure function of the step (a resumed
        run gets the same rates): 3DGS's base rates, the position rate decaying exponentially
        from ``means_lr`` to ``means_lr_final`` over the run. A subclass adds its own keys."""
        o = self.run.optim
        t = run_fraction(step, self.run.total_steps)
        return {
            "means": log_lerp(o.means_lr, o.means_lr_final, t) * self.scene_scale,
            "quats": o.quats_lr,
            "scales": o.scales_lr,
            "opacities": o.opacities_lr,
            "sh0": o.sh0_lr,
            "shN": o.shN_lr,
        }

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """One Adam per trainable parameter key."""
        lrs = self.learning_rates(0)
        return {
            k: adam([{"params": [p], "lr": lrs[k], "name": k}], lr=lrs[k])
            for k, p in self.params.items()
            if p.requires_grad and k in lrs
        }

    def trainable_keys(self, step: int) -> set[str] | None:
        """Parameter keys to update at ``step`` (None = all)."""
        return None

    def on_step_start(self, step: int) -> None:
        self.active_sh_degree = min(step // max(self.config.sh_degree_interval, 1), self.config.sh_degree)

    def drop_opacities(self, opacities: Tensor, step: int | None) -> Tensor:
        """[N] activated opacities as step ``step``'s training render draws them: DropGaussian
        (``model.reg.drop_rate``): each row zeroed with probability p = drop_rate * (fraction of the
        run done), the others divided by (1 - p); then opacity noise (``model.reg.opacity_noise``):
        each row multiplied by (1 + opacity_noise * a standard normal draw), floored at 0. The draws
        are a pure function of (seed, step), so a resumed run repeats them. With ``step`` None (not
        a training render) or both off, ``opacities`` unchanged."""
        reg = self.config.reg
        if step is None:
            return opacities
        rate = reg.drop_rate * min(step / max(self.run.total_steps, 1), 1.0)
        if rate <= 0 and reg.opacity_noise <= 0:
            return opacities
        draws = keyed_generator(self.run.seed, step)
        if rate > 0:
            keep = torch.rand(opacities.shape[0], generator=draws) >= rate
            opacities = opacities * (keep.to(opacities) / (1.0 - rate))
        if reg.opacity_noise > 0:
            noise = torch.randn(opacities.shape[0], generator=draws).to(opacities)
            opacities = (opacities * (1.0 + reg.opacity_noise * noise)).clamp(min=0.0)
        return opacities

    def prepare_for_strategy(self) -> None:
        """Make ``params['means']`` hold every row's true position (subclasses with
        other parameterisations override this)."""

    def after_optimizer_step(self, step: int, losses: dict[str, Tensor], optimizers: dict) -> RowChange | None:
        """Hook after the optimizers stepped (caching, filtering); None, or the :class:`~.ops.RowChange`
        of a hook that added or removed rows (with ``ops.remove`` / ``ops.append`` on ``self.params``,
        ``optimizers`` and an empty state, ``{}``): the trainer hands it to the strategy, which
        resizes its own state (``Strategy.rows_changed``)."""

    # ------------------------------------------------------- state, report
    def extra_state(self) -> dict:
        """Model state beyond ``params`` to checkpoint (tensors on CPU); see :meth:`load_extra_state`."""
        return {}

    def load_extra_state(self, state: dict) -> None:
        """Restore what :meth:`extra_state` returned (called after ``params`` were loaded)."""

    def report(self, datamanager) -> dict | None:
        """Method-specific numbers for metrics.json's ``model_report`` at the end of training (None: none)."""
        return None

    # ---------------------------------------------------------------- render
    def export_gaussians(self) -> dict[str, Tensor]:
        """The model as standard 3DGS Gaussians (PLY export): means [N, 3] (:meth:`positions`,
        e.g. the true positions of ray-based Gaussians), quats [N, 4] wxyz, scales [N, 3] log,
        opacities [N] logit, sh0 [N, 1, 3], shN [N, K-1, 3]. A model whose Gaussians are
        decoded per view (anchor-based methods) returns those of a reference view."""
        p = self.params
        return {"means": self.positions(), **{k: p[k] for k in ("quats", "scales", "opacities", "sh0", "shN")}}

    def positions(self) -> Tensor:
        """[N, 3] world positions of all Gaussians."""
        return self.params["means"]

    def get_outputs(self, camera: Camera, background: Tensor | None = None, step: int | None = None) -> RenderOutput:
        """Render ``camera``'s view; ``step`` is the training step when this is a training render
        (DropGaussian draws from it), None for evaluation, the viewer and exports."""
        p = self.params
        d = self.active_sh_degree
        # only the active bands are copied; shN stays in the graph (its gradient is zero beyond them)
        coeffs = torch.cat([p["sh0"], p["shN"][:, : (d + 1) ** 2 - 1]], dim=1)
        return rasterize(
            self.positions(),
            p["quats"],
            torch.exp(p["scales"]),
            self.drop_opacities(torch.sigmoid(p["opacities"]), step),
            coeffs,
            camera.world_to_cam.float(),
            camera.K.float(),
            camera.width,
            camera.height,
            sh_degree=d,
            background=background,
            near_plane=0.01,
            depth_mode=self.config.depth_mode,
            settings=self.render_settings,
            absgrad=self.absgrad and step is not None,
        )

    def get_loss_dict(
        self, outputs: RenderOutput, batch: dict, camera: Camera, step: int
    ) -> dict[str, Tensor]:
        """Loss terms; the trainer minimises their sum: ``photometric`` (against the image, its
        backdrop blacked out when that regulariser is on), then the terms of the opt-in regularisers
        ``model.reg`` switches on (:func:`~splat_framework.model.regularisers.regulariser_terms`)."""
        target, terms = self.regulariser_terms(outputs, batch, camera, step)
        with section("photometric"):
            return {"photometric": photometric_loss(outputs.rgb, target, lambda_dssim=self.config.lambda_dssim,
                                                    settings=self.render_settings)} | terms

    def regulariser_terms(self, outputs: RenderOutput, batch: dict, camera: Camera, step: int) -> tuple[Tensor, dict[str, Tensor]]:
        """(photometric target, {term: scalar}) of the opt-in regularisers ``model.reg`` switches on
        (:func:`~splat_framework.model.regularisers.regulariser_terms`), given what they need from
        this model: the run's seed and length, :meth:`gaussian_log_scales`, a training re-render
        of another camera (the stereo term's partner view), :meth:`training_partners` and :meth:`training_view`."""
        return regulariser_terms(
            self.config.reg, outputs, batch, camera, step, seed=self.run.seed,
            total_steps=self.run.total_steps, log_scales=lambda: self.gaussian_log_scales(outputs),
            render=lambda view: self.get_outputs(view, outputs.meta.get("background"), step=step),
            partners=lambda k, angle: self.training_partners(batch.get("train_position"), k, angle),
            own=lambda: self.training_view(batch.get("train_position")),
        )

    def training_view(self, view: int | None) -> tuple[Camera, Tensor] | None:
        """(camera, photo [H, W, 3]) of training view ``view`` (its position in the split) at the
        photos' size; None for None or a model without its training views."""
        if view is None or view >= len(self.train_cameras):
            return None
        return self.train_cameras[view], self.train_images[view]

    def training_partners(self, view: int | None, k: int, max_angle: float = 180.0) -> list[tuple[Camera, Tensor]]:
        """(camera, photo [H, W, 3]) of the ``k`` training views whose centres lie nearest training
        view ``view``'s (its position in the split), nearest first, among those whose optical axis
        is within ``max_angle`` degrees of ``view``'s; [] for None, without views or with none so near.
        Chosen once per (view, k, max_angle) and kept until keep_training_views: no host sync a step on CUDA."""
        if view is None or len(self.train_cameras) < 2:
            return []
        key = (view, k, max_angle)
        if key not in self._partner_orders:
            self._partner_orders[key] = _nearest_within(self.train_cameras, view, k, max_angle)
        return [(self.train_cameras[i], self.train_images[i]) for i in self._partner_orders[key]]

    def gaussian_log_scales(self, outputs: RenderOutput) -> Tensor:
        """[N, 3] log-scales of the Gaussians the scale regularisers act on (``reg.anisotropy_weight``):
        every row here; a model whose Gaussians are decoded per view gives those drawn in ``outputs``."""
        return self.params["scales"]

    # ---------------------------------------------------------------- load
    @classmethod
    def from_checkpoint(cls, config: GaussianModelConfig, run: RunFacts, scene_scale: float,
                        checkpoint: dict) -> "GaussianModel":
        """A trained model from a checkpoint payload: normal construction from its rows (no
        initialisation work), then :meth:`restore`; it renders with every SH degree."""
        model = cls(config, run, scene_scale, None, None, rows=checkpoint["params"])
        model.restore(checkpoint)
        model.on_loaded()
        return model

    def on_loaded(self) -> None:
        """After :meth:`from_checkpoint`'s restore: render with every SH degree."""
        self.active_sh_degree = self.config.sh_degree

    def as_params(self, rows: Mapping[str, Tensor], like: Mapping[str, Tensor] | None = None) -> dict[str, nn.Parameter]:
        """``rows`` as parameters, each trainable as the same key of ``like`` is, else when it holds
        floats and is not in :attr:`FIXED`."""
        like = like or {}
        return {
            k: nn.Parameter(v, requires_grad=like[k].requires_grad if k in like else v.is_floating_point() and k not in self.FIXED)
            for k, v in rows.items()
        }

    def restore(self, checkpoint: dict, device: torch.device | str | None = None) -> None:
        """The restore step of loading: a checkpoint payload's rows (``params``, moved to ``device``
        when given), network weights and extra state (:meth:`load_extra_state`) into this model."""
        rows = {k: v.to(device) if device is not None else v for k, v in checkpoint["params"].items()}
        self.params = nn.ParameterDict(self.as_params(rows, like=self.params))
        if checkpoint.get("networks"):
            self.networks.load_state_dict(checkpoint["networks"])
        if checkpoint.get("model_state"):
            self.load_extra_state(checkpoint["model_state"])


def _nearest_within(cameras: Sequence[Camera], view: int, k: int, max_angle: float) -> list[int]:
    """Indices of the ``k`` ``cameras`` whose centres lie nearest ``cameras[view]``'s, nearest first,
    among those whose optical axis is within ``max_angle`` degrees of its own (``view`` left out)."""
    centres = torch.stack([c.center.detach().float().cpu() for c in cameras])
    dist = (centres - centres[view]).norm(dim=-1).tolist()
    near = [i for i in sorted(range(len(cameras)), key=dist.__getitem__)
            if i != view and view_angle(cameras[view], cameras[i]) <= max_angle]
    return near[:k]

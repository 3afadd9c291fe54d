"""Densification (clone / split / prune / opacity reset) as a policy over plain dicts.

Modelled on gsplat's ``strategy/default.py``: the strategy sees only
``(params, optimizers, state, info)`` and never the model.

Typical loop::

    strategy = DefaultStrategy(DensifyConfig())
    strategy.check_sanity(params, optimizers)
    state = strategy.initialize_state(scene_scale)
    for step in range(max_steps):
        out = rasterize(..., absgrad=strategy.absgrad)  # out.meta is ``info``
        strategy.step_pre_backward(params, optimizers, state, step, out.meta)
        loss.backward()
        for opt in optimizers.values(): opt.step(); opt.zero_grad(set_to_none=True)  # first, as gsplat
        # params["means"] must now hold the true positions of ALL rows (a
        # model whose positions are computed, e.g. ray-bound Gaussians, writes
        # them into params["means"] before this call: prepare_for_strategy).
        # The statistics come from info (the render's meta), not from .grad.
        counts = strategy.step_post_backward(params, optimizers, state, step, out.meta)
        # a model hook that resized the rows returns a RowChange instead:
        # strategy.rows_changed(params, optimizers, state, step, change)

Extension points of :class:`DefaultStrategy` for models with extra per-row
parameters (SCGaussian's ray flags): ``protected_rows`` marks rows that are never
pruned, ``child_values`` gives the values that rows newly created by clone/split
take for named keys (e.g. ``{"is_ray": 0.0}``); a split parent stays in its row
(keeping its flags) and only the appended child is new.
"""

from __future__ import annotations

from typing import Any, Mapping, MutableMapping

import torch
from torch import Tensor

from splat_framework.config import DensifyConfig
from splat_framework.model.ops import RowChange, decay_opa, duplicate, remove, reset_opa, split

__all__ = ["DefaultStrategy", "DensifyConfig", "Strategy", "check_rows", "unplain_state"]


def check_rows(params: Mapping[str, Tensor], optimizers: Mapping[str, torch.optim.Optimizer],
               required: tuple[str, ...]) -> None:
    """Raise ValueError unless ``params`` holds the ``required`` keys, every entry has the same
    leading dimension (one row per Gaussian, anchor, ...) and every entry that requires grad
    has an optimizer (the conventions of ``model.ops``)."""
    for key in required:
        if key not in params:
            raise ValueError(f"params is missing {key!r}")
    n = params[required[0]].shape[0]
    for key, p in params.items():
        if p.dim() == 0 or p.shape[0] != n:
            raise ValueError(f"params[{key!r}] has shape {tuple(p.shape)}, expected leading dim {n}")
        if p.requires_grad and key not in optimizers:
            raise ValueError(f"params[{key!r}] requires grad but has no optimizer")


def unplain_state(state: Mapping[str, Any]) -> str | None:
    """``'key' (type)`` of the first entry of a strategy's ``state`` holding a value that a checkpoint
    loaded with ``weights_only=True`` cannot hold, None when every value is a tensor, a bool, int,
    float, str or None, or a list, tuple or dict of them (a numpy number is not: ``float(x)`` it)."""

    def odd(value: Any) -> str | None:
        if torch.is_tensor(value) or type(value) in (bool, int, float, str, type(None)):
            return None
        if isinstance(value, (list, tuple, dict)):
            items = [*value.keys(), *value.values()] if isinstance(value, dict) else value
            return next((bad for v in items if (bad := odd(v)) is not None), None)
        return type(value).__name__

    return next((f"{k!r} ({bad})" for k, v in state.items() if (bad := odd(v)) is not None), None)


class Strategy:
    """What the trainer calls to grow and prune Gaussians: the seam a plugin overrides.

    The run's config chooses it: ``config.strategy`` is a
    :class:`~splat_framework.config.StrategyConfig` whose ``setup()`` builds the
    strategy its ``strategy_class`` names (default: :class:`DefaultStrategy` from
    :class:`DensifyConfig`). A plugin adds its own kind (an MCMC-style relocation, ...)
    for every method by registering its config in the entry-point group
    ``splat_framework.strategies``, without touching the trainer. A
    strategy sees plain dicts only, never the model: ``params`` (name -> [N, ...]
    tensors, one row per Gaussian), ``optimizers`` (name -> optimizer of that one
    tensor), its own ``state`` (checkpointed by the trainer and loaded with ``weights_only=True``:
    tensors and plain values only, see :func:`unplain_state`; only the strategy edits it) and
    ``info`` (the rasterizer's meta dict). The trainer calls, each step: :meth:`loss` (added to
    the model's loss); unless its config is disabled (``enabled=False``), :meth:`step_pre_backward`
    and, after the optimizers stepped, :meth:`step_post_backward`, which returns counts of what it
    changed (summed in metrics.json's ``densified``); and :meth:`rows_changed` instead, at any
    step where a model hook resized the Gaussians. Every method has a do-nothing
    default (``rows_changed``: resize the per-row tensors), so a
    subclass overrides only what it needs; this base used as is never densifies.

    Built by its config as ``StrategyClass(config)`` (:meth:`StrategyConfig.setup`): the config is
    ``self.config`` (a subclass that takes more overrides ``__init__`` and calls this one).
    """

    def __init__(self, config: Any = None) -> None:
        self.config = config
        """The :class:`~splat_framework.config.StrategyConfig` this strategy was built from (None: built by hand)."""

    @property
    def absgrad(self) -> bool:
        """Whether a training render must leave ``means2d.absgrad`` for this strategy
        (``rasterize(absgrad=True)``; the trainer tells the model). Default: no."""
        return False

    def initialize_state(self, scene_scale: float = 1.0) -> dict[str, Any]:
        """Fresh running state (saved in every checkpoint)."""
        return {"scene_scale": float(scene_scale)}

    def check_sanity(self, params: Mapping[str, Tensor], optimizers: Mapping[str, torch.optim.Optimizer]) -> None:
        """Raise ValueError when ``params`` / ``optimizers`` break this strategy's conventions."""

    def loss(self, params: Mapping[str, Tensor], step: int) -> dict[str, Tensor]:
        """Loss terms this strategy adds to the model's at ``step`` (name -> scalar tensor, e.g.
        MCMC's opacity and scale regularisers), named unlike the model's terms; the trainer sums them
        with the model's and logs them alike. Default: none."""
        return {}

    def step_pre_backward(
        self,
        params: Mapping[str, Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer],
        state: MutableMapping[str, Any],
        step: int,
        info: Mapping[str, Any],
    ) -> None:
        """Before ``loss.backward()`` (e.g. ask the rasterizer to keep a gradient)."""

    def step_post_backward(
        self,
        params: Mapping[str, Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer],
        state: MutableMapping[str, Any],
        step: int,
        info: Mapping[str, Any],
    ) -> dict[str, int]:
        """After the optimizers stepped: grow / prune rows in place (resizing ``optimizers``
        and ``state`` with ``model.ops``); returns counts of what changed (name -> int, e.g.
        ``n_clone``), which the trainer sums over the run into metrics.json's ``densified``."""
        return {}

    def rows_changed(
        self,
        params: Mapping[str, Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer],
        state: MutableMapping[str, Any],
        step: int,
        change: RowChange,
    ) -> None:
        """Something other than this strategy (a model hook, e.g. SCGaussian's match filter) added or
        removed rows at ``step``, as ``change`` says (as gaussian-splatting-lightning's
        ``after_density_changed``); ``params`` and ``optimizers`` already have the new rows. The
        strategy brings its ``state`` in line; on a densify step this is called instead of
        :meth:`step_post_backward` (the step's statistics no longer line up). Default: every
        per-row tensor of ``state`` resized with :meth:`RowChange.resize`; a strategy with other
        bookkeeping (row counts, index maps) extends it."""
        change.resize(state)


class DefaultStrategy(Strategy):
    """3DGS adaptive density control with gsplat's interface.

    ``info`` is the rasterizer's meta dict: "means2d" [N, 2] (or [C, N, 2])
    pixel-space centres whose ``.grad`` is the positional gradient, "radii" [N]
    (or [N, 2] / [C, N] / [C, N, 2]) pixel radius, 0 when not visible,
    "width", "height" ints. The caller must make ``params["means"]`` hold the
    true current positions of all rows before ``step_post_backward``.
    """

    REQUIRED_KEYS = ("means", "quats", "scales", "opacities")

    def __init__(self, config: DensifyConfig | None = None) -> None:
        self.config = config if config is not None else DensifyConfig()

    @property
    def absgrad(self) -> bool:
        """``config.absgrad``: densify on the sums of absolute per-pixel gradients (AbsGS)."""
        return bool(self.config.absgrad)

    # ----------------------------------------------------------------- setup
    def initialize_state(self, scene_scale: float = 1.0) -> dict[str, Any]:
        """Fresh running state; per-Gaussian tensors are created lazily at the first step."""
        return {"grad2d": None, "count": None, "radii": None, "scene_scale": float(scene_scale)}

    def check_sanity(self, params: Mapping[str, Tensor], optimizers: Mapping[str, torch.optim.Optimizer]) -> None:
        """Raise ValueError if params/optimizers do not follow the conventions of ``ops``."""
        check_rows(params, optimizers, self.REQUIRED_KEYS)
        for key, opt in optimizers.items():
            if key not in params:
                raise ValueError(f"optimizer {key!r} has no matching params entry")
            groups = opt.param_groups
            if len(groups) != 1 or len(groups[0]["params"]) != 1 or groups[0]["params"][0] is not params[key]:
                raise ValueError(f"optimizer {key!r} must hold exactly params[{key!r}] in one param group")
        for key in self.child_values(params):
            if key not in params:
                raise ValueError(f"child value for {key!r}, which is not in params")

    # ----------------------------------------------------------------- hooks
    def protected_rows(self, params: Mapping[str, Tensor]) -> Tensor | None:
        """[N] bool of rows never pruned, or None (default: every row may be pruned)."""
        return None

    def child_values(self, params: Mapping[str, Tensor]) -> dict[str, float]:
        """Values that rows created by clone / split take for these keys (default: copies of the parent)."""
        return {}

    # ----------------------------------------------------------------- steps
    def step_pre_backward(
        self,
        params: Mapping[str, Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer],
        state: MutableMapping[str, Any],
        step: int,
        info: Mapping[str, Any],
    ) -> None:
        """Ask autograd to keep the gradient of ``info["means2d"]`` (with ``absgrad``, the render
        was asked for its sums of absolute per-pixel gradients: :attr:`absgrad`)."""
        means2d = info["means2d"]
        if means2d.requires_grad:
            means2d.retain_grad()

    def step_post_backward(
        self,
        params: MutableMapping[str, Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer],
        state: MutableMapping[str, Any],
        step: int,
        info: Mapping[str, Any],
    ) -> dict[str, int]:
        """Accumulate gradient statistics, densify/prune and reset opacities on schedule.

        Modifies ``params``, ``optimizers`` and ``state`` in place. Returns
        ``{"n_clone", "n_split", "n_prune"}`` (zeros when nothing ran).
        """
        cfg = self.config
        counts = {"n_clone": 0, "n_split": 0, "n_prune": 0}
        if cfg.opacity_decay < 1.0 and step > cfg.refine_start_iter:
            decay_opa(params, cfg.opacity_decay)
        if step >= cfg.refine_stop_iter:
            return counts
        self._update_state(params, state, info)
        since_reset = step if cfg.reset_every is None else step % cfg.reset_every
        if step > cfg.refine_start_iter and step % cfg.refine_every == 0 and since_reset >= cfg.pause_refine_after_reset:
            counts["n_clone"], counts["n_split"] = self._grow(params, optimizers, state, step)
            counts["n_prune"] = self._prune(params, optimizers, state, step)
            state["grad2d"].zero_()
            state["count"].zero_()
            state["radii"].zero_()
        if cfg.reset_every is not None and step % cfg.reset_every == 0 and step > 0:
            reset_opa(params, optimizers, state, value=cfg.prune_opa * 2.0)
        return counts

    # ------------------------------------------------------------- internals
    def _update_state(self, params: Mapping[str, Tensor], state: MutableMapping[str, Any], info: Mapping[str, Any]) -> None:
        means2d = info["means2d"]
        grad = getattr(means2d, "absgrad", None) if self.config.absgrad else means2d.grad
        if grad is None:
            what = "means2d.absgrad" if self.config.absgrad else "means2d.grad"
            raise RuntimeError(f"info[{what!r}] is None: call step_pre_backward before backward()")
        n = params["means"].shape[0]
        radii = info["radii"].detach()
        if radii.dim() == grad.dim():  # per-axis radii [..., N, 2] -> max
            radii = radii.max(dim=-1).values
        grads = grad.detach().clone()
        if grads.dim() == 2:  # single camera: [N, 2] -> [1, N, 2]
            grads, radii = grads[None], radii[None]
        if grads.shape[1] != n or radii.shape != grads.shape[:2]:
            raise ValueError(
                f"info['means2d'] {tuple(grad.shape)} / info['radii'] {tuple(info['radii'].shape)} "
                f"do not match {n} Gaussians"
            )
        radii = radii.to(grads.dtype)  # [C, N]
        n_cams = grads.shape[0]
        grads[..., 0] *= info["width"] / 2.0 * n_cams
        grads[..., 1] *= info["height"] / 2.0 * n_cams

        for key in ("grad2d", "count", "radii"):
            if state[key] is None:
                state[key] = torch.zeros(n, device=grads.device, dtype=grads.dtype)
            elif state[key].shape[0] != n:
                raise RuntimeError(
                    f"strategy state has {state[key].shape[0]} rows but params have {n}: "
                    "Gaussians were added or removed outside the strategy; call initialize_state() again"
                )
        # dense over every row (masked), not gathered at the visible ones: a gather's size is a host read
        visible = radii > 0  # [C, N]
        state["grad2d"] += torch.where(visible, grads.norm(dim=-1), 0.0).sum(0)
        state["count"] += visible.sum(0).to(grads.dtype)
        rel = torch.where(visible, radii / float(max(info["width"], info["height"])), 0.0).amax(0)
        torch.maximum(state["radii"], rel, out=state["radii"])

    @torch.no_grad()
    def _grow(self, params, optimizers, state, step: int) -> tuple[int, int]:
        cfg = self.config
        grads = state["grad2d"] / state["count"].clamp_min(1)
        is_grad_high = grads > cfg.grow_grad2d
        max_scale = torch.exp(params["scales"]).max(dim=-1).values
        is_small = max_scale <= cfg.grow_scale3d * state["scene_scale"]
        is_clone = is_grad_high & is_small
        is_split = is_grad_high & ~is_small
        if step < cfg.refine_scale2d_stop_iter:
            is_split |= state["radii"] > cfg.grow_scale2d
        n_clone, n_split = int(is_clone.sum()), int(is_split.sum())
        children = self.child_values(params)
        if n_clone > 0:
            duplicate(params, optimizers, state, is_clone, child_values=children)
        # clones are appended after all original rows and are not split
        is_split = torch.cat([is_split, is_split.new_zeros(n_clone)])
        if n_split > 0:
            split(params, optimizers, state, is_split, revised_opacity=cfg.revised_opacity, child_values=children)
        return n_clone, n_split

    @torch.no_grad()
    def _prune(self, params, optimizers, state, step: int) -> int:
        cfg = self.config
        is_prune = torch.sigmoid(params["opacities"].flatten()) < cfg.prune_opa
        if cfg.reset_every is not None and step > cfg.reset_every:
            max_scale = torch.exp(params["scales"]).max(dim=-1).values
            is_prune |= max_scale > cfg.prune_scale3d * state["scene_scale"]
            if step < cfg.refine_scale2d_stop_iter:
                is_prune |= state["radii"] > cfg.prune_scale2d
        protected = self.protected_rows(params)
        if protected is not None:
            is_prune &= ~protected
        n_prune = int(is_prune.sum())
        if n_prune > 0:
            remove(params, optimizers, state, is_prune)
        return n_prune

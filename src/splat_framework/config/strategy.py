"""The densification strategies' configs: :class:`StrategyConfig` (each kind tagged by ``kind``),
3DGS's :class:`DensifyConfig`, and the kinds every method accepts (:data:`RegisteredStrategies`,
filled from the ``splat_framework.strategies`` entry points). Torch-free."""

from __future__ import annotations

from functools import cache
from typing import Annotated, Any, ClassVar, Literal, Union

import tyro
from pydantic import BeforeValidator, Field, SerializeAsAny

from .base import (
    Interval,
    Kind,
    KindConfig,
    NonNegative,
    OptionalPeriod,
    Positive,
    StartSteps,
    StepFactor,
    Steps,
    as_registered_kind,
    registered_kinds,
)


class StrategyConfig(KindConfig):
    """Base of the densification strategies' configs, each tagged by its ``kind``.

    Each subclass names its ``kind`` (``kind: Kind[Literal["TAG"]] = "TAG"``: the tag by which a saved
    config, a TOML variant, a sweep or ``--strategy.kind`` picks it) and its strategy
    class as ``"module:Class"`` in :attr:`strategy_class` (imported, with torch, only
    by :meth:`setup`). A kind registered in the entry-point group
    ``splat_framework.strategies`` (see :mod:`splat_framework.entry_points`) is accepted by
    every method whose config keeps :data:`RegisteredStrategies`; a method that
    accepts fewer kinds lists them with :func:`strategy_field`."""

    strategy_class: ClassVar[str] = ""
    """``"module:Class"`` of the :class:`~splat_framework.model.strategy.Strategy` built from this config
    (a :class:`~splat_framework.entry_points.Ref`, checked before any data loads)."""
    enabled: bool = True
    """Run densification at all (False keeps the initial Gaussians only)."""

    @classmethod
    def registered_kinds(cls) -> dict[str, type["StrategyConfig"]]:
        """The kinds a field of this base type accepts (:func:`strategy_kinds`; the command line's
        ``--strategy.kind``, see :mod:`splat_framework.cli.kinds`)."""
        return strategy_kinds()

    def setup(self):
        """The :class:`~splat_framework.model.strategy.Strategy` this config describes: ``strategy_class(self)``."""
        if not self.strategy_class:
            raise NotImplementedError(f"{type(self).__name__}.strategy_class is not set")
        from ..entry_points import STRATEGY_BASE, Ref

        return Ref(self.strategy_class, STRATEGY_BASE, f"{type(self).__name__}.strategy_class").load()(self)


def strategy_field(*configs: type[StrategyConfig]):
    """The annotation of a ``strategy`` field accepting only these :class:`StrategyConfig` kinds.

    A method whose strategy must not be swapped for any registered one (SCGaussian keeps the
    Gaussians of its matches) narrows its field, e.g.
    ``strategy: strategy_field(MyStrategyConfig, DensifyConfig) = Field(default_factory=MyStrategyConfig)``.
    The CLI shows the flags of the default's kind (no subcommand to type)."""
    if len(configs) == 1:
        return Annotated[configs[0], tyro.conf.AvoidSubcommands]
    return Annotated[Union[configs], Field(discriminator="kind"), tyro.conf.AvoidSubcommands]


@cache
def strategy_kinds() -> dict[str, type[StrategyConfig]]:
    """Every strategy kind a method accepts unless it narrows its field: ``default``
    (:class:`DensifyConfig`), then the ``splat_framework.strategies`` entry points."""
    from ..entry_points import STRATEGY_ENTRY_POINT_GROUP

    return registered_kinds(STRATEGY_ENTRY_POINT_GROUP, "strategy", StrategyConfig, {"default": DensifyConfig})


def _registered_strategy(value: Any) -> Any:
    """``value`` (a dict or a config) as the :class:`StrategyConfig` of its registered kind."""
    return as_registered_kind(value, strategy_kinds(), "default", "strategy")


class DensifyConfig(StrategyConfig):
    """Adaptive density control of 3DGS (clone, split, prune, opacity reset)."""

    kind: Kind[Literal["default"]] = "default"
    """The strategy's tag."""
    prune_opa: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.005
    """Prune Gaussians whose opacity falls below this."""
    grow_grad2d: NonNegative = 0.0002
    """Grow Gaussians whose mean screen-space gradient exceeds this."""
    grow_scale3d: Positive = 0.01
    """Clone below / split above this largest scale (scene scale)."""
    grow_scale2d: Positive = 0.05
    """Also split Gaussians whose screen radius / image size exceeds this."""
    prune_scale3d: Positive = 0.1
    """After the first reset, prune Gaussians larger than this (scene scale)."""
    prune_scale2d: Positive = 0.15
    """Prune Gaussians whose screen radius exceeds this fraction of the image."""
    refine_scale2d_stop_iter: Steps = 0
    """Stop the 2D-size pruning after this iteration (0 = never use it)."""
    refine_start_iter: StartSteps = 500
    """First iteration at which densification runs."""
    refine_stop_iter: Steps = 2500
    """Last iteration at which densification runs."""
    reset_every: OptionalPeriod = 3000
    """Reset opacities to 2*prune_opa every this many iterations (None: never)."""
    opacity_decay: StepFactor = 1.0
    """Multiply every opacity by this each step from refine_start_iter (1 = off)."""
    refine_every: Interval = 100
    """Densify every this many iterations (not rescaled by --steps)."""
    pause_refine_after_reset: Steps = 0
    """Skip densification for this many iterations after an opacity reset."""
    absgrad: bool = False
    """Grow by the absolute gradient (AbsGS); raise grow_grad2d with it."""
    revised_opacity: bool = False
    """Revised opacity for cloned and split Gaussians (Rota Bulo et al.)."""

    strategy_class: ClassVar[str] = "splat_framework.model.strategy:DefaultStrategy"


RegisteredStrategies = Annotated[
    SerializeAsAny[StrategyConfig], BeforeValidator(_registered_strategy), tyro.conf.AvoidSubcommands
]
"""The strategy kinds every method accepts unless it narrows them with :func:`strategy_field`:
``default`` (:class:`DensifyConfig`) and every kind of the ``splat_framework.strategies`` entry points."""


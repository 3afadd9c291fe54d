"""The 3dgs baseline's schedules for a run of another method (torch-free).

A method whose init can come out thin (SCGaussian's matching prior with few matches) may train
as the baseline would instead: :func:`baseline_schedule` gives the densification and SH schedules
the ``3dgs`` baseline uses at the run's length, in the run's own strategy kind, keeping every field
the user set.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import StrategyConfig, flag_name, resolve_steps
from ..registry import registered_defaults
from .gaussian_splatting import config_3dgs


@dataclass(frozen=True)
class BaselineSchedule:
    """What a run trains with instead of its config's schedule (the run's config,
    saved in config.json and checked by ``--resume``, stays the one config of the run)."""

    strategy: StrategyConfig
    """The densification: SCGaussian's strategy kind with the ``3dgs`` baseline's thresholds and
    iterations, except the fields the user set."""
    sh_degree_interval: int
    """Steps between SH degree increases: the baseline's, or the user's own when set."""
    changed: dict[str, tuple]
    """Field -> (the run config's value, the value trained with), for each field the switch changed."""
    kept: tuple[str, ...]
    """The fields the user set (they differ from the method's defaults), kept as set."""

    def message(self, why: str) -> str:
        """One line: ``why`` the run switched, what the switch changed and what it kept."""
        changes = ", ".join(f"{k} {a} -> {b}" for k, (a, b) in self.changed.items()) or "nothing"
        flags = ", ".join(flag_name(k) for k in self.kept)
        kept = f"; kept as you set: {flags}" if self.kept else ""
        return f"{why}: training on the 3dgs baseline's densification and SH schedule ({changes}){kept}"


def baseline_schedule(config) -> BaselineSchedule:
    """The densification and SH schedules that the ``3dgs`` baseline would use at the
    same total iterations as ``config`` (its own thresholds and iterations, rescaled as
    ``--steps`` does), in ``config``'s strategy kind (SCGaussian's, which keeps the ray-based
    Gaussians) with its other strategy fields unchanged. A field the user set (one that differs
    from the method's registered defaults, :func:`~splat_framework.plugin.registered_defaults`)
    keeps the user's value."""
    base = resolve_steps(config_3dgs().model_copy(update={"steps": config.total_steps}))
    defaults = registered_defaults(config)
    own = config.strategy.model_dump()
    reference = defaults.strategy.model_dump() if defaults is not None and type(defaults.strategy) is type(config.strategy) else own
    user = {k for k, v in own.items() if reference.get(k, v) != v}
    swap = {k: v for k, v in base.strategy.model_dump(exclude={"kind", "enabled"}).items() if k in own and k not in user}
    strategy = type(config.strategy).model_validate(own | swap)
    changed = {k: (own[k], v) for k, v in swap.items() if own[k] != v}
    interval = config.model.sh_degree_interval
    if defaults is not None and interval != defaults.model.sh_degree_interval:
        user.add("model.sh_degree_interval")
    elif interval != base.model.sh_degree_interval:
        changed["model.sh_degree_interval"] = (interval, base.model.sh_degree_interval)
        interval = base.model.sh_degree_interval
    kept = tuple(sorted(f"strategy.{k}" if "." not in k else k for k in user))
    return BaselineSchedule(strategy=strategy, sh_degree_interval=interval, changed=changed, kept=kept)

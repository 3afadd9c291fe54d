"""Schedule arithmetic: ``--steps`` (or more views than a method's schedule is written for)
rescales every :data:`~splat_framework.config.base.Steps` field of a config, and every per-step
factor (:data:`~splat_framework.config.base.StepFactor`) with it. Torch-free."""

from __future__ import annotations

from typing import Any

from .base import PER_STEP_MARKER, SHORTEN_ONLY, STEPS_MARKER, Marker, SplatConfig
from .train import TrainConfig


def _has_marker(info, marker: Marker) -> bool:
    return any(m is marker for m in info.metadata)


def follows_schedule(info) -> bool:
    """Whether a field (its pydantic ``FieldInfo``) is rescaled with the schedule: it counts
    iterations (:data:`Steps` and its kin) or is a per-step factor (:data:`StepFactor`)."""
    return _has_marker(info, STEPS_MARKER) or _has_marker(info, PER_STEP_MARKER)


def scale_schedule(config: SplatConfig, factor: float) -> SplatConfig:
    """A copy of ``config`` with every :data:`Steps` field multiplied by ``factor`` (recursively),
    except that a :data:`StartSteps` or :data:`RampPeriod` field is only ever shortened (times
    ``min(factor, 1)``), and every :data:`StepFactor` field (a decay applied each iteration) is
    raised to the power ``1 / factor``, so that its product over the run stays the same.

    The rule for starts follows the public 3DGS and SCGaussian code, which begin densification
    at iteration 500 whatever the run's length, and keep the SH degree's interval at 1000; the
    measurements that chose it are in docs/decisions.md.
    """
    updates: dict[str, Any] = {}
    for name, info in type(config).model_fields.items():
        value = getattr(config, name)
        if isinstance(value, SplatConfig):
            updates[name] = scale_schedule(value, factor)
        elif _has_marker(info, STEPS_MARKER) and isinstance(value, int) and value > 0:
            f = min(factor, 1.0) if _has_marker(info, SHORTEN_ONLY) else factor
            updates[name] = max(1, int(round(value * f)))
        elif _has_marker(info, PER_STEP_MARKER) and isinstance(value, float):
            updates[name] = value ** (1.0 / factor)
    return config.model_copy(update=updates)


def resolve_steps(config: TrainConfig) -> TrainConfig:
    """The config with its total iterations settled and the schedule rescaled to fit them.

    The total is ``--steps`` when given, else ``default_steps``, scaled by
    views / ``schedule_views`` when the run has more training views than the
    method's schedule is written for (each view is then seen as often); a
    resolved config resolves to itself (so a resumed run sees the same schedule).
    """
    steps = config.steps
    if steps is None and config.schedule_views > 0 and isinstance(config.views, int) and config.views > config.schedule_views:
        steps = int(round(config.default_steps * config.views / config.schedule_views))
    if steps is None or steps == config.default_steps:
        return config
    scaled = scale_schedule(config, steps / config.default_steps)
    return scaled.model_copy(update={"default_steps": steps, "steps": steps})


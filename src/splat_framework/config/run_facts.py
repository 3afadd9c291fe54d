"""What a model may read of its run beyond its own config (torch-free)."""

from __future__ import annotations

from dataclasses import dataclass

from .model import OptimConfig


@dataclass(frozen=True)
class RunFacts:
    """The run's facts a model reads besides ``config.model``, which is all of the run config it
    receives (its constructor, ``from_data`` and ``from_checkpoint`` take both). Made once by the
    pipeline (:meth:`of`) from the resolved config."""

    total_steps: int
    """The run's length in steps (learning-rate decays and ramps over the run)."""
    seed: int
    """The run's seed (per-step draws are keyed by it and the step)."""
    coarse_steps: int
    """The first steps, which train on the images at the coarse scale (0: none)."""
    optim: OptimConfig
    """The Gaussians' learning rates (``--optim.*``)."""

    @classmethod
    def of(cls, config) -> "RunFacts":
        """The facts of a resolved ``TrainConfig`` (its ``--steps`` and views already applied)."""
        return cls(total_steps=config.total_steps, seed=config.seed, coarse_steps=config.coarse_steps,
                   optim=config.optim)

"""SCGaussian's pipeline: the framework's, plus the 3dgs baseline's schedule after a thin prior."""

from __future__ import annotations

import warnings

from splat_framework.plugin import BaselineSchedule, Pipeline, baseline_schedule


class SCGaussianPipeline(Pipeline):
    """When the model's init found the matching prior missing or sparse (``model.thin_prior``) and
    ``model.thin_prior_baseline`` is on, the run trains with the 3dgs baseline's densification and
    SH schedules (:func:`~splat_framework.methods.baseline.baseline_schedule`): the strategy config this pipeline
    names, and the model's SH interval. config.json keeps the run's one config."""

    baseline: BaselineSchedule | None = None
    """The baseline's schedules the run trains with instead of its config's (None: its config's)."""

    def build_model(self, generator):
        model = super().build_model(generator)
        use = bool(self.config.model.thin_prior_baseline and model.thin_prior)
        if use:
            self.baseline = baseline_schedule(self.config)
            warnings.warn(self.baseline.message("thin prior"), stacklevel=2)
            model.config = model.config.model_copy(update={"sh_degree_interval": self.baseline.sh_degree_interval})
        model.init_stats = dict(model.init_stats) | {"baseline_schedule": use}
        return model

    def strategy_config(self):
        return super().strategy_config() if self.baseline is None else self.baseline.strategy

"""The pipeline: it builds a run's data and model (:class:`Pipeline`) from the resolved config.

- :mod:`.base`: :class:`Pipeline`, what a method subclasses to build its data or model differently;
- :mod:`.scene`: the scene a training config names, read with its recorded split, and its background;
- :mod:`.memory_plan`: the decoded-image cache sized to the machine's memory;
- :mod:`.camera_refine`: the training views' learned pose corrections (``--camera-refine``).
"""

from .base import Pipeline
from .scene import resolve_run_config

__all__ = ["Pipeline", "resolve_run_config"]

"""Evaluation: held-out views (held_out), pictures (PNG, colour maps), metrics, ST-LPIPS, test-time pose refinement, figures.

The names of the old module ``splat_framework.evaluation`` resolve here for one release, with a
``DeprecationWarning``; import them from the module that holds them now (held_out, metrics, pictures).
"""

from .._moved import forwarding

_OLD_HOMES = {
    "evaluate": "held_out",
    "DEPTH_KEYS": "metrics",
    "depth_metrics": "metrics",
    "colorize_depth": "pictures",
    "error_map": "pictures",
    "label_panel": "pictures",
    "to_uint8": "pictures",
    "write_png": "pictures",
}

__getattr__ = forwarding(__name__, _OLD_HOMES)

"""Evaluation: held-out views (held_out), metrics, ST-LPIPS, test-time pose refinement, figures.

The names of the old module ``splat_framework.evaluation`` resolve here for one release, with a
``DeprecationWarning``; import them from ``splat_framework.evaluation.held_out``.
"""

from .._moved import forward

_OLD_NAMES = frozenset(['DEPTH_KEYS', 'colorize_depth', 'depth_metrics', 'error_map', 'evaluate', 'label_panel', 'to_uint8', 'write_png'])


def __getattr__(name: str):
    return forward(__name__, f"{__name__}.held_out", _OLD_NAMES, name)

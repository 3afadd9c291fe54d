"""What leaves a run: PLY files (ply), videos (video), novel-view camera paths (camera_paths).

The names of the old module ``splat_framework.export`` resolve here for one release, with a
``DeprecationWarning``; import them from ``splat_framework.export.ply``.
"""

from .._moved import forward

_OLD_NAMES = frozenset(['export_ply', 'gaussians_for_export', 'load_ply', 'ply_property_names', 'write_ply'])


def __getattr__(name: str):
    return forward(__name__, f"{__name__}.ply", _OLD_NAMES, name)

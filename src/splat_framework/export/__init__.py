"""What leaves a run: PLY files (ply), videos (video), novel-view camera paths (camera_paths).

The names of the old module ``splat_framework.export`` resolve here for one release, with a
``DeprecationWarning``; import them from ``splat_framework.export.ply``.
"""

from .._moved import forwarding

_OLD_HOMES = {
    "export_ply": "ply",
    "gaussians_for_export": "ply",
    "load_ply": "ply",
    "ply_property_names": "ply",
    "write_ply": "ply",
}

__getattr__ = forwarding(__name__, _OLD_HOMES)

"""The local web viewer (scene_viewer), where it listens (serving) and what its clients may do (viser_clients).

The names of the old module ``splat_framework.viewer`` resolve here for one release, with a
``DeprecationWarning``; import them from ``splat_framework.viewer.scene_viewer``.
"""

from .._moved import forwarding

_OLD_HOMES = {
    "ORDINARY_RGB": "scene_viewer",
    "RAY_RGB": "scene_viewer",
    "STARTUP_S": "scene_viewer",
    "THUMBNAIL_PX": "scene_viewer",
    "Viewer": "scene_viewer",
    "ViewerCallback": "scene_viewer",
    "splat_arrays": "scene_viewer",
    "view_run": "scene_viewer",
}

__getattr__ = forwarding(__name__, _OLD_HOMES)

"""The local web viewer (scene_viewer), where it listens (serving) and what its clients may do (viser_clients).

The names of the old module ``splat_framework.viewer`` resolve here for one release, with a
``DeprecationWarning``; import them from ``splat_framework.viewer.scene_viewer``.
"""

from .._moved import forward

_OLD_NAMES = frozenset(['ORDINARY_RGB', 'RAY_RGB', 'STARTUP_S', 'THUMBNAIL_PX', 'Viewer', 'ViewerCallback', 'splat_arrays', 'view_run'])


def __getattr__(name: str):
    return forward(__name__, f"{__name__}.scene_viewer", _OLD_NAMES, name)

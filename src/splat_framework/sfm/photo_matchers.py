"""Photo matchers: the correspondences COLMAP maps from, by name.

"sift" is COLMAP's own; others are registered under the entry point group
``splat_framework.photo_matchers`` (the framework's matching prior registers its learned
``aliked-lightglue`` and ``disk-lightglue``; plugins may add more): a function
``match(images: list[[H, W, 3] uint8 RGB]) -> {(i, j): (pts_i [M, 2], pts_j [M, 2])}`` in
continuous pixel coordinates (pixel centres at +0.5, COLMAP's convention). "auto" is
AUTO_PREFERRED where it is registered and its weights are installed, else SIFT.
"""

from __future__ import annotations

from ..entry_points import PHOTO_MATCHER_ENTRY_POINT_GROUP as PHOTO_MATCHER_GROUP
from ..errors import DataError

AUTO_MATCHER = "auto"  # AUTO_PREFERRED where registered and its weights are installed, else sift
AUTO_PREFERRED = "aliked-lightglue"


def photo_matchers() -> dict[str, object]:
    """Entry points of the registered photo matchers (the framework's and installed plugins'), by name (not loaded)."""
    from ..entry_points import registered

    return {ep.name: ep for ep in registered(PHOTO_MATCHER_GROUP)}


def choose_matcher(matcher: str, plugins: dict[str, object]) -> str:
    """The matcher that ``matcher`` names ("auto" resolved against the registered ``plugins``); a
    one-line DataError listing the choices when it names none."""
    if matcher == AUTO_MATCHER:
        return AUTO_PREFERRED if AUTO_PREFERRED in plugins else "sift"
    if matcher != "sift" and matcher not in plugins:
        raise DataError(f"--matcher must be one of {', '.join(['auto', 'sift', *sorted(plugins)])}, got {matcher!r}")
    return matcher

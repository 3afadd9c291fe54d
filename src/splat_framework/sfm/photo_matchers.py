"""Photo matchers: the correspondences COLMAP maps from, by name.

"sift" is COLMAP's own; others are registered under the entry point group
``splat_framework.photo_matchers`` (the framework's matching prior registers its learned
``aliked-lightglue`` and ``disk-lightglue``; plugins may add more): a function
``match(images: list[[H, W, 3] uint8 RGB], pairs=None) -> {(i, j): (pts_i [M, 2], pts_j [M, 2])}``
in continuous pixel coordinates (pixel centres at +0.5, COLMAP's convention), over the pairs
``pairs`` names (:mod:`.pair_selection`; None: every pair). A function without a ``pairs``
parameter matches every pair, and the pairs not chosen are dropped (:func:`run_matcher`). "auto" is
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


def run_matcher(match, images: list, pairs: list[tuple[int, int]]) -> dict:
    """``match``'s matches of ``images`` over ``pairs``: passed to it when it takes a ``pairs``
    parameter, else every pair matched and the others dropped."""
    import inspect

    try:
        takes_pairs = "pairs" in inspect.signature(match).parameters
    except (TypeError, ValueError):  # a builtin without a signature
        takes_pairs = False
    if takes_pairs:
        return match(images, pairs=pairs)
    chosen = set(pairs)
    return {pair: m for pair, m in match(images).items() if tuple(pair) in chosen}

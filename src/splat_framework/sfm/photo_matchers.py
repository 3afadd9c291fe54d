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
    """Entry points of the registered photo matchers (the framework's and installed plugins'), by name
    (not loaded), under the one rule of every kind (:class:`~splat_framework.entry_points.Parts`):
    ``sift`` and the framework's own first, and a taken name keeps its first registration."""
    from ..entry_points import Parts

    parts = Parts("photo matcher")
    parts.add("sift", None, "the framework (COLMAP's SIFT)")
    parts.load(PHOTO_MATCHER_GROUP, load=False)
    return {name: entry for name, entry in parts.parts.items() if entry is not None}


def choose_matcher(matcher: str, plugins: dict[str, object], flag: str = "--matcher") -> str:
    """The matcher that ``matcher`` names ("auto" resolved against the registered ``plugins``); a
    one-line DataError naming ``flag`` (the command's, e.g. splat-train's ``--photos.matcher``) and
    listing the choices when it names none."""
    if matcher == AUTO_MATCHER:
        return AUTO_PREFERRED if AUTO_PREFERRED in plugins else "sift"
    if matcher != "sift" and matcher not in plugins:
        raise DataError(f"{flag} must be one of {', '.join(['auto', 'sift', *sorted(plugins)])}, got {matcher!r}")
    return matcher


def load_matcher(name: str, entry) -> object:
    """The function the photo matcher ``name``'s ``entry`` names; one DataError line naming the entry
    when it does not import or is not callable."""
    from ..entry_points import IMPORT_FAILURES, raised

    try:
        match = entry.load()
    except IMPORT_FAILURES as e:
        raise DataError(f"photo matcher '{name}' of {entry} cannot be imported ({raised(e)})") from None
    if not callable(match):
        raise DataError(f"photo matcher '{name}' of {entry} is not callable (it is of type {type(match).__name__}); "
                        "it must be a function match(images, pairs=None) -> {(i, j): (pts_i [M, 2], pts_j [M, 2])}")
    return match


def run_matcher(match, images: list, pairs: list[tuple[int, int]], name: str = "") -> dict:
    """``match``'s matches of ``images`` over ``pairs``: passed to it when it takes a ``pairs``
    parameter, else every pair matched and the others dropped. What it returns is checked: one
    DataError line naming the matcher ``name`` when it is not ``{(i, j): (pts_i [M, 2], pts_j [M, 2])}``
    with i < j photo indices and finite points."""
    import inspect

    try:
        takes_pairs = "pairs" in inspect.signature(match).parameters
    except (TypeError, ValueError):  # a builtin without a signature
        takes_pairs = False
    found = match(images, pairs=pairs) if takes_pairs else match(images)
    problem = _matches_problem(found, len(images))
    if problem:
        raise DataError(f"photo matcher '{name}' returned {problem}; it must return "
                        "{(i, j): (pts_i [M, 2], pts_j [M, 2])} with 0 <= i < j < the photos' count")
    if takes_pairs:
        return {tuple(pair): m for pair, m in found.items()}
    chosen = set(pairs)
    return {tuple(pair): m for pair, m in found.items() if tuple(pair) in chosen}


def _matches_problem(found: object, count: int) -> str | None:
    """What is wrong with a photo matcher's result ``found`` for ``count`` photos (one phrase), or None."""
    import numpy as np

    if not isinstance(found, dict):
        return f"a {type(found).__name__}, not a dict"
    for pair, value in found.items():
        if not (isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(k, (int, np.integer)) for k in pair)
                and 0 <= pair[0] < pair[1] < count):
            return f"the key {pair!r}, not a pair (i, j) of photo indices"
        if not (isinstance(value, (tuple, list)) and len(value) == 2):
            return f"for {pair} a {type(value).__name__}, not (pts_i, pts_j)"
        try:
            pts = [np.asarray(v, dtype=np.float64) for v in value]
        except (TypeError, ValueError):
            return f"for {pair} points that are not numbers"
        if any(a.ndim != 2 or a.shape[1] != 2 for a in pts) or pts[0].shape != pts[1].shape:
            return f"for {pair} points of shapes {[list(a.shape) for a in pts]}, not two [M, 2]"
        if not all(np.isfinite(a).all() for a in pts):
            return f"for {pair} points that are not finite"
    return None

"""What the matching says about views and pairs, by the views' names (their images' names, as
``describe_split`` names them: ``IMG_9``), never by their indices in the dataset.

:func:`~.pipeline.compute_matches` records why a pair was left empty (``MatchSet.warnings``);
whoever asked for the matches reports it with :func:`warn_empty`: at most two lines, one naming
the pairs left empty (and, for photos posed by splat, whether that touches the poses), one naming
the views without any verified match.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

from .geometry import MIN_PAIR_MATCHES
from .matchset import MatchSet, Pair

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera
    from splat_framework.sfm.posing_record import PosingRecord

LISTED = 10
"""Up to this many pairs or views are named in a line; more are counted."""


def view_names(view_ids: list[int], cameras: list["Camera"] | None) -> dict[int, str]:
    """View id -> its camera's name (the image's name), or the id itself where a view has no named camera."""
    named = [c.name for c in cameras] if cameras is not None else [""] * len(view_ids)
    return {int(v): name or str(int(v)) for v, name in zip(view_ids, named)}


def pair_name(pair: Pair, names: dict[int, str]) -> str:
    """``IMG_1-IMG_3``: a pair of views by name (``names``: view id -> name; an id missing there stands for itself)."""
    return "-".join(names.get(v) or str(v) for v in pair)


def listed(items: list[str], limit: int = LISTED) -> str:
    """``a, b, c``, or beyond ``limit`` items ``a, b, ... and 12 more``."""
    more = f" and {len(items) - limit} more" if len(items) > limit else ""
    return ", ".join(items[:limit]) + more


def empty_pairs_line(match_set: MatchSet, names: dict[int, str]) -> str | None:
    """One line naming the pairs left empty (too few verified matches), or None when every pair kept some."""
    empty = [p for p in match_set.pairs() if p in match_set.warnings]
    if not empty:
        return None
    return (f"{len(empty)} of {len(match_set.pairs())} pairs left empty (fewer than {MIN_PAIR_MATCHES} verified "
            f"matches): {listed([pair_name(p, names) for p in empty])}")


def unmatched_views_line(match_set: MatchSet, names: dict[int, str]) -> str | None:
    """One line naming the training views without a verified match with any other, or None when there are none."""
    lost = [names.get(v) or str(v) for v in match_set.unmatched_views()]
    if not lost:
        return None
    which = f"training view {lost[0]} has" if len(lost) == 1 else f"training views {listed(lost)} have"
    return (f"{which} no verified match with any other training view: the matching prior cannot place "
            f"{'it' if len(lost) == 1 else 'them'} (photos with more overlap, or another matcher, help)")


def poses_clause(posing: "PosingRecord") -> str:
    """What the pairs left empty mean for the poses of photos posed by splat (``posing``): nothing,
    when every photo registered; else which photos the poses lack, and what may pose them."""
    n = len(posing.photos)
    if not posing.left_out:
        return (f"the poses are not affected (all {n} photos registered): those photos overlap too little "
                "for the prior's matches")
    return (f"the poses lack {len(posing.left_out)} of the {n} photos, not registered (left out of the scene): "
            f"{listed(posing.left_out)}; {posing.retry} may pose them")


def warn_empty(match_set: MatchSet, names: dict[int, str], posing: "PosingRecord | None" = None) -> None:
    """Report (one line each) the pairs of ``match_set`` left empty and the views it leaves without
    any verified match, every view by its name (``names``: view id -> name, :func:`view_names`).

    ``posing``: the record of the posing of the scene's photos by splat (None for a dataset's own
    poses). With it, the empty pairs' line says what they mean for the poses: an information line
    when every photo registered, else a warning naming the photos left out and what to try."""
    from ..console import say

    empty = empty_pairs_line(match_set, names)
    if empty is not None and posing is not None and not posing.left_out:
        say(f"{empty}; {poses_clause(posing)}")
    elif empty is not None:
        warnings.warn(f"{empty}; {poses_clause(posing)}" if posing is not None else empty, stacklevel=3)
    lost = unmatched_views_line(match_set, names)
    if lost is not None:
        warnings.warn(lost, stacklevel=3)


__all__ = ["LISTED", "empty_pairs_line", "listed", "pair_name", "poses_clause", "unmatched_views_line", "view_names",
           "warn_empty"]

"""What the matching says about views and pairs, by the views' names (their images' names, as
``describe_split`` names them: ``IMG_9``), never by their indices in the dataset.

:func:`~.pipeline.compute_matches` records why a pair was left empty (``MatchSet.warnings``);
whoever asked for the matches reports it with :func:`warn_empty`: at most two warning lines,
one naming the pairs left empty, one naming the views without any verified match.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

from .geometry import MIN_PAIR_MATCHES
from .matchset import MatchSet, Pair

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera

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


def warn_empty(match_set: MatchSet, names: dict[int, str]) -> None:
    """Warn (one line each) about the pairs of ``match_set`` left empty and the views it leaves without
    any verified match, every view by its name (``names``: view id -> name, :func:`view_names`)."""
    for line in (empty_pairs_line(match_set, names), unmatched_views_line(match_set, names)):
        if line is not None:
            warnings.warn(line, stacklevel=3)


__all__ = ["LISTED", "empty_pairs_line", "listed", "pair_name", "unmatched_views_line", "view_names", "warn_empty"]

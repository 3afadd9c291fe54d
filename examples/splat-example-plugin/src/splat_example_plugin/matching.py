"""A photo matcher from outside the framework: OpenCV's ORB features, matched by brute force with
Lowe's ratio test (``splat-process images PHOTOS --out SCENE --matcher orb``)."""

import cv2
import numpy as np

RATIO = 0.8
"""A match is kept when its Hamming distance is below this fraction of the second best's."""


def match_photos(images: list[np.ndarray]) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """The matches of every pair of ``images`` ([H, W, 3] uint8 RGB): ``{(i, j): (pts_i [M, 2],
    pts_j [M, 2])}`` in continuous pixel coordinates (pixel centres at +0.5); a pair without
    matches is left out."""
    orb = cv2.ORB_create(nfeatures=4000)
    features = [orb.detectAndCompute(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), None) for image in images]
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    found = {}
    for i, (keys_i, desc_i) in enumerate(features):
        for j in range(i + 1, len(features)):
            keys_j, desc_j = features[j]
            if desc_i is None or desc_j is None or len(keys_j) < 2:
                continue
            best = [p[0] for p in matcher.knnMatch(desc_i, desc_j, k=2) if len(p) == 2 and p[0].distance < RATIO * p[1].distance]
            if best:
                pts_i = np.float32([keys_i[m.queryIdx].pt for m in best]) + 0.5  # OpenCV's centres are at integers
                pts_j = np.float32([keys_j[m.trainIdx].pt for m in best]) + 0.5
                found[(i, j)] = (pts_i, pts_j)
    return found

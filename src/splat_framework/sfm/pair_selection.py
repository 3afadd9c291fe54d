"""Which pairs of photos are matched when posing them: every pair of a small set; for a larger one
each photo's nearest photos by a global similarity computed from the photos themselves, and for
the frames of a clip their neighbours in time as well (COLMAP's and hloc's retrieval and sequential
pairing, with no downloaded model or vocabulary).

The similarity is a bag of visual words built on the fly: SIFT features of each photo at
:data:`THUMBNAIL_PX`, a vocabulary of :data:`WORDS` words clustered from them (k-means, seeded),
and each photo's tf-idf histogram of words (square-rooted, unit length); two photos are as similar
as the cosine of their histograms. The rules and what chose them: docs/decisions.md, "Pairs chosen
before they are matched".
"""

from __future__ import annotations

import numpy as np

EXHAUSTIVE_MAX_PHOTOS = 10
"""Up to this many photos every pair is matched (45 pairs); above, pairs are chosen."""
RETRIEVAL_NEIGHBOURS = 5
"""Each photo is paired with this many most similar photos (a pair chosen by either side counts once)."""
SEQUENTIAL_NEIGHBOURS = 3
"""The frames of a clip are also paired with this many frames after them."""
THUMBNAIL_PX = 480
"""The longer side the photos are resized to for the similarity's features."""
WORDS = 512
"""Visual words of the vocabulary (fewer when the photos have few features: 10 features a word)."""
FEATURES_PER_PHOTO = 1500
"""SIFT features a photo contributes to the similarity."""


def linked_groups(items: list, links) -> list[list]:
    """``items`` in groups joined by ``links`` (pairs of items, directly or through others), each group
    in the items' order, largest first."""
    parent = {item: item for item in items}

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in links:
        if a in parent and b in parent:
            parent[root(a)] = root(b)
    found: dict = {}
    for item in items:
        found.setdefault(root(item), []).append(item)
    return sorted(found.values(), key=len, reverse=True)


def all_pairs(n: int) -> list[tuple[int, int]]:
    """Every pair (i, j), i < j, of ``n`` photos."""
    return [(i, j) for i in range(n) for j in range(i + 1, n)]


def word_histograms(images: list[np.ndarray], seed: int = 0) -> np.ndarray:
    """[N, W] the photos' tf-idf histograms of visual words, square-rooted and of unit length
    (a photo without features: zeros). ``images``: [H, W, 3] uint8 RGB."""
    import cv2

    sift = cv2.SIFT_create(nfeatures=FEATURES_PER_PHOTO)
    descriptors = []
    for image in images:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        scale = THUMBNAIL_PX / max(gray.shape)
        if scale < 1:
            gray = cv2.resize(gray, (round(gray.shape[1] * scale), round(gray.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        _, d = sift.detectAndCompute(gray, None)
        descriptors.append(np.zeros((0, 128), np.float32) if d is None else d.astype(np.float32))
    stacked = np.concatenate(descriptors)
    words = min(WORDS, len(stacked) // 10)
    hist = np.zeros((len(images), max(words, 1)), np.float64)
    if words < 2:
        return hist
    cv2.setRNGSeed(seed)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-3)
    _, labels, _ = cv2.kmeans(stacked, words, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
    labels = labels.ravel()
    start = 0
    for k, d in enumerate(descriptors):
        np.add.at(hist[k], labels[start:start + len(d)], 1.0)
        start += len(d)
    idf = np.log(len(images) / np.maximum((hist > 0).sum(axis=0), 1))
    hist = np.sqrt(hist * idf)
    norms = np.linalg.norm(hist, axis=1, keepdims=True)
    return np.divide(hist, norms, out=np.zeros_like(hist), where=norms > 0)


def choose_pairs(images: list[np.ndarray], ordered: bool = False, neighbours: int = RETRIEVAL_NEIGHBOURS,
                 seed: int = 0) -> list[tuple[int, int]]:
    """The pairs (i, j), i < j, ascending, of ``images`` ([H, W, 3] uint8 RGB) to match: every pair up to
    :data:`EXHAUSTIVE_MAX_PHOTOS` photos; above, each photo with its ``neighbours`` most similar
    photos (:func:`word_histograms`) and, when ``ordered`` (the frames of a clip), with the
    :data:`SEQUENTIAL_NEIGHBOURS` frames after it."""
    n = len(images)
    if n <= EXHAUSTIVE_MAX_PHOTOS:
        return all_pairs(n)
    hist = word_histograms(images, seed)
    return pairs_from_similarity(hist @ hist.T, ordered, neighbours)


def pairs_from_similarity(similarity: np.ndarray, ordered: bool = False,
                          neighbours: int = RETRIEVAL_NEIGHBOURS) -> list[tuple[int, int]]:
    """The pairs of :func:`choose_pairs` from an [N, N] similarity (its diagonal ignored)."""
    n = len(similarity)
    s = similarity.astype(np.float64).copy()
    np.fill_diagonal(s, -np.inf)
    chosen = set()
    for i in range(n):
        for j in np.argsort(-s[i], kind="stable")[: min(neighbours, n - 1)]:
            chosen.add((min(i, int(j)), max(i, int(j))))
        if ordered:
            chosen.update((i, j) for j in range(i + 1, min(n, i + 1 + SEQUENTIAL_NEIGHBOURS)))
    return sorted(chosen)

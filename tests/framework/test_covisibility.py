"""The matching prior's pairs by covisibility (``matching.partners``): each training view with its
best partners by frustum overlap and axis angle, not every pair (issue 83)."""

from __future__ import annotations

import math

import pytest
import torch

from splat_framework.cameras import Camera
from splat_framework.matching.covisibility import covisibility, partner_pairs
from support import look_at


def camera(eye, target=(0.0, 0.0, 0.0), near=1.0, far=10.0) -> Camera:
    K = torch.tensor([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]])
    return Camera(K=K, world_to_cam=look_at(eye, target, (0.0, -1.0, 0.0)).float(), width=64, height=48,
                  near=near, far=far)


def test_the_score_is_frustum_overlap_times_the_axis_cosine():
    """The same camera twice scores 1; a camera that looks away, or one facing the first across the
    object (it sees the other side), scores 0; a wider baseline scores less than a narrow one."""
    a = camera((0, 0, -4))
    score = covisibility([a, camera((0, 0, -4)), camera((0, 0, -4), target=(0, 0, -8)), camera((0, 0, 4)),
                          camera((0.3, 0, -4)), camera((2.5, 0, -3.5))])
    assert score[0, 1] == pytest.approx(1.0)
    assert score[0, 2] == 0.0 and score[0, 3] == 0.0
    assert 1.0 > score[0, 4] > score[0, 5] > 0.0
    assert torch.equal(score, score.T) and torch.all(score.diagonal() == 0)


def test_each_view_takes_its_best_partners_and_few_views_take_every_pair():
    """Seven cameras on an arc round the object: with 2 partners each view is paired with its two
    neighbours on the arc (the ends with the next two), at most n * k pairs, every view in one;
    with at most k + 1 views every pair is taken."""
    cams = [camera((4 * math.sin(a), 0.0, -4 * math.cos(a))) for a in torch.linspace(-0.9, 0.9, 7).tolist()]
    ids = [10, 11, 12, 13, 14, 15, 16]
    pairs = partner_pairs(cams, ids, 2)
    assert set(pairs) >= {(10, 11), (11, 12), (12, 13), (13, 14), (14, 15), (15, 16)}
    assert (10, 16) not in pairs and len(pairs) <= 7 * 2
    assert all(a < b for a, b in pairs) and {v for p in pairs for v in p} == set(ids)
    assert partner_pairs(cams[:3], ids[:3], 2) == [(10, 11), (10, 12), (11, 12)]


def test_the_prior_matches_only_the_partner_pairs_and_says_so(capsys):
    """compute_match_set with ``partners``: the MatchSet holds exactly the chosen pairs, and one line
    says how many of all the pairs were kept."""
    from splat_framework.config import match_config
    from splat_framework.matching.prior import compute_match_set
    from splat_framework.testing import scene_and_data

    _, dm = scene_and_data("forward-tiny", views=5)
    cams = [c for c, _ in dm.train_views()]
    ids = [int(b["index"]) for _, b in dm.train_views()]
    matching = match_config("sift", cache=False, partners=2)
    found = compute_match_set(matching, dm)
    assert sorted(found.pairs()) == partner_pairs(cams, ids, 2) and len(found.pairs()) < 10
    assert f"matching: {len(found.pairs())} of the 10 pairs of training views, each view with its 2 best partners" \
        in capsys.readouterr().err


def test_every_pair_up_to_eight_views_and_three_partners_beyond_by_default():
    """``partners`` None (the default): every pair up to 8 training views (the paper's protocols, 3
    and 8 views, keep their pairs), 3 partners beyond; a number as set at any count; 0 every pair."""
    from splat_framework.config import match_config
    from splat_framework.matching.covisibility import partners_for

    assert match_config("auto").partners is None
    assert [partners_for(None, n) for n in (3, 8, 9, 21)] == [None, None, 3, 3]
    assert (partners_for(2, 5), partners_for(0, 40)) == (2, None)

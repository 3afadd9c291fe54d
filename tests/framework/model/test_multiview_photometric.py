"""Multi-view photometric consistency: a view's pixels, lifted to the rendered depth and projected
into the other training views, must find their own colour in those views' photos."""

from __future__ import annotations

import pytest
import torch

from splat_framework.cameras import Camera, intrinsics
from splat_framework.config import RunFacts, apply_overrides
from splat_framework.losses import multiview_photometric
from splat_framework.model.gaussians import GaussianModel
from splat_framework.registry import get_method

H, W, PLANE = 24, 32, 2.0
FINE = 4.0


def _camera(x: float) -> Camera:
    """A camera at (x, 0, 0) looking down +z (world = camera axes, shifted)."""
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[0, 3] = -x
    return Camera(K=intrinsics(30.0, 30.0, W / 2, H / 2).double(), world_to_cam=w2c, width=W, height=H)


def _photo(cam: Camera, fine: float = 1.0) -> torch.Tensor:
    """[H, W, 3] what ``cam`` sees of a textured plane at z = PLANE (the texture a function of world x, y,
    its frequencies times ``fine``)."""
    u = torch.arange(W, dtype=torch.float64) + 0.5
    v = torch.arange(H, dtype=torch.float64) + 0.5
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)
    p = cam.unproject_depth(uv, torch.full((H, W), PLANE, dtype=torch.float64))
    x, y = fine * p[..., 0], fine * p[..., 1]
    return torch.stack([0.5 + 0.4 * torch.sin(3 * x), 0.5 + 0.4 * torch.cos(2 * y + x), 0.5 + 0.3 * torch.sin(5 * x - y)], -1)


@pytest.mark.parametrize("downsample", [1, 2])
def test_consistency_is_least_at_the_true_depth_and_pulls_a_wrong_depth_towards_it(downsample):
    view, partners = _camera(0.0), [_camera(0.15), _camera(-0.15)]
    photo, alpha = _photo(view), torch.ones(H, W, 1, dtype=torch.float64)
    pairs = [(c, _photo(c)) for c in partners]
    at = {z: multiview_photometric(torch.full((H, W, 1), z, dtype=torch.float64), alpha, photo, view, pairs,
                                   downsample=downsample).item() for z in (1.6, 1.8, 2.0, 2.2, 2.5)}
    assert at[2.0] < 4e-3 and min(at, key=at.get) == 2.0
    assert at[1.6] > at[1.8] > at[2.0] < at[2.2] < at[2.5]
    for z, sign in ((1.8, -1.0), (2.2, 1.0)):  # too near: the loss falls with depth; too far: it rises
        depth = torch.full((H, W, 1), z, dtype=torch.float64, requires_grad=True)
        multiview_photometric(depth, alpha, photo, view, pairs, downsample=downsample).backward()
        assert sign * depth.grad.sum() > 0


def test_a_pixel_is_judged_by_the_partner_that_agrees_and_only_where_covered_and_seen():
    view, good, bad = _camera(0.0), _camera(0.15), _camera(0.15)
    photo, depth = _photo(view), torch.full((H, W, 1), PLANE, dtype=torch.float64)
    alpha = torch.ones(H, W, 1, dtype=torch.float64)
    occluded = torch.zeros(H, W, 3, dtype=torch.float64)  # the other partner, where the first is, sees something else
    both = multiview_photometric(depth, alpha, photo, view, [(good, _photo(good)), (bad, occluded)]).item()
    assert both == pytest.approx(multiview_photometric(depth, alpha, photo, view, [(good, _photo(good))]).item())
    assert multiview_photometric(depth, alpha, photo, view, [(bad, occluded)]).item() > 0.3
    # uncovered pixels do not count: a photo that differs there changes nothing
    half = alpha.clone()
    half[:, : W // 2] = 0.0
    other = photo.clone()
    other[:, : W // 2] = 1.0 - other[:, : W // 2]
    pairs = [(good, _photo(good))]
    assert multiview_photometric(depth, half, other, view, pairs).item() == pytest.approx(
        multiview_photometric(depth, half, photo, view, pairs).item())
    # a partner that sees none of it (the plane behind it) gives zero, with a graph
    behind = _camera(0.0)
    behind.world_to_cam[2, 3] = -5.0
    empty = multiview_photometric(depth.requires_grad_(), alpha, photo, view, [(behind, _photo(good))])
    assert empty.item() == 0.0 and empty.requires_grad


@pytest.mark.parametrize("downsample", [1, 2])
def test_edge_ratio_skips_the_pixels_across_an_occluding_edge_and_nothing_on_a_surface(downsample):
    view, partner = _camera(0.0), _camera(0.15)
    photo, alpha, pairs = _photo(view), torch.ones(H, W, 1, dtype=torch.float64), [(partner, _photo(partner))]
    flat = torch.full((H, W, 1), PLANE, dtype=torch.float64)
    assert multiview_photometric(flat, alpha, photo, view, pairs, downsample=downsample, edge_ratio=1.1).item() == \
        pytest.approx(multiview_photometric(flat, alpha, photo, view, pairs, downsample=downsample).item())
    step = flat.clone()
    step[:, W // 2:] = 2.0 * PLANE  # a near surface on the left, a far one on the right
    band = photo.clone()  # the photo differs only next to the step
    band[:, W // 2 - 1: W // 2 + 1] = 1.0 - band[:, W // 2 - 1: W // 2 + 1]

    def loss(img, **kw):
        return multiview_photometric(step, alpha, img, view, pairs, downsample=downsample, **kw).item()
    assert loss(band, edge_ratio=1.1) == pytest.approx(loss(photo, edge_ratio=1.1))
    assert loss(band) != pytest.approx(loss(photo))
    assert loss(photo, edge_ratio=1.1) > 0.0  # the rest of the far surface still counts


def test_the_multiview_term_compares_each_view_with_its_nearest_until_its_stop_and_reaches_the_gaussians(dm):
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 20, "model": {"reg": {"multiview_weight": 1.0, "multiview_partners": 1, "multiview_until": 0.5}, "init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    assert len(model.train_cameras) == len(model.train_images) == 3
    centres = torch.stack([c.center for c in model.train_cameras]).float()
    for k, (cam, batch) in enumerate(dm.train_views()):
        (partner, photo), = model.training_partners(k, 1)
        dist = (centres - centres[k]).norm(dim=-1)
        dist[k] = float("inf")
        assert partner is model.train_cameras[int(dist.argmin())] and photo.shape == batch["image"].shape
    assert len(model.training_partners(0, 5)) == 2 and model.training_partners(None, 2) == []
    cam, batch = next(iter(dm.train_views()))
    term = model.get_loss_dict(model.get_outputs(cam, step=9), batch, cam, 9)["multiview"]
    assert term.item() > 0
    assert "multiview" not in model.get_loss_dict(model.get_outputs(cam, step=10), batch, cam, 10)  # half the run
    term.backward()
    assert model.params["means"].grad.abs().sum() > 0
    off = apply_overrides(cfg, {"model": {"reg": {"multiview_weight": 0.0}}})
    plain = GaussianModel.from_data(off.model, RunFacts.of(off), dm, torch.Generator().manual_seed(0))
    assert "multiview" not in plain.get_loss_dict(plain.get_outputs(cam, step=5), batch, cam, 5)


def test_partners_beyond_the_angle_are_left_out_and_the_term_with_them(dm):
    """The training views' optical axes here differ by 3.4 (0-1), 5.8 (0-2) and 8.2 (1-2) degrees."""
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 20, "model": {"reg": {"multiview_weight": 1.0, "multiview_max_angle": 4.0}, "init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cams = model.train_cameras
    assert [c for c, _ in model.training_partners(0, 2, 4.0)] == [cams[1]]
    assert [c for c, _ in model.training_partners(1, 2, 4.0)] == [cams[0]]
    assert model.training_partners(2, 2, 4.0) == [] and len(model.training_partners(2, 2, 6.0)) == 1
    assert len(model.training_partners(2, 2)) == 2  # 180: any direction
    views = list(dm.train_views())
    for k, (cam, batch) in enumerate(views):
        terms = model.get_loss_dict(model.get_outputs(cam, step=1), batch, cam, 1)
        assert ("multiview" in terms) == (k != 2)
    with pytest.raises(ValueError):
        apply_overrides(cfg, {"model": {"reg": {"multiview_max_angle": 0.0}}})


def test_the_partners_are_chosen_once_per_view_not_every_step(dm, monkeypatch):
    """No per-step work (nor a host sync on CUDA) for the choice: kept until the views are replaced."""
    from splat_framework.model import gaussians
    calls = []
    real = gaussians._nearest_within
    monkeypatch.setattr(gaussians, "_nearest_within", lambda *a: calls.append(a[1:]) or real(*a))
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 20, "model": {"reg": {"multiview_weight": 1.0}, "init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cam, batch = next(iter(dm.train_views()))
    for step in range(3):
        assert "multiview" in model.get_loss_dict(model.get_outputs(cam, step=step), batch, cam, step)
    assert calls == [(0, 2, 180.0)]
    model.keep_training_views(dm)
    model.get_loss_dict(model.get_outputs(cam, step=3), batch, cam, 3)
    assert calls == [(0, 2, 180.0)] * 2


def _turned(x: float, degrees: float) -> Camera:
    """``_camera(x)`` turned by ``degrees`` about the world y axis."""
    cam = _camera(x)
    a = torch.tensor(degrees, dtype=torch.float64).deg2rad()
    R = torch.tensor([[a.cos(), 0.0, a.sin()], [0.0, 1.0, 0.0], [-a.sin(), 0.0, a.cos()]], dtype=torch.float64)
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ torch.tensor([x, 0.0, 0.0], dtype=torch.float64)
    return Camera(K=cam.K, world_to_cam=w2c, width=W, height=H)


def test_a_camera_between_two_moves_its_centre_and_turns_its_axes_in_proportion():
    a, b = _turned(0.0, 0.0), _turned(0.3, 10.0)
    b = Camera(K=b.K * 2.0, world_to_cam=b.world_to_cam, width=2 * W, height=2 * H)  # another size: the first's is kept
    assert torch.allclose(a.between(b, 0.0).world_to_cam, a.world_to_cam, atol=1e-12)
    assert torch.allclose(a.between(b, 1.0).world_to_cam, b.world_to_cam, atol=1e-12)
    mid = a.between(b, 0.25)
    assert torch.allclose(mid.center, torch.tensor([0.075, 0.0, 0.0], dtype=torch.float64), atol=1e-12)
    R = mid.world_to_cam[:3, :3]
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-12) and torch.linalg.det(R) > 0
    assert float(torch.atan2(R[0, 2], R[0, 0]).rad2deg()) == pytest.approx(2.5, abs=0.01)  # a quarter of 10 degrees
    assert (mid.width, mid.height) == (W, H) and torch.equal(mid.K, a.K)


def _plane_render(colour_gain: float = 1.0, depth: float = PLANE):
    """A stand-in for a model's render: what a camera sees of the textured plane (its colours times
    ``colour_gain``, drawn at ``depth``), at the camera's own size."""
    from splat_framework.render import RenderOutput

    def render(cam: Camera) -> RenderOutput:
        u = torch.arange(cam.width, dtype=torch.float64) + 0.5
        v = torch.arange(cam.height, dtype=torch.float64) + 0.5
        uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)
        p = cam.unproject_depth(uv, torch.full((cam.height, cam.width), PLANE, dtype=torch.float64))
        x, y = p[..., 0], p[..., 1]
        rgb = torch.stack([0.5 + 0.4 * torch.sin(3 * x), 0.5 + 0.4 * torch.cos(2 * y + x), 0.5 + 0.3 * torch.sin(5 * x - y)], -1)
        ones = torch.ones(cam.height, cam.width, 1, dtype=torch.float64)
        return RenderOutput(rgb=(rgb * colour_gain).requires_grad_(), depth=ones * depth, alpha=ones, depth_mode="expected")
    return render


@pytest.mark.parametrize("downsample", [1, 2])
def test_a_render_between_two_photos_agrees_with_them_only_with_the_scenes_depth_and_colours(downsample):
    from splat_framework.model.regularisers import pseudo_view_consistency
    home, partner = (_camera(0.0), _photo(_camera(0.0))), (_camera(0.3), _photo(_camera(0.3)))

    def loss(**kw):
        return pseudo_view_consistency(home, partner, 0.4, _plane_render(**kw), downsample=downsample).item()
    right = loss()
    assert right < 4e-3
    assert min(loss(depth=1.6), loss(depth=2.6)) > max(10 * right, 0.01)  # drawn nearer or farther
    assert loss(colour_gain=0.7) > right + 0.1  # see-through over black: darker than the photos
    rendered = []
    pseudo_view_consistency(home, partner, 0.4, lambda c: rendered.append(c) or _plane_render()(c), downsample=downsample)
    assert rendered[0].width == W // downsample and float(rendered[0].center[0]) == pytest.approx(0.12)


@pytest.mark.slow  # renders pseudo views over many steps
def test_the_pseudo_view_term_draws_its_view_per_seed_and_step_stops_and_reaches_the_gaussians(dm):
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 20, "model": {"reg": {"pseudo_view_weight": 1.0, "pseudo_view_until": 0.5}, "init": {"num_points": 2000}}})
    model = GaussianModel.from_data(cfg.model, RunFacts.of(cfg), dm, torch.Generator().manual_seed(0))
    cam, batch = next(iter(dm.train_views()))
    assert model.training_view(0)[0] is model.train_cameras[0] and model.training_view(None) is None

    def term(step):
        return model.get_loss_dict(model.get_outputs(cam, step=step), batch, cam, step).get("pseudo_view")
    first = term(3)
    assert first.item() > 0 and term(3).item() == first.item() and term(4).item() != first.item()
    assert term(10) is None  # half the run
    first.backward()
    assert model.params["means"].grad.abs().sum() > 0 and model.params["sh0"].grad.abs().sum() > 0
    narrow = apply_overrides(cfg, {"model": {"reg": {"multiview_max_angle": 4.0}}})  # view 2's nearest is 5.8 degrees away
    narrow_model = GaussianModel.from_data(narrow.model, RunFacts.of(narrow), dm, torch.Generator().manual_seed(0))
    for k, (view, b) in enumerate(dm.train_views()):
        terms = narrow_model.get_loss_dict(narrow_model.get_outputs(view, step=1), b, view, 1)
        assert ("pseudo_view" in terms) == (k != 2)


@pytest.mark.parametrize("downsample", [1, 2])
def test_patch_correlation_is_least_at_the_true_depth_ignores_exposure_and_leaves_flat_pixels_out(downsample):
    view, partners = _camera(0.0), [_camera(0.15), _camera(-0.15)]
    photo, alpha = _photo(view, FINE), torch.ones(H, W, 1, dtype=torch.float64)  # texture within a 3x3 patch
    pairs = [(c, _photo(c, FINE)) for c in partners]

    def loss(z, pairs=pairs, image=photo):
        return multiview_photometric(torch.full((H, W, 1), z, dtype=torch.float64), alpha, image, view, pairs,
                                     downsample=downsample, compare="ncc").item()
    at = {z: loss(z) for z in (1.6, 1.8, 2.0, 2.2, 2.5)}
    assert at[2.0] < 6e-3 and at[1.6] > at[1.8] > at[2.0] < at[2.2] < at[2.5]
    brighter = [(c, 0.6 * p + 0.3) for c, p in pairs]  # another exposure: the colours differ, the patterns do not
    assert loss(2.0, brighter) == pytest.approx(at[2.0], abs=2e-3)
    assert multiview_photometric(torch.full((H, W, 1), 2.0, dtype=torch.float64), alpha, photo, view, brighter,
                                 downsample=downsample).item() > 0.05
    flat = torch.full_like(photo, 0.5)  # no texture: nothing to judge a depth by, so no pixel counts
    assert loss(1.6, [(c, flat) for c, _ in pairs], flat) == 0.0


def test_the_multiview_comparison_is_chosen_by_its_flag(dm):
    cfg = apply_overrides(get_method("3dgs").default_config(), {
        "steps": 20, "model": {"reg": {"multiview_weight": 1.0}, "init": {"num_points": 2000}}})
    cam, batch = next(iter(dm.train_views()))
    terms = {}
    for compare in ("colour", "ncc"):
        variant = apply_overrides(cfg, {"model": {"reg": {"multiview_compare": compare}}})
        model = GaussianModel.from_data(variant.model, RunFacts.of(variant), dm, torch.Generator().manual_seed(0))
        terms[compare] = model.get_loss_dict(model.get_outputs(cam, step=1), batch, cam, 1)["multiview"].item()
    assert terms["colour"] > 0 and terms["ncc"] > 0 and terms["colour"] != pytest.approx(terms["ncc"])

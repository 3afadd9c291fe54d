"""splat-view: the viser viewer of a trained run serves its page, shows every Gaussian and the
cameras, renders a chosen camera with splat's rasterizer; in a real browser when Chromium is installed."""

import time
import urllib.request

import numpy as np
import pytest
import torch
from support import HeadlessPage, chromium_binary

pytestmark = pytest.mark.slow
pytest.importorskip("viser")


@pytest.fixture(scope="module")
def viewer(run_dir):
    from splat_framework.cli.view import ViewArgs, main

    v = main(ViewArgs(run_dir=run_dir, port=0, host="127.0.0.1"), serve=False)
    yield v
    v.close()


def test_viewer_serves_the_model_and_the_cameras(viewer, run_dir):
    from splat_framework.engine.run import load_run
    from splat_framework.viewer.scene_viewer import ORDINARY_RGB, splat_arrays

    with urllib.request.urlopen(viewer.url, timeout=30) as r:  # the web client ships in the viser wheel
        assert r.status == 200 and b"<html" in r.read(4096).lower()
    _, dm, model = load_run(run_dir)
    assert viewer.num_splats == model.num_gaussians
    labels = viewer._chosen.options
    assert len(labels) == len(dm.train_indices) + len(dm.test_indices) and labels[0].startswith("train/")
    arrays = splat_arrays(model)
    cov = arrays["covariances"]
    assert np.allclose(cov, cov.transpose(0, 2, 1), atol=1e-6) and (np.linalg.eigvalsh(cov) > 0).all()
    assert arrays["opacities"].shape == (model.num_gaussians, 1) and 0 <= arrays["rgbs"].min() <= arrays["rgbs"].max() <= 1
    # colour by type on a model without ray-based Gaussians: the control is hidden, colours unchanged
    assert not viewer._by_type.visible and np.allclose(splat_arrays(model, by_type=True)["rgbs"], arrays["rgbs"])
    model.params["is_ray"] = (torch.arange(model.num_gaussians) % 2).float()
    typed = splat_arrays(model, by_type=True)["rgbs"]
    del model.params["is_ray"]
    assert np.allclose(typed[0], ORDINARY_RGB) and not np.allclose(typed[1], ORDINARY_RGB)


def test_render_button_shows_splats_own_render(viewer, run_dir):
    from splat_framework.engine.run import background_for, load_run

    _, dm, model = load_run(run_dir)
    label = next(lab for lab in viewer._chosen.options if lab.startswith("test/"))
    panel = viewer.render_panel(label)
    cam, _ = dm.eval_views()[0]
    assert panel.shape == (cam.height, 3 * cam.width, 3) and panel.dtype == np.uint8
    with torch.no_grad():
        rgb = model.get_outputs(cam, background_for(dm.scene, "cpu")).rgb
    expect = (rgb.clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8)
    assert np.abs(panel[:, : cam.width].astype(int) - expect.astype(int)).max() <= 1
    assert viewer.render_panel("no/such camera") is None
    viewer.go_to(label)  # no browser connected: nothing to move, no error
    assert not viewer._frusta[label].visible and all(f.visible for k, f in viewer._frusta.items() if k != label)


@pytest.mark.skipif(chromium_binary() is None, reason="Chromium is not installed (Debian package chromium)")
def test_the_page_loads_in_headless_chromium(viewer):
    """The page's own client connects and receives the scene: its panel names the Gaussian count, the
    browser draws the splats (the view moved to a training camera is not blank)."""
    with HeadlessPage(viewer.url) as page:
        text = page.wait_for_text(f"{viewer.num_splats:,} Gaussians", timeout=90)
        assert f"{viewer.num_splats:,} Gaussians" in text and "Render with splat" in text
        empty = page.screenshot()
        viewer.go_to(viewer._chosen.options[0])  # the browser's camera jumps to a training camera
        time.sleep(3)
        shot = page.screenshot()
    assert shot.shape[2] == 3 and shot.std() > 5
    # the splats fill the middle of the view once the camera looks at them (a blank canvas does not change)
    h, w = shot.shape[:2]
    centre = (slice(h // 4, 3 * h // 4), slice(w // 8, w // 2))
    assert np.abs(shot[centre].astype(int) - empty[centre].astype(int)).mean() > 5


def test_training_viewer_follows_the_model(tmp_path):
    """splat-train --viewer: the callback opens the viewer at the first step and shows a copy of the
    model every viewer_every steps; renders from the browser never touch the training model."""
    from splat_framework.registry import get_method
    from splat_framework.engine.trainer import Trainer
    from splat_framework.viewer.scene_viewer import ViewerCallback

    cfg = get_method("3dgs").default_config()
    cfg = cfg.model_copy(update=dict(data="synthetic/forward-tiny", steps=12, output=tmp_path / "run", progress=False,
                                     model=cfg.model.model_copy(update=dict(init=cfg.model.init.model_copy(update=dict(num_points=500))))))
    live = ViewerCallback(port=0, every=5, host="127.0.0.1")
    seen = []
    trainer = Trainer(cfg, callbacks=[live, lambda t, step: seen.append((step, live.viewer.num_splats))])
    try:
        trainer.train()
        assert seen[0] == (1, 500) and live.viewer.num_splats == trainer.model.num_gaussians
        assert "(step 12)" in live.viewer._status.content
        shown = live.viewer._model
        assert shown is not trainer.model and all(
            shown.params[k] is not v and torch.equal(shown.params[k], v) for k, v in trainer.model.params.items())
        with urllib.request.urlopen(live.viewer.url, timeout=30) as r:
            assert r.status == 200
    finally:
        if live.viewer is not None:
            live.viewer.close()

"""splat-view: the viser viewer of a trained run serves its page, shows every Gaussian and the
cameras, renders a chosen camera with splat's rasterizer; in a real browser when Chromium is installed."""

import contextlib
import logging
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

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


def test_every_browser_starts_at_the_first_training_camera(viewer, run_dir):
    """A browser that connects looks through the first training camera (position, look direction, up,
    field of view), orbiting a point among the Gaussians; that camera's frustum is hidden, and no
    other frustum reaches into its view."""
    from splat_framework.engine.run import load_run
    from splat_framework.viewer.scene_viewer import FRUSTUM_DEPTH, frustum_depth, splat_arrays

    _, dm, model = load_run(run_dir)
    cam, _ = dm.train_views()[0]
    c2w = cam.cam_to_world.double().numpy()
    start = viewer.server.initial_camera
    assert np.allclose(start.position, c2w[:3, 3]) and np.allclose(start.up, -c2w[:3, 1])
    look = start.look_at - start.position
    assert np.allclose(look / np.linalg.norm(look), c2w[:3, 2])
    assert np.isclose(start.fov, 2 * np.arctan2(cam.height / 2, float(cam.K[1, 1])))
    depths = (splat_arrays(model)["centers"] - c2w[:3, 3]) @ c2w[:3, 2]
    assert np.isclose(np.linalg.norm(look), np.median(depths[depths > cam.near]))
    first = viewer._chosen.options[0]
    assert not viewer._frusta[first].visible and all(f.visible for k, f in viewer._frusta.items() if k != first)
    centers = np.stack([c.center.numpy() for c, _ in dm.train_views() + dm.eval_views()])
    gaps = np.linalg.norm(centers[:, None] - centers[None], axis=-1) + np.diag([np.inf] * len(centers))
    depth = viewer._frusta[first].scale / np.tan(start.fov / 2)  # viser's scale: the far end's half-height
    assert np.isclose(depth, 0.5 * np.median(gaps.min(1))) and frustum_depth([cam]) == FRUSTUM_DEPTH


def test_render_button_shows_splats_own_render(viewer, run_dir):
    from splat_framework.engine.run import load_run
    from splat_framework.pipeline.scene import background_for
    from splat_framework.viewer.scene_viewer import PANEL_PIXELS

    _, dm, model = load_run(run_dir)
    label = next(lab for lab in viewer._chosen.options if lab.startswith("test/"))
    panel = viewer.render_panel(label)
    cam, _ = dm.eval_views()[0]
    assert cam.width * cam.height <= PANEL_PIXELS  # a camera within the panel's pixels renders at its own size
    assert panel.shape == (cam.height, 3 * cam.width, 3) and panel.dtype == np.uint8
    with torch.no_grad():
        rgb = model.get_outputs(cam, background_for(dm.scene, "cpu")).rgb
    expect = (rgb.clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8)
    assert np.abs(panel[:, : cam.width].astype(int) - expect.astype(int)).max() <= 1
    assert viewer.render_panel("no/such camera") is None
    viewer.go_to(label)  # no browser connected: nothing to move, no error
    start = viewer._chosen.options[0]  # where browsers that connect later start: its frustum stays hidden
    assert not viewer._frusta[label].visible and not viewer._frusta[start].visible
    assert all(f.visible for k, f in viewer._frusta.items() if k not in (label, start))


def test_a_large_camera_renders_the_panel_within_its_pixels(viewer, monkeypatch):
    """A camera larger than PANEL_PIXELS renders scaled down (aspect kept), compared against its photo
    resized alike; a smaller one is never scaled up."""
    from splat_framework.evaluation.pictures import error_map
    from splat_framework.viewer import scene_viewer

    label = viewer._chosen.options[0]
    cam, photo = viewer._cameras[label]
    monkeypatch.setattr(scene_viewer, "PANEL_PIXELS", cam.width * cam.height // 4)
    small = scene_viewer.panel_camera(cam)
    assert (small.width, small.height) == (cam.width // 2, cam.height // 2)
    assert torch.allclose(small.K[:2], cam.K[:2] / 2) and scene_viewer.panel_camera(small) is small
    panel = viewer.render_panel(label)
    assert panel.shape == (small.height, 3 * small.width, 3)
    assert f"{small.width}x{small.height}" in viewer._image.label
    halved = photo.reshape(small.height, 2, small.width, 2, 3).mean((1, 3))
    with torch.no_grad():
        rgb = viewer._model.get_outputs(small, viewer._background).rgb.clamp(0, 1)
    assert np.abs(panel[:, 2 * small.width:].astype(int) - error_map(rgb, halved).astype(int)).max() <= 1


def test_render_with_splat_says_it_is_busy(viewer, monkeypatch):
    """While "Render with splat" works its button is disabled and reads "Rendering…"; it comes back
    when the render is done, and after a render that failed."""
    from splat_framework.viewer.scene_viewer import BUSY_LABEL, RENDER_LABEL

    seen, render = [], viewer.render_panel

    def watched(label):
        seen.append((viewer._render.disabled, viewer._render.label))
        if len(seen) == 2:
            raise RuntimeError("a render that fails")
        return render(label)

    monkeypatch.setattr(viewer, "render_panel", watched)
    assert viewer.render_chosen() is not None
    assert (viewer._render.disabled, viewer._render.label) == (False, RENDER_LABEL)
    with pytest.raises(RuntimeError):
        viewer.render_chosen()
    assert seen == [(True, BUSY_LABEL)] * 2 and (viewer._render.disabled, viewer._render.label) == (False, RENDER_LABEL)


@contextlib.contextmanager
def _open_page(viewer):
    """A websocket client doing what the viewer's page does when a browser opens it: connect as its own
    client (viser's subprotocol, the viewer's Origin) and report its camera (the start view), after
    which viser counts it as a connected client."""
    import msgspec
    import viser
    from websockets.sync.client import connect

    start = viewer.server.initial_camera
    camera = {"type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": list(map(float, start.position)),
              "fov": float(start.fov), "near": 0.01, "far": 1000.0, "image_height": 480, "image_width": 640,
              "look_at": list(map(float, start.look_at)), "up_direction": list(map(float, start.up))}
    with connect(f"ws://127.0.0.1:{viewer.port}", subprotocols=[f"viser-v{viser.__version__}"],
                 origin=f"http://127.0.0.1:{viewer.port}", max_size=None, open_timeout=30) as ws:
        ws.send(msgspec.msgpack.encode(camera))
        yield ws


def test_a_page_that_opens_finds_the_panel_rendered(run_dir, monkeypatch):
    """Issue 107: the panel is not an empty strip until "Render with splat" is pressed: a page that
    connects gets the chosen camera's render (the first training camera's, where browsers start), as
    the button makes it; a second page finds it there (no render again), a new model (the training
    viewer's next copy) is rendered for the next page that opens."""
    from splat_framework.cli.view import ViewArgs, main

    v = main(ViewArgs(run_dir=run_dir, port=0, host="127.0.0.1"), serve=False)
    try:
        assert v._image.image.shape == (8, 24, 3)  # the placeholder: no page has opened yet
        renders, render = [], v.render_panel
        monkeypatch.setattr(v, "render_panel", lambda label: renders.append(label) or render(label))

        def page_opens(count: int) -> None:
            with _open_page(v):
                deadline = time.time() + 60
                while len(renders) < count or v._render.disabled:  # rendered in viser's thread pool
                    assert time.time() < deadline, renders
                    time.sleep(0.05)
                time.sleep(0.3)  # a render that should not happen would have started by now

        first = v._chosen.options[0]
        page_opens(1)
        assert renders == [first] and first.startswith("train/"), renders
        camera, _ = v._cameras[first]
        assert v._image.image.shape == (camera.height, 3 * camera.width, 3) and first in v._image.label
        assert np.array_equal(v._image.image, render(first))  # the picture the button would show
        page_opens(1)
        assert renders == [first]  # the second page finds it rendered
        v.set_model(v._model, v._background, note="(step 20)", snapshot=True)
        page_opens(2)
        assert renders == [first, first]
    finally:
        v.close()


@pytest.mark.skipif(chromium_binary() is None,
                    reason="Chromium is not installed (Debian: apt-get install -y chromium); the browser test needs it")
def test_the_first_frame_shows_the_scene_in_headless_chromium(viewer):
    """A browser opening http://127.0.0.1:PORT (a loopback page the client guard accepts) draws the scene
    from the first training camera before anything is clicked: the page's own client connects and
    receives the model (its panel names the Gaussian count) and splat's own render of that camera in
    the side panel, the canvas is covered by splats, and it is the picture splat's rasterizer renders
    at that camera (over the page's white background)."""
    camera, _ = viewer._cameras[viewer._chosen.options[0]]
    big = camera.scaled(4)  # the viewport has the camera's aspect: the canvas is the camera's picture
    with torch.no_grad():
        expect = viewer._model.get_outputs(big, torch.ones(3)).rgb.clamp(0, 1).numpy()
    with HeadlessPage(f"http://127.0.0.1:{viewer.port}", size=(big.width, big.height)) as page:
        page.wait_for_text(f"{viewer.num_splats:,} Gaussians", timeout=60)
        # the panel holds splat's own render of the camera the page starts at, with no click (issue 107),
        # and the button, which read "Rendering…" meanwhile, is back
        page.wait_for_text(f"splat render of {viewer._chosen.options[0]}", timeout=60)
        text = page.wait_for_text("Render with splat", timeout=60)
        assert f"{viewer.num_splats:,} Gaussians" in text and f"splat render of {viewer._chosen.options[0]}" in text
        page.only_canvases()
        deadline, shot = time.time() + 30, None
        while True:  # the splats are sorted in a web worker and fade in: wait for two equal frames
            last, shot = shot, page.screenshot()[..., ::-1] / 255.0
            if last is not None and np.abs(shot - last).mean() < 0.005 or time.time() > deadline:
                break
            time.sleep(0.5)
    drawn = (np.abs(shot - 1).max(-1) > 0.06).mean()  # not the page's white background
    assert shot.shape[:2] == expect.shape[:2] and drawn > 0.5
    assert np.corrcoef(shot.mean(-1).ravel(), expect.mean(-1).ravel())[0, 1] > 0.5


def _serving_page(html: str) -> ThreadingHTTPServer:
    """A server on a free port of 127.0.0.1 answering every GET with the page ``html`` (another local
    site, to a browser); stopped with ``shutdown()``."""

    class Page(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            body = html.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


@pytest.mark.skipif(chromium_binary() is None,
                    reason="Chromium is not installed (Debian: apt-get install -y chromium); the browser test needs it")
@pytest.mark.bad_input("a web page of another site (foreign Origin) or a DNS-rebinding name (foreign Host) reaching the local viewer", "403 for the websocket and every HTTP request; nothing served")
def test_a_page_of_another_local_port_cannot_open_the_viewers_socket_in_headless_chromium(viewer, caplog):
    """A page served from another port of this machine (another web site, to the browser) opens a
    websocket to the viewer as viser's own client does: the handshake is refused (403: the socket
    never opens, the browser reports 1006), and the viewer logged the refusal of that page's Origin."""
    import viser

    caplog.set_level(logging.DEBUG, logger="splat_framework.viewer.viser_clients")
    page = _serving_page(f"""<!doctype html><body>tried:<script>
        const ws = new WebSocket("ws://127.0.0.1:{viewer.port}", "viser-v{viser.__version__}");
        ws.onopen = () => document.body.append(" socket opened");
        ws.onclose = (e) => document.body.append(` socket closed ${{e.code}}`);
        </script></body>""")
    try:
        origin = f"http://127.0.0.1:{page.server_address[1]}"
        with HeadlessPage(f"{origin}/") as browser:
            text = browser.wait_for_text("socket closed", timeout=60)
    finally:
        page.shutdown()
    assert "socket closed 1006" in text and "opened" not in text, text
    assert any(f"Origin [{origin!r}]" in r.getMessage() for r in caplog.records), [r.getMessage() for r in caplog.records]


def test_training_viewer_follows_the_model(tmp_path):
    """splat-train --viewer: the callback opens the viewer at the first step and shows a copy of the
    model every viewer_every steps; renders from the browser never touch the training model."""
    from splat_framework.engine.trainer import Trainer
    from splat_framework.registry import get_method
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
        # browsers start at the first training camera, orbiting a point among the Gaussians shown at step 1
        cam, _ = trainer.datamanager.train_views()[0]
        start = live.viewer.server.initial_camera
        assert np.allclose(start.position, cam.center.numpy(), atol=1e-5) and live.viewer._start_pivoted
        shown = live.viewer._model
        assert shown is not trainer.model and all(
            shown.params[k] is not v and torch.equal(shown.params[k], v) for k, v in trainer.model.params.items())
        with urllib.request.urlopen(live.viewer.url, timeout=30) as r:
            assert r.status == 200
    finally:
        if live.viewer is not None:
            live.viewer.close()

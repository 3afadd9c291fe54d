"""A local web viewer of a trained (or training) model, on viser.

The browser draws the Gaussians itself (viser's WebGL splat renderer, through
``add_gaussian_splats``), so looking around is interactive even though this
project's CPU rasterizer is slow. Beside it:

- the training cameras as frusta with their photos, the test cameras as frusta
  (half as deep as the cameras are apart);
- every browser that connects starts at the first training camera (its position,
  look direction, up and field of view; viser's "Reset View" returns there), so the
  first frame shows the scene;
- "Go to camera": moves every connected browser to a dataset camera;
- "Render with splat": this project's rasterizer renders the chosen camera
  (RGB | depth | |error| against its photo) into the side panel, so the
  browser's splats and the real renderer can be compared at the same pose; the
  camera is scaled down to :data:`PANEL_PIXELS` pixels, and the button reads
  "Rendering…" (disabled) until the render is done. A page that opens finds the
  panel holding the chosen camera's render of the model shown (the first training
  camera's, where the browser starts): rendered when the page connects, unless the
  panel already shows it;
- "Colour by type" (models with ray-based Gaussians, SCGaussian): ray-based
  Gaussians orange, ordinary ones blue: the picture of the paper's claim.

Cameras are OpenCV-convention in both this project and viser (x right, y down,
z forward), so poses pass through unchanged.

Where it listens (127.0.0.1 unless a host is given, a free port, the true URL) is
:mod:`splat_framework.viewer.serving`'s; what its clients may do (no page of another web site nor a
DNS-rebinding name: 403 for the page and the websocket; no traceback from a malformed message, no share
tunnel) is :mod:`splat_framework.viewer.viser_clients`'.
"""

from __future__ import annotations

import contextlib
import copy
import io
import math
import threading
import warnings
from pathlib import Path

import numpy as np
import torch

from .serving import LOOPBACK, InvalidAddress, ServingWarning, check_port, exposure_warning, free_port, server_url
from .viser_clients import from_client, guard_clients, start_checked

__all__ = ["Viewer", "frustum_depth", "panel_camera", "splat_arrays"]

RAY_RGB = (1.0, 0.55, 0.1)
ORDINARY_RGB = (0.2, 0.45, 1.0)
THUMBNAIL_PX = 160
"""Longest side of the photos drawn in the camera frusta."""
FRUSTUM_DEPTH = 0.1
"""Depth (world units) of a frustum drawn alone (see :func:`frustum_depth`)."""
FRUSTUM_LINE = 0.03
"""Thickness of a frustum's lines, a fraction of its depth."""
PANEL_PIXELS = 256 * 192
"""Most pixels of one image of the "Render with splat" panel: a larger camera is rendered scaled down
to this many (the CPU rasterizer's time grows with the pixels; see :func:`panel_camera`)."""
RENDER_LABEL, BUSY_LABEL = "Render with splat", "Rendering…"


@torch.no_grad()
def splat_arrays(model, by_type: bool = False) -> dict[str, np.ndarray]:
    """What viser's splat renderer takes, from the model's standard Gaussians
    (:meth:`~splat_framework.model.gaussians.GaussianModel.export_gaussians`: the
    PLY exporter's; for a model that decodes its Gaussians per view, such as the
    anchor methods, those of its reference view).

    Returns float32 arrays: centers [N, 3], covariances [N, 3, 3] (R S^2 R^T),
    rgbs [N, 3] (degree-0 colour, or the type colours with ``by_type``), opacities [N, 1].
    """
    from ..render import quat_to_rotmat, sh_to_rgb

    g = model.export_gaussians()
    R = quat_to_rotmat(g["quats"].float())
    s = torch.exp(g["scales"].float())
    cov = R @ torch.diag_embed(s * s) @ R.transpose(-1, -2)
    rgb = sh_to_rgb(g["sh0"].float().reshape(-1, 3)).clamp(0, 1)
    if by_type and _has_types(model):
        ray = model.params["is_ray"].reshape(-1, 1) > 0.5
        rgb = torch.where(ray, rgb.new_tensor(RAY_RGB), rgb.new_tensor(ORDINARY_RGB))
    return {
        "centers": g["means"].float().cpu().numpy(),
        "covariances": cov.cpu().numpy(),
        "rgbs": rgb.cpu().numpy(),
        "opacities": torch.sigmoid(g["opacities"].float()).reshape(-1, 1).cpu().numpy(),
    }


def _has_types(model) -> bool:
    """Whether the model flags its rows as ray-based or ordinary (SCGaussian's ``is_ray``)."""
    return "is_ray" in model.params


def _pose(camera) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz [4], position [3]) of a camera's camera-to-world transform."""
    import viser.transforms as vtf

    c2w = camera.cam_to_world.double().cpu().numpy()
    return vtf.SO3.from_matrix(c2w[:3, :3]).wxyz, c2w[:3, 3]


def _fov_y(camera) -> float:
    return float(2 * np.arctan2(camera.height / 2, float(camera.K[1, 1])))


def _start_view(camera, centers: np.ndarray | None) -> dict[str, np.ndarray | float]:
    """Where a browser's camera starts to look through ``camera``: position [3], look_at [3] (the
    point it orbits: at the median depth of the ``centers`` [N, 3] in front of it, else midway between
    its near and far planes), up [3] (the image's up, -y in OpenCV) and fov (vertical, radians)."""
    import viser.transforms as vtf

    wxyz, position = _pose(camera)
    R = vtf.SO3(wxyz).as_matrix()
    depth = 0.5 * (camera.near + camera.far)
    if centers is not None and len(centers):
        z = (centers - position) @ R[:, 2]
        ahead = z[z > camera.near]
        if len(ahead):
            depth = float(np.median(ahead))
    return {"position": position, "look_at": position + depth * R[:, 2], "up": -R[:, 1], "fov": _fov_y(camera)}


def frustum_depth(cameras) -> float:
    """How deep (world units) the cameras' frusta are drawn: half the median distance from a camera
    to its nearest neighbour (:data:`FRUSTUM_DEPTH` without two distinct cameras), so that from any
    camera its neighbours' frusta stay out of view instead of covering the scene."""
    if len(cameras) < 2:
        return FRUSTUM_DEPTH
    centers = np.stack([camera.center.double().cpu().numpy() for camera in cameras])
    gaps = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    np.fill_diagonal(gaps, np.inf)
    nearest = gaps.min(axis=1)
    nearest = nearest[nearest > 0]
    return 0.5 * float(np.median(nearest)) if len(nearest) else FRUSTUM_DEPTH


def panel_camera(camera):
    """``camera`` as "Render with splat" renders it: scaled down (never up, aspect kept) to at most
    :data:`PANEL_PIXELS` pixels."""
    factor = math.sqrt(PANEL_PIXELS / (camera.width * camera.height))
    return camera if factor >= 1 else camera.scaled(factor)


def _thumbnail(image: torch.Tensor) -> np.ndarray:
    import cv2

    from ..evaluation.pictures import to_uint8

    img = to_uint8(image)
    f = THUMBNAIL_PX / max(img.shape[:2])
    return cv2.resize(img, (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f))), interpolation=cv2.INTER_AREA)


STARTUP_S = 60.0
"""How long a viewer may take to start listening before the command gives up on it."""


def _start_server(host: str, port: int, timeout: float | None = None):
    """A ``viser.ViserServer`` listening on ``host``:``port``, or :class:`InvalidAddress` when it has
    not started within ``timeout`` seconds (default :data:`STARTUP_S`): viser's constructor waits,
    without a timeout, for a server thread that may have died (then the command never ended).
    Viser's banner is swallowed (its URL says localhost whatever the host; ours is :attr:`Viewer.url`).
    Every request it answers is checked first (:func:`~splat_framework.viewer.viser_clients.start_checked`):
    pages of other web sites and DNS-rebinding names get 403."""
    import viser

    started: dict = {}

    def start() -> None:
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                started["server"] = start_checked(lambda: viser.ViserServer(host=host, port=port, verbose=False), host)
        except BaseException as e:  # noqa: BLE001 - re-raised in the caller's thread
            started["error"] = e

    thread = threading.Thread(target=start, name="viewer-start", daemon=True)
    thread.start()
    thread.join(STARTUP_S if timeout is None else timeout)
    if "error" in started:
        raise started["error"]
    if "server" not in started:
        raise InvalidAddress(f"the viewer did not start listening on {host} port {port} "
                             f"within {STARTUP_S if timeout is None else timeout:.0f} s")
    return started["server"]


class Viewer:
    """A viser server showing one model and a dataset's cameras.

    Args:
        port: TCP port, 0..65535 (0 = any free one); a port in use: the next free one, said in a
            :class:`~splat_framework.viewer.serving.ServingWarning`. The port served is :attr:`port`, the URL :attr:`url`.
        host: interface to listen on: 127.0.0.1 (this machine only) by default; any other address
            (0.0.0.0: every interface) brings a ServingWarning naming what becomes reachable.
    """

    def __init__(self, port: int = 8080, host: str = LOOPBACK) -> None:
        chosen = free_port(host, port)  # a bad port or host: one-line InvalidAddress here, never a dead server thread
        self.server = _start_server(host, chosen)
        self.host, self.port = host, self.server.get_port()
        if port and self.port != port:
            warnings.warn(f"port {port} is in use; serving on {self.port}", ServingWarning, stacklevel=2)
        exposed = exposure_warning(host, self.port)
        if exposed:
            warnings.warn(exposed, ServingWarning, stacklevel=2)
        guard_clients(self.server)
        self._lock = threading.Lock()  # the model is read by viser's GUI thread and written by training
        self._model = None
        self._background = None
        self._cameras: dict[str, tuple] = {}  # label -> (camera, photo [H, W, 3] or None)
        self._frusta: dict[str, object] = {}  # label -> viser frustum handle
        self._centers: np.ndarray | None = None  # [N, 3] of the Gaussians shown
        self._start_label: str | None = None  # the camera browsers start at
        self._start_pivoted = False  # whether its orbit point came from the model's Gaussians
        self.num_splats = 0
        gui = self.server.gui
        self._by_type = gui.add_checkbox("Colour by type", initial_value=False, hint="ray-based orange, ordinary blue")
        self._by_type.on_update(from_client(lambda _: self._draw_splats()))
        self._status = gui.add_markdown("")
        self._chosen = gui.add_dropdown("Camera", ["(none)"])
        goto = gui.add_button("Go to camera")
        goto.on_click(from_client(lambda _: self.go_to(self._chosen.value)))
        self._render = gui.add_button(RENDER_LABEL)
        self._render.on_click(from_client(lambda _: self.render_chosen()))
        self._image = gui.add_image(np.zeros((8, 24, 3), np.uint8), label="splat render: RGB | depth | |error|")
        self._model_version = 0  # counts the models shown (set_model)
        self._panel_shows: tuple[int, str] | None = None  # (model version, camera label) of the panel; None: placeholder
        self._panel_busy = threading.Lock()  # one render of the panel at a time
        self.server.on_client_connect(from_client(lambda _: self.page_opened()))  # in viser's thread pool

    @property
    def url(self) -> str:
        """The address a browser opens (localhost on 127.0.0.1, the host given otherwise)."""
        return server_url(self.host, self.port)

    # ----------------------------------------------------------------- scene
    def set_model(self, model, background: torch.Tensor, note: str = "", snapshot: bool = False) -> None:
        """Show ``model`` (replacing the previous one); ``note`` goes in the panel (e.g. the step).

        ``snapshot``: keep a copy of its parameters (a model that goes on training), so that
        renders asked for from the browser never see it half-way through a step."""
        if snapshot:
            with torch.no_grad():
                model = copy.deepcopy(model)
        with self._lock:
            self._model, self._background = model, background
            self._model_version += 1
        has_types = _has_types(model)
        self._by_type.visible = has_types
        self._draw_splats()
        self._status.content = f"**{self.num_splats:,} Gaussians** {note}".strip()
        if not self._start_pivoted:
            self._set_start_view()

    def _draw_splats(self) -> None:
        with self._lock:
            if self._model is None:
                return
            arrays = splat_arrays(self._model, by_type=bool(self._by_type.value))
        self.server.scene.add_gaussian_splats("/gaussians", **arrays)
        self._centers = arrays["centers"]
        self.num_splats = int(arrays["centers"].shape[0])

    def set_cameras(self, views, kind: str, color: tuple[int, int, int], depth: float = FRUSTUM_DEPTH) -> None:
        """Frusta for ``views`` (a list of (camera, batch) pairs), named ``kind``/``view``, ``depth``
        world units deep; training frusta carry their photo."""
        for camera, batch in views:
            label = f"{kind}/{camera.name or batch['index']}"
            photo = batch.get("image")
            wxyz, position = _pose(camera)
            self._frusta[label] = self.server.scene.add_camera_frustum(  # viser's scale: the far end's half-height
                f"/cameras/{label}", fov=_fov_y(camera), aspect=camera.width / camera.height,
                scale=depth * math.tan(_fov_y(camera) / 2), thickness=FRUSTUM_LINE * depth,
                color=color, wxyz=wxyz, position=position,
                image=_thumbnail(photo) if kind == "train" and photo is not None else None,
            )
            self._cameras[label] = (camera, photo)
        self._chosen.options = tuple(self._cameras)
        self._chosen.value = next(iter(self._cameras))
        if self._start_label is None and kind == "train" and views:
            self._start_label = self._chosen.value
            self._set_start_view()

    def _set_start_view(self) -> None:
        """Every browser that connects from now on starts looking through the first training camera
        (viser's initial camera, to which "Reset View" also returns; the scene's up is that camera's),
        whose frustum, which would cover the view with its photo, is hidden as by :meth:`go_to`."""
        if self._start_label is None:
            return
        camera, _ = self._cameras[self._start_label]
        view = _start_view(camera, self._centers)
        self._start_pivoted = self._centers is not None
        self.server.scene.set_up_direction(view["up"])
        start = self.server.initial_camera
        start.fov, start.position, start.look_at, start.up = view["fov"], view["position"], view["look_at"], view["up"]
        self._show_frusta_but(self._start_label)

    def set_dataset(self, datamanager) -> None:
        """The training cameras (orange, with their photos) and the test cameras (blue), their frusta
        as deep as :func:`frustum_depth` says."""
        train, test = datamanager.train_views(), datamanager.eval_views()
        depth = frustum_depth([camera for camera, _ in train + test])
        self.set_cameras(train, "train", (230, 120, 20), depth)
        self.set_cameras(test, "test", (40, 90, 230), depth)

    # ------------------------------------------------------------- controls
    def go_to(self, label: str) -> None:
        """Move every connected browser's view to dataset camera ``label`` (whose own frustum, which
        would cover the view with its photo, is hidden until another camera is chosen; so is always
        that of the first training camera, where browsers that connect later start)."""
        if label not in self._cameras:
            return
        self._show_frusta_but(label)
        camera, _ = self._cameras[label]
        wxyz, position = _pose(camera)
        for client in self.server.get_clients().values():
            with client.atomic():
                client.camera.fov = _fov_y(camera)
                client.camera.wxyz = wxyz
                client.camera.position = position

    def _show_frusta_but(self, label: str) -> None:
        """Hide the frustum of camera ``label`` and that of the camera browsers start at, show the others."""
        for other, frustum in self._frusta.items():
            frustum.visible = other not in (label, self._start_label)

    def render_chosen(self) -> np.ndarray | None:
        """"Render with splat": :meth:`render_panel` of the camera chosen in the dropdown, the button
        disabled and reading "Rendering…" until it is done (or has failed)."""
        self._render.disabled, self._render.label = True, BUSY_LABEL
        try:
            return self.render_panel(self._chosen.value)
        finally:
            self._render.disabled, self._render.label = False, RENDER_LABEL

    def page_opened(self) -> np.ndarray | None:
        """A browser connected: the panel gets the chosen camera's render of the model shown (as
        "Render with splat" makes it), unless it already holds that render or one is under way (a
        second page opening meanwhile), so that no page opens on an empty panel. The new panel, or
        None when nothing was rendered (no model yet: the training viewer before its first step)."""
        with self._lock:
            shown = self._model_version if self._model is not None else None
        if shown is None or self._panel_shows == (shown, self._chosen.value):
            return None
        if not self._panel_busy.acquire(blocking=False):
            return None
        try:
            return self.render_chosen()
        finally:
            self._panel_busy.release()

    @torch.no_grad()
    def render_panel(self, label: str) -> np.ndarray | None:
        """Render dataset camera ``label``, scaled down by :func:`panel_camera`, with this project's
        rasterizer into the side panel: [h, w*3, 3] uint8 (RGB | depth | |error| against the photo,
        or the RGB again without one)."""
        from ..data.datamanager import area_resized
        from ..evaluation.pictures import colorize_depth, error_map, to_uint8

        if label not in self._cameras:
            return None
        camera, photo = self._cameras[label]
        camera = panel_camera(camera)
        with self._lock:
            model, bg = self._model, self._background
            if model is None:
                return None
            version = self._model_version
            out = model.get_outputs(camera.to(bg.device), bg)
        rgb = out.rgb.clamp(0, 1)
        depth = colorize_depth(out.expected_depth, out.alpha)
        if photo is not None:
            err = error_map(rgb, area_resized(photo, camera.width, camera.height).to(rgb.device))
        else:
            err = to_uint8(rgb)
        panel = np.concatenate([to_uint8(rgb), depth, err], axis=1)
        self._image.image = panel
        self._image.label = f"splat render of {label}, {camera.width}x{camera.height}: RGB | depth | |error|"
        self._panel_shows = (version, label)
        return panel

    def close(self) -> None:
        self.server.stop()

    def serve_until_interrupted(self) -> None:
        """Keep serving until Ctrl-C, then stop the server."""
        try:
            self.server.sleep_forever()
        except KeyboardInterrupt:
            pass
        finally:
            self.close()


def view_run(run_dir: Path, port: int = 8080, host: str = LOOPBACK, device: str | None = None,
             trust_edits: bool = False) -> Viewer:
    """A :class:`Viewer` of a trained run: its newest checkpoint, training and test cameras."""
    from ..engine.run import load_run
    from ..pipeline.scene import background_for

    config, dm, model = load_run(run_dir, device, trust_edits)
    viewer = Viewer(port=port, host=host)
    viewer.set_model(model, background_for(dm.scene, config.device), note=f"({config.method}, {Path(run_dir).name})")
    viewer.set_dataset(dm)
    return viewer


class ViewerCallback:
    """A training callback (``trainer.train(config, callbacks)``) that opens a :class:`Viewer` at the
    first step and shows the model every ``every`` steps (a copy of its parameters: sending ~30k
    Gaussians costs milliseconds, about nothing against a training step).

    A port or host it could not listen on raises :class:`~splat_framework.viewer.serving.InvalidAddress`
    here, before training starts (and before anything is written)."""

    def __init__(self, port: int = 8080, every: int = 100, host: str = LOOPBACK) -> None:
        check_port(port)
        free_port(host, 0)  # the host is this machine's (any port: the one asked for may be free by step 1)
        self.port, self.every, self.host = port, max(int(every), 1), host
        self.viewer: Viewer | None = None

    def __call__(self, trainer, step: int) -> None:
        if self.viewer is None:
            self.viewer = Viewer(port=self.port, host=self.host)
            self.viewer.set_dataset(trainer.datamanager)
            print(f"viewer at {self.viewer.url}", flush=True)
        if step % self.every == 0 or step == trainer.config.total_steps or self.viewer.num_splats == 0:
            self.viewer.set_model(trainer.model, trainer.background, note=f"(step {step})", snapshot=True)

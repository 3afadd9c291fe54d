"""Test support: the repository and real-data locations, and writers of tiny datasets in each layout.

Importable from every test folder (``pythonpath = ["tests"]`` in pyproject.toml).
The ``make_*`` builders write LLFF, Blender, DTU and COLMAP folders into a temporary
path, with cameras whose geometry the parser tests check.
"""

from __future__ import annotations

import json
import math
import os
import struct
from pathlib import Path

import cv2
import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
"""The repository root."""
DATA = Path(os.environ.get("SPLAT_DATA") or REPO.parent / "shared" / "data")
"""Real scenes ($SPLAT_DATA, else ../shared/data beside the repository); tests that need them skip without them."""



def look_at(eye, target, up) -> torch.Tensor:
    """[4, 4] float64 OpenCV world-to-camera with ``up`` appearing upwards in the image.

    (Local on purpose: the tests must not share a bug with the code under test.)
    """
    eye, target, up = (torch.as_tensor(a, dtype=torch.float64) for a in (eye, target, up))
    fwd = (target - eye) / (target - eye).norm()
    right = torch.linalg.cross(fwd, up)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    R = torch.stack([right, down, fwd])
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def write_png(path: Path, w: int, h: int, *, seed: int = 0, rgba: bool = False) -> np.ndarray:
    """Write a random 8-bit PNG; returns the array as stored (BGR[A])."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    arr = rng.integers(0, 256, size=(h, w, 4 if rgba else 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), arr)
    return arr


def llff_row(R_cv: np.ndarray, center, H: float, W: float, focal: float, near: float, far: float) -> np.ndarray:
    """One poses_bounds row from an OpenCV camera-to-world rotation."""
    right, down, fwd = R_cv[:, 0], R_cv[:, 1], R_cv[:, 2]
    m = np.zeros((3, 5))
    m[:, 0], m[:, 1], m[:, 2] = down, right, -fwd
    m[:, 3] = center
    m[:, 4] = [H, W, focal]
    return np.concatenate([m.reshape(-1), [near, far]])


def make_llff(
    root: Path,
    n: int = 10,
    *,
    w: int = 16,
    h: int = 12,
    full_factor: int = 8,
    folder: str = "images_8",
    focal_full: float = 100.0,
    depths: bool = False,
) -> Path:
    """Forward-facing LLFF scene: cameras on a line at z=0 looking down +z."""
    rows = []
    for i in range(n):
        rows.append(
            llff_row(np.eye(3), [0.1 * i, 0.0, 0.0], h * full_factor, w * full_factor, focal_full, 1.0 + 0.1 * i, 10.0)
        )
        write_png(root / folder / f"img{i:03d}.png", w, h, seed=i)
        if depths:
            (root / "depths").mkdir(parents=True, exist_ok=True)
            np.save(root / "depths" / f"img{i:03d}.npy", np.full((h, w), 5.0, np.float32))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return root


def gl_c2w_looking_at_origin(eye) -> np.ndarray:
    w2c_cv = look_at(torch.tensor(eye, dtype=torch.float64), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0]))
    c2w_cv = torch.linalg.inv(w2c_cv).numpy()
    return c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV -> OpenGL (its own inverse)


def make_blender(root: Path, n_train: int = 10, n_test: int = 16, *, size: int = 8, angle: float = 0.7,
                 n_val: int = 0) -> Path:
    """A Blender scene of ``n_train`` / ``n_test`` / ``n_val`` frames on a circle (no val file when 0)."""
    root.mkdir(parents=True, exist_ok=True)
    for split, n in (("train", n_train), ("test", n_test), ("val", n_val)):
        if n == 0:
            continue
        frames = []
        for i in range(n):
            a = 2 * math.pi * i / n + (0.1 if split == "test" else 0.0)
            eye = [4.0 * math.cos(a), 4.0 * math.sin(a), 1.0]
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": gl_c2w_looking_at_origin(eye).tolist()})
            write_png(root / split / f"r_{i}.png", size, size, seed=i, rgba=True)
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))
    return root


DTU_K = np.array([[2800.0, 0.0, 799.5], [0.0, 2790.0, 599.5], [0.0, 0.0, 1.0]])
DTU_SCALE = np.array([[200.0, 0, 0, 10.0], [0, 200.0, 0, -20.0], [0, 0, 200.0, 600.0], [0, 0, 0, 1]])


def dtu_eye(i: int) -> np.ndarray:
    a = 2 * math.pi * i / 49
    return np.array([3.0 * math.cos(a), 3.0 * math.sin(a), -1.0 - 0.01 * i])


def make_dtu(root: Path, n: int = 49, *, w: int = 16, h: int = 12, masks: bool = True) -> Path:
    """DTU layout whose normalised-space cameras look at the origin from ``dtu_eye(i)``."""
    mats = {}
    for i in range(n):
        w2c = look_at(torch.tensor(dtu_eye(i)), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0])).numpy()
        # world_mat @ scale_mat = K [R|t] (normalised) -> world_mat = K[R|t] @ inv(scale_mat)
        P = DTU_K @ w2c[:3]
        world = np.eye(4)
        world[:3] = P @ np.linalg.inv(DTU_SCALE)
        mats[f"world_mat_{i}"] = world * 3.7  # projective scale must not matter
        mats[f"scale_mat_{i}"] = DTU_SCALE
        write_png(root / "images_4" / f"{i:06d}.png", w, h, seed=i)
        if masks:
            m = np.zeros((h, w, 3), np.uint8)
            m[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4] = 255
            (root / "mask_4").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / "mask_4" / f"{i:03d}.png"), m)
    np.savez(root / "cameras_sphere.npz", **mats)
    return root


def _qvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> COLMAP (w, x, y, z) quaternion (no scipy needed)."""
    K = np.array(
        [
            [R[0, 0] - R[1, 1] - R[2, 2], 0, 0, 0],
            [R[1, 0] + R[0, 1], R[1, 1] - R[0, 0] - R[2, 2], 0, 0],
            [R[2, 0] + R[0, 2], R[2, 1] + R[1, 2], R[2, 2] - R[0, 0] - R[1, 1], 0],
            [R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], R[0, 0] + R[1, 1] + R[2, 2]],
        ]
    ) / 3.0
    vals, vecs = np.linalg.eigh(K)
    q = vecs[[3, 0, 1, 2], np.argmax(vals)]
    return -q if q[0] < 0 else q


COLMAP_MODELS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4, "FOV": 7}


def colmap_scene(n_images: int = 9, n_points: int = 200, seed: int = 0):
    """Cameras on a line looking down +z at random points with z in [4, 8]."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-1, 1, n_points), rng.uniform(-1, 1, n_points), rng.uniform(4, 8, n_points)])
    images = []
    for i in range(n_images):
        eye = np.array([0.2 * i - 0.8, 0.05 * i, 0.0])
        w2c = look_at(torch.tensor(eye), torch.tensor([0.0, 0.0, 6.0]), torch.tensor([0.0, -1.0, 0.0])).numpy()
        images.append((i + 1, w2c[:3, :3], w2c[:3, 3], f"frame_{i:02d}.png"))
    return pts, images


def make_colmap(
    root: Path,
    *,
    binary: bool,
    model: str = "PINHOLE",
    w: int = 16,
    h: int = 12,
    cam_w: int = 32,
    cam_h: int = 24,
    n_images: int = 9,
    sparse_sub: str = "sparse/0",
) -> Path:
    """Tiny COLMAP model (camera at 2x the stored image size) in text or binary form."""
    params = {
        "SIMPLE_PINHOLE": [30.0, 16.0, 12.0],
        "PINHOLE": [30.0, 31.0, 16.0, 12.0],
        "SIMPLE_RADIAL": [30.0, 16.0, 12.0, 0.01],
        "OPENCV": [30.0, 31.0, 16.0, 12.0, 0.01, 0.0, 0.0, 0.0],
        "FOV": [30.0, 31.0, 16.0, 12.0, 0.5],
    }[model]
    pts, images = colmap_scene(n_images)
    sparse = root / sparse_sub
    sparse.mkdir(parents=True, exist_ok=True)
    for _, _, _, name in images:
        write_png(root / "images" / name, w, h)
    # every image observes every point
    if binary:
        with open(sparse / "cameras.bin", "wb") as f:
            f.write(struct.pack("<Q", 1))
            f.write(struct.pack("<iiQQ", 1, COLMAP_MODELS[model], cam_w, cam_h))
            f.write(struct.pack("<" + "d" * len(params), *params))
        with open(sparse / "images.bin", "wb") as f:
            f.write(struct.pack("<Q", len(images)))
            for iid, R, t, name in images:
                f.write(struct.pack("<i", iid))
                f.write(struct.pack("<4d", *_qvec(R)))
                f.write(struct.pack("<3d", *t))
                f.write(struct.pack("<i", 1))
                f.write(name.encode() + b"\x00")
                f.write(struct.pack("<Q", len(pts)))
                for k in range(len(pts)):
                    f.write(struct.pack("<ddq", 1.0, 2.0, k + 1))
        with open(sparse / "points3D.bin", "wb") as f:
            f.write(struct.pack("<Q", len(pts)))
            for k, p in enumerate(pts):
                f.write(struct.pack("<Q3d3Bd", k + 1, *p, 10, 20, 30, 0.5))
                f.write(struct.pack("<Q", len(images)))
                for iid, *_ in images:
                    f.write(struct.pack("<ii", iid, k))
    else:
        (sparse / "cameras.txt").write_text(
            "# Camera list\n" + f"1 {model} {cam_w} {cam_h} " + " ".join(map(str, params)) + "\n"
        )
        lines = ["# Image list", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"]
        for iid, R, t, name in images:
            q = _qvec(R)
            lines.append(" ".join(map(str, [iid, *q, *t, 1, name])))
            lines.append(" ".join(f"1.0 2.0 {k + 1}" for k in range(len(pts))))
        (sparse / "images.txt").write_text("\n".join(lines) + "\n")
        plines = ["# 3D point list"]
        for k, p in enumerate(pts):
            track = " ".join(f"{iid} {k}" for iid, *_ in images)
            plines.append(f"{k + 1} {p[0]} {p[1]} {p[2]} 10 20 30 0.5 {track}")
        (sparse / "points3D.txt").write_text("\n".join(plines) + "\n")
    return root


# ------------------------------------------------------------ an independent splat reader
SPLAT_TRANSFORM = REPO / ".tools" / "node" / "node_modules" / ".bin" / "splat-transform"
"""Where .ci/run installs PlayCanvas's splat-transform (npm, @playcanvas/splat-transform 3.x)."""


def splat_transform_command() -> tuple[list[str] | None, str]:
    """(the command that runs PlayCanvas's splat-transform, or None; why it is missing): the
    executable ``$SPLAT_TRANSFORM`` names, else :data:`SPLAT_TRANSFORM`; both need ``node``."""
    import shutil

    given = os.environ.get("SPLAT_TRANSFORM")
    path = Path(given) if given else SPLAT_TRANSFORM
    if shutil.which("node") is None:
        return None, "node is not installed (Debian: apt-get install -y nodejs npm)"
    if not path.is_file():
        return None, (f"splat-transform is not installed at {path} (npm install --prefix .tools/node "
                      "@playcanvas/splat-transform@3, as .ci/run does, or set $SPLAT_TRANSFORM)")
    return [str(path)], ""


# ------------------------------------------------------------ a real browser
def chromium_binary() -> str | None:
    """Path of a Chromium / Chrome executable, or None."""
    import shutil

    return next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


class HeadlessPage:
    """A page of headless Chromium driven through the Chrome DevTools protocol (software WebGL),
    its viewport ``size`` (width, height) CSS pixels.

    ``with HeadlessPage(url) as page: page.wait_for_text("...", 60); png = page.screenshot()``
    """

    def __init__(self, url: str, size: tuple[int, int] = (1000, 700)) -> None:
        self.url, self.size = url, size

    def __enter__(self) -> "HeadlessPage":
        import socket
        import subprocess
        import tempfile
        import time
        import urllib.request

        from websockets.sync.client import connect

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self._profile = tempfile.TemporaryDirectory(ignore_cleanup_errors=True)  # Chromium's helpers may still write
        self._proc = subprocess.Popen(
            [chromium_binary(), "--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             f"--window-size={self.size[0]},{self.size[1]}", f"--remote-debugging-port={port}",
             f"--user-data-dir={self._profile.name}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        deadline = time.time() + 60
        while True:
            try:
                tabs = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=5).read())
                page = next(t for t in tabs if t["type"] == "page")
                break
            except Exception:
                if time.time() > deadline:
                    self.__exit__()
                    raise RuntimeError("Chromium's DevTools endpoint did not come up")
                time.sleep(0.5)
        self._ws = connect(page["webSocketDebuggerUrl"], max_size=100_000_000)
        self._id = 0
        self.call("Emulation.setDeviceMetricsOverride", width=self.size[0], height=self.size[1], deviceScaleFactor=1,
                  mobile=False)
        self.call("Page.navigate", url=self.url)
        return self

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self._ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self._ws.recv(timeout=60))
            if msg.get("id") == self._id:
                return msg.get("result", {})

    def text(self) -> str:
        return self.evaluate("document.body ? document.body.innerText : ''") or ""

    def wait_for_text(self, needle: str, timeout: float) -> str:
        import time

        deadline = time.time() + timeout
        while True:
            text = self.text()
            if needle in text or time.time() > deadline:
                return text
            time.sleep(0.5)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True).get("result", {}).get("value")

    def only_canvases(self) -> None:
        """Hide everything on the page but its canvases (panels, notifications), for screenshots of the 3D view."""
        self.evaluate("const s = document.createElement('style'); document.head.appendChild(s); s.textContent = "
                      "'* {visibility: hidden !important} canvas {visibility: visible !important}'; 1")

    def screenshot(self) -> np.ndarray:
        """[H, W, 3] uint8 BGR."""
        import base64

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)

    def __exit__(self, *exc) -> None:
        if getattr(self, "_ws", None) is not None:
            self._ws.close()
        self._proc.terminate()
        self._proc.wait(timeout=30)
        self._profile.cleanup()

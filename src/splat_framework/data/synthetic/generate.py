"""Render the synthetic scenes and write them as LLFF / Blender datasets (see the package docstring)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from ...console import phase
from ..builtin_scenes import NAMED_SCENES, unknown_scene_message
from ..cache_dir import user_cache_dir
from ..scene import DataError
from .raycast import Scene, cast_rays
from .scenes import (
    FORWARD_HFOV_DEG,
    FORWARD_RIG_RADIUS,
    FORWARD_TARGET_Z,
    OBJECT_CAMERA_ANGLE_X,
    OBJECT_RADIUS,
    ViewSpec,
    build_forward,
    build_object,
    forward_views,
    object_views,
)
from .textures import sample

GENERATOR_VERSION = 2
"""Bumped whenever the output of a given (kind, size, views, seed) changes; part of the cache key."""

Kind = Literal["forward", "object"]

DEFAULTS: dict[str, dict] = {
    "forward": dict(width=504, height=378, n_views=20),
    "object": dict(width=400, height=400, n_views=100),
}



def n_test_for(n_train: int) -> int:
    """Number of Blender test frames written with ``n_train`` training frames (40 for 100)."""
    return max(1, int(round(0.4 * n_train)))


# ------------------------------------------------------------------ rendering
def build_scene(kind: Kind, seed: int = 0, focal: float = 400.0) -> Scene:
    """The primitives of scene ``kind`` for ``seed`` (``focal`` only sets texture resolution)."""
    if kind == "forward":
        return build_forward(seed, focal)
    if kind == "object":
        return build_object(seed, focal)
    raise ValueError(f"unknown synthetic scene kind {kind!r} (expected 'forward' or 'object')")


def pixel_rays(view: ViewSpec) -> tuple[np.ndarray, np.ndarray]:
    """Rays through all pixel centres of ``view`` (row-major).

    Returns the shared origin [3] (the camera centre) and directions [H*W, 3]
    scaled so that the ray parameter equals camera-space z (the camera-space
    direction has z = 1).
    """
    K, w2c = view.K, view.world_to_cam
    x = (np.arange(view.width, dtype=np.float64) + 0.5 - K[0, 2]) / K[0, 0]
    y = (np.arange(view.height, dtype=np.float64) + 0.5 - K[1, 2]) / K[1, 1]
    R = w2c[:3, :3]  # rows: camera axes in world space; world dir = R^T d_cam
    d = x[None, :, None] * R[0] + y[:, None, None] * R[1] + R[2]
    center = -R.T @ w2c[:3, 3]
    return center, d.reshape(-1, 3)


def screen_candidates(scene: Scene, view: ViewSpec) -> list:
    """Per primitive, the row-major pixel indices inside the projection of its bounding corners.

    None means "all pixels" (a corner is behind or too close to the camera).
    """
    K, w2c, W, H = view.K, view.world_to_cam, view.width, view.height
    out = []
    for prim in scene.primitives:
        pc = prim.corners() @ w2c[:3, :3].T + w2c[:3, 3]
        if np.any(pc[:, 2] <= 1e-3):
            out.append(None)
            continue
        u = K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]
        v = K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]
        # pixel i has its centre at i + 0.5; keep a one-pixel margin
        u0, u1 = max(0, int(np.floor(u.min())) - 1), min(W - 1, int(np.ceil(u.max())) + 1)
        v0, v1 = max(0, int(np.floor(v.min())) - 1), min(H - 1, int(np.ceil(v.max())) + 1)
        if u0 > u1 or v0 > v1:
            out.append(np.zeros(0, np.int64))
            continue
        rows = np.arange(v0, v1 + 1, dtype=np.int64)
        cols = np.arange(u0, u1 + 1, dtype=np.int64)
        out.append((rows[:, None] * W + cols[None, :]).ravel())
    return out


def render_view(scene: Scene, view: ViewSpec, directions: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray-cast one view.

    Args:
        directions: camera-space ray directions [H*W, 3] (z = 1) of the pixels, row-major, for a
            lens that is not ``view.K``'s pinhole (a distorted one); default: through the pixel
            centres of ``view.K``.

    Returns:
        rgb: [H, W, 3] float32 in [0, 1] (0 where nothing is hit).
        alpha: [H, W] float32, 1 where a surface is hit, else 0.
        depth: [H, W] float32 camera-space z of the surface at the pixel centre, 0 where none.
    """
    o, d_all = pixel_rays(view)
    n_all = len(d_all)
    if directions is not None:  # the pinhole's screen rectangles do not bound another lens's pixels
        d_all = np.asarray(directions, np.float64).reshape(n_all, 3) @ view.world_to_cam[:3, :3]
    cand = screen_candidates(scene, view) if directions is None else [None] * len(scene.primitives)
    # only rays inside some primitive's screen rectangle can hit anything
    if any(c is None for c in cand):
        active = np.arange(n_all)
    else:
        mask = np.zeros(n_all, bool)
        for c in cand:
            mask[c] = True
        active = np.nonzero(mask)[0]
        pos = np.full(n_all, -1, np.int64)
        pos[active] = np.arange(len(active))
        cand = [pos[c] for c in cand]
    d = d_all[active]
    hits = cast_rays(scene, o, d, cand)
    rgb = np.zeros((len(d), 3), np.float32)
    f = 0.5 * (view.K[0, 0] + view.K[1, 1])
    for i, prim in enumerate(scene.primitives):
        sel = np.nonzero(hits.prim == i)[0]
        if len(sel) == 0:
            continue
        ds = d[sel]
        dlen = np.sqrt((ds * ds).sum(-1))
        nrm = hits.normal[sel]
        cos = (nrm * ds).sum(-1) / dlen
        nrm = nrm * np.where(cos > 0, -1.0, 1.0)[:, None]  # face the viewer (two-sided)
        # pixel footprint on the surface, in level-0 texels -> mip level
        foot = hits.t[sel] / f * dlen / np.sqrt(np.maximum(np.abs(cos), 0.05))
        lod = np.log2(np.maximum(foot * prim.texel_density, 1.0))
        albedo = sample(prim.texture, hits.uv[sel], lod)
        shade = np.full(len(sel), scene.ambient)
        for light in scene.lights:
            shade += light.intensity * np.maximum(nrm @ light.direction, 0.0)
        rgb[sel] = albedo * shade[:, None].astype(np.float32)
    H, W = view.height, view.width
    rgb_full = np.zeros((n_all, 3), np.float32)
    rgb_full[active] = np.clip(rgb, 0, 1)
    alpha = np.zeros(n_all, np.float32)
    alpha[active] = hits.hit
    depth = np.zeros(n_all, np.float32)
    depth[active] = np.where(hits.hit, hits.t, 0.0)
    return rgb_full.reshape(H, W, 3), alpha.reshape(H, W), depth.reshape(H, W)


# ------------------------------------------------------------------ writers
def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def _write_png(path: Path, rgb: np.ndarray, alpha: np.ndarray | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = _to_u8(rgb)[..., ::-1]
    if alpha is not None:
        img = np.concatenate([img, _to_u8(alpha)[..., None]], -1)
    if not cv2.imwrite(str(path), np.ascontiguousarray(img)):
        raise OSError(f"could not write {path}")


def _write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=2) + "\n")


def _bounds(depth: np.ndarray, default: tuple[float, float]) -> tuple[float, float]:
    valid = depth[depth > 0]
    if valid.size == 0:
        return default
    return float(valid.min()), float(valid.max())


def opencv_to_llff_rotation(c2w_cv: np.ndarray) -> np.ndarray:
    """[3,3] LLFF rotation columns [down, right, back] = [y, x, -z] of an OpenCV cam-to-world."""
    R = c2w_cv[:3, :3]
    return np.stack([R[:, 1], R[:, 0], -R[:, 2]], 1)


def _render_all(scene: Scene, views: list[ViewSpec], out: Path, rgba: bool, default_bounds):
    records = []
    for view in views:
        rgb, alpha, depth = render_view(scene, view)
        _write_png(out / (view.name if rgba else f"images/{view.name}"), rgb, alpha if rgba else None)
        depth_rel = "depths/" + str(Path(view.name).with_suffix(".npy")).replace(os.sep, "/")
        (out / depth_rel).parent.mkdir(parents=True, exist_ok=True)
        np.save(out / depth_rel, depth)
        near, far = _bounds(depth, default_bounds)
        records.append(dict(
            name=view.name,
            image=view.name if rgba else f"images/{view.name}",
            split=view.split,
            width=view.width,
            height=view.height,
            K=view.K.tolist(),
            world_to_cam=view.world_to_cam.tolist(),
            near=near,
            far=far,
            depth=depth_rel,
        ))
    return records


def generate_scene(
    kind: Kind,
    out_dir: Path,
    *,
    width: int | None = None,
    height: int | None = None,
    n_views: int | None = None,
    seed: int = 0,
) -> Path:
    """Render scene ``kind`` and write it as a dataset into ``out_dir`` (created; existing files overwritten).

    Args:
        kind: "forward" (LLFF format) or "object" (Blender format, RGBA).
        out_dir: destination folder.
        width, height: image size (defaults: forward 504x378, object 400x400).
        n_views: forward: number of images (default 20); object: number of
            training frames (default 100), plus ``round(0.4 * n_views)`` test frames.
        seed: everything (layout, textures, cameras) is a function of the seed.

    Returns:
        ``out_dir``.
    """
    if kind not in DEFAULTS:
        raise ValueError(f"unknown synthetic scene kind {kind!r} (expected 'forward' or 'object')")
    dflt = DEFAULTS[kind]
    width = int(width or dflt["width"])
    height = int(height or dflt["height"])
    n_views = int(n_views or dflt["n_views"])
    if width < 4 or height < 4 or n_views < 1:
        raise ValueError(f"bad synthetic scene size {width}x{height} with {n_views} views")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = dict(kind=kind, width=width, height=height, n_views=n_views, seed=seed)
    if kind == "forward":
        views = forward_views(seed, n_views, width, height)
        scene = build_scene(kind, seed, float(views[0].K[0, 0]))
        records = _render_all(scene, views, out, rgba=False, default_bounds=(2.0, 10.0))
        rows = []
        for view, rec in zip(views, records):
            c2w = np.linalg.inv(view.world_to_cam)
            m = np.concatenate([opencv_to_llff_rotation(c2w), c2w[:3, 3:4],
                                np.array([[height], [width], [view.K[0, 0]]], dtype=np.float64)], 1)
            rows.append(np.concatenate([m.ravel(), [rec["near"], rec["far"]]]))
        np.save(out / "poses_bounds.npy", np.stack(rows).astype(np.float64))
        fmt = "llff"
        extra = dict(hfov_deg=FORWARD_HFOV_DEG, rig_radius=FORWARD_RIG_RADIUS, target_z=FORWARD_TARGET_Z,
                     world_axes="OpenCV axes of the central camera: x right, y down, z forward")
    else:
        n_test = n_test_for(n_views)
        views = object_views(seed, n_views, n_test, width, height)
        scene = build_scene(kind, seed, float(views[0].K[0, 0]))
        records = _render_all(scene, views, out, rgba=True, default_bounds=(2.0, 6.0))
        flip = np.diag([1.0, -1.0, -1.0, 1.0])
        for split in ("train", "test"):
            frames = []
            for view in views:
                if view.split != split:
                    continue
                c2w_gl = np.linalg.inv(view.world_to_cam) @ flip
                frames.append(dict(file_path="./" + view.name[: -len(".png")], rotation=0.0,
                                   transform_matrix=c2w_gl.tolist()))
            _write_json(out / f"transforms_{split}.json", dict(camera_angle_x=OBJECT_CAMERA_ANGLE_X, frames=frames))
        fmt = "blender"
        params["n_train"] = n_views
        params["n_test"] = n_test
        extra = dict(camera_angle_x=OBJECT_CAMERA_ANGLE_X, camera_radius=OBJECT_RADIUS,
                     world_axes="Blender: z up")
    _write_json(out / "cameras.json", dict(
        format=fmt,
        convention="OpenCV: x right, y down, z forward; pixel centres at +0.5; K and world_to_cam per view",
        views=records,
    ))
    _write_json(out / "scene.json", dict(
        generator="splat_framework.data.synthetic",
        generator_version=GENERATOR_VERSION,
        format=fmt,
        **params,
        **extra,
        depth_format=("depths/<image path relative to the image folder (LLFF: images/, Blender: the dataset root)"
                      " with .npy>: float32 [H, W] camera-space z at pixel centres, 0 = no surface"),
        scene=scene.describe(),
    ))
    return out


# ------------------------------------------------------------------ cache
def scene_params(name: str) -> dict:
    """Generator parameters of a named scene (see :data:`NAMED_SCENES`)."""
    refused = unknown_scene_message(name)
    if refused:
        raise DataError(refused)
    return dict(NAMED_SCENES[name])


def default_cache_dir() -> Path:
    """``$SPLAT_CACHE/synthetic`` if ``SPLAT_CACHE`` is set, else ``~/.cache/splat/synthetic``."""
    return user_cache_dir() / "synthetic"


def cache_key(name: str, params: dict) -> str:
    """Folder name ``<name>-v<version>-<hash of params>``."""
    blob = json.dumps(dict(params, version=GENERATOR_VERSION), sort_keys=True).encode()
    return f"{name}-v{GENERATOR_VERSION}-{hashlib.sha256(blob).hexdigest()[:10]}"


def ensure_generated(name: str, params: dict, cache_dir: Path | None = None) -> Path:
    """Generate ``params`` once into the cache (atomically) and return the folder."""
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    final = root / cache_key(name, params)
    if (final / "scene.json").is_file():
        return final
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{final.name}-", dir=root))
    try:
        p = dict(params)
        with phase(f"generating the built-in scene {name} (once; kept in {final})"):  # lines after 2 s
            generate_scene(p.pop("kind"), tmp, **p)
        try:
            os.rename(tmp, final)
        except OSError:
            # another process finished first (or a stale incomplete folder is in the way)
            if (final / "scene.json").is_file():
                shutil.rmtree(tmp, ignore_errors=True)
                return final
            shutil.rmtree(final, ignore_errors=True)
            os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def ensure_scene(name: str, cache_dir: Path | None = None) -> Path:
    """Return the folder of named scene ``name``, generating it on first use.

    Known names: "forward", "object", "forward-tiny" (64x48, 20 views),
    "object-tiny" (64x64, 100 train + 40 test). The folder is
    ``<cache_dir>/<name>-v<GENERATOR_VERSION>-<hash>``, ``cache_dir`` defaulting
    to :func:`default_cache_dir`. Generation goes to a temporary sibling folder
    that is renamed into place when complete, so an interrupted run never
    leaves a partial dataset that would be reused.
    """
    return ensure_generated(name, scene_params(name), cache_dir)

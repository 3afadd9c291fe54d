"""Scene layouts and camera rigs for the two built-in synthetic scenes.

``forward`` (LLFF-like): world axes are those of the central camera in the
OpenCV convention (x right, y down, z forward). A textured back wall at
z ~ 9.4, a floor at y = +2.2 (below the cameras, since y points down) and a
seeded clutter of textured cards, boxes, spheres and cylinders between
z ~ 2 and z ~ 8. Cameras lie on a Vogel (sunflower) spiral of radius 0.4 in
the z = 0 plane, each looking at a slightly jittered point near (0, 0, 5.5),
with a horizontal field of view of 60 degrees.

``object`` (Blender-like): world z is up. A pedestal cylinder, a box on it,
a sphere on the box and two small props, all within about [-1, 1.2]^3.
Cameras on a sphere of radius 4 (upper hemisphere) look at the origin with
``camera_angle_x`` = 0.6911 rad, as in the Blender synthetic scenes.

The geometry and camera placement depend only on the seed; the texture
resolution follows the focal length (so tiny renders do not build huge
textures), while the texture content is drawn from the same seeded streams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .raycast import Box, Cylinder, Light, Quad, Scene, Sphere, rotation
from .textures import make_texture, mip_pyramid

FORWARD_HFOV_DEG = 60.0
OBJECT_CAMERA_ANGLE_X = 0.6911112070083618  # Blender synthetic scenes
OBJECT_RADIUS = 4.0
FORWARD_RIG_RADIUS = 0.4
FORWARD_TARGET_Z = 5.5


@dataclass
class ViewSpec:
    """One camera: OpenCV K [3,3] and world-to-camera [4,4] (float64), size and name."""

    K: np.ndarray
    world_to_cam: np.ndarray
    width: int
    height: int
    name: str
    split: str | None = None


def look_at_np(eye, target, up) -> np.ndarray:
    """[4, 4] float64 world-to-camera (OpenCV axes): :func:`splat_framework.cameras.look_at` as numpy."""
    from ...cameras import look_at

    return look_at(np.asarray(eye, np.float64), np.asarray(target, np.float64), np.asarray(up, np.float64)).numpy()


def _texture(seed: int, index: int, w_world: float, h_world: float, density: float, *, text: bool = True,
             tiles: float = 1.0, max_side: int = 1024, min_side: int = 24) -> tuple[list[np.ndarray], float]:
    """Mip pyramid for a surface of world size w_world x h_world at ``density`` texels/unit."""
    rng = np.random.default_rng([seed, 1000 + index])
    w = w_world * density
    h = h_world * density
    s = min(1.0, max_side / max(w, h))
    w, h = max(min_side, int(round(w * s))), max(min_side, int(round(h * s)))
    eff = max(w / w_world, h / h_world)
    return mip_pyramid(make_texture(rng, h, w, text=text, tiles=tiles)), eff


def _with_texture(prim, seed: int, index: int, w_world: float, h_world: float, density: float, **kw):
    prim.texture, prim.texel_density = _texture(seed, index, w_world, h_world, density, **kw)
    return prim


# ------------------------------------------------------------------ forward
def build_forward(seed: int, focal: float) -> Scene:
    """The LLFF-like scene; ``focal`` (pixels) sets the texture resolution only."""
    rng = np.random.default_rng([seed, 1])
    prims = []

    def density_at(z: float) -> float:
        return 1.5 * focal / z

    wall_yaw = rng.uniform(-0.08, 0.08)
    Rw = rotation(yaw=wall_yaw)
    wall = Quad(name="wall", center=(0.0, 0.0, 9.4), axis_u=Rw[:, 0], axis_v=Rw[:, 1], half_u=9.0, half_v=6.5)
    prims.append(_with_texture(wall, seed, 0, 18.0, 13.0, density_at(9.4), tiles=3.0))
    floor = Quad(name="floor", center=(0.0, 2.2, 6.0), axis_u=(1, 0, 0), axis_v=(0, 0, 1), half_u=9.0, half_v=4.5)
    prims.append(_with_texture(floor, seed, 1, 18.0, 9.0, density_at(6.0), tiles=3.0))

    # a near sphere so the scene's near bound is ~2
    side = 1.0 if rng.random() < 0.5 else -1.0
    near = Sphere(name="near-sphere", center=(side * rng.uniform(0.75, 0.95), rng.uniform(0.3, 0.5), 2.55),
                  radius=0.4, R=rotation(*rng.uniform(-np.pi, np.pi, 3)))
    prims.append(_with_texture(near, seed, 2, 2 * np.pi * 0.4, np.pi * 0.4, density_at(2.2)))

    kinds = ["box", "card", "sphere", "box", "cylinder", "card", "sphere", "box", "card", "cylinder", "box",
             "card"]
    for i, kind in enumerate(kinds):
        z = rng.uniform(3.0, 8.3)
        hx, hy = 0.577 * z * 0.85, 0.433 * z * 0.85
        x = rng.uniform(-hx, hx)
        size = rng.uniform(0.25, 0.5) * (0.6 + 0.08 * z)
        y = rng.uniform(-hy, min(hy, 2.2 - size))
        on_floor = z > 5.2 and rng.random() < 0.6
        tex_i = 10 + i
        d = density_at(z)
        if kind == "box":
            half = size * rng.uniform(0.6, 1.2, 3)
            if on_floor:
                y = 2.2 - half[1]
                R = rotation(yaw=rng.uniform(-np.pi, np.pi))
            else:
                R = rotation(*rng.uniform(-np.pi, np.pi, 3))
            prim = Box(name=f"box{i}", center=(x, y, z), half=half, R=R)
            prims.append(_with_texture(prim, seed, tex_i, 6 * half.max(), 4 * half.max(), d))
        elif kind == "sphere":
            r = size
            if on_floor:
                y = 2.2 - r
            prim = Sphere(name=f"sphere{i}", center=(x, y, z), radius=r, R=rotation(*rng.uniform(-np.pi, np.pi, 3)))
            prims.append(_with_texture(prim, seed, tex_i, 2 * np.pi * r, np.pi * r, d))
        elif kind == "cylinder":
            r = size * rng.uniform(0.5, 0.8)
            hh = size * rng.uniform(0.8, 1.6)
            if on_floor:
                y = 2.2 - hh
                # axis along world y (vertical), with a random spin
                R = rotation(yaw=rng.uniform(-np.pi, np.pi)) @ rotation(pitch=np.pi / 2)
            else:
                R = rotation(*rng.uniform(-np.pi, np.pi, 3))
            prim = Cylinder(name=f"cylinder{i}", center=(x, y, z), radius=r, half_height=hh, R=R)
            prims.append(_with_texture(prim, seed, tex_i, 2 * np.pi * r, 3 * hh, d))
        else:  # card: a textured rectangle, mostly facing the cameras
            hu = size * rng.uniform(1.2, 2.2)
            hv = hu * rng.uniform(0.5, 1.0)
            R = rotation(yaw=rng.uniform(-0.7, 0.7), pitch=rng.uniform(-0.4, 0.4), roll=rng.uniform(-0.3, 0.3))
            prim = Quad(name=f"card{i}", center=(x, y, z), axis_u=R[:, 0], axis_v=R[:, 1], half_u=hu, half_v=hv)
            prims.append(_with_texture(prim, seed, tex_i, 2 * hu, 2 * hv, d))

    lights = [Light(direction=(0.35, -1.0, -0.45), intensity=0.75), Light(direction=(-0.6, -0.3, -1.0), intensity=0.3)]
    return Scene(primitives=prims, lights=lights, ambient=0.3)


def forward_views(seed: int, n_views: int, width: int, height: int) -> list[ViewSpec]:
    """Cameras on a sunflower spiral (radius 0.4) in z = 0, looking roughly along +z."""
    rng = np.random.default_rng([seed, 2])
    f = 0.5 * width / math.tan(math.radians(FORWARD_HFOV_DEG) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=np.float64)
    golden = math.pi * (3 - math.sqrt(5))
    views = []
    digits = max(3, len(str(n_views - 1)))
    for i in range(n_views):
        r = FORWARD_RIG_RADIUS * math.sqrt((i + 0.5) / n_views)
        a = i * golden
        eye = np.array([r * math.cos(a), r * math.sin(a), rng.uniform(-0.05, 0.05)])
        target = np.array([rng.normal(0, 0.12), rng.normal(0, 0.08), FORWARD_TARGET_Z])
        w2c = look_at_np(eye, target, (0.0, -1.0, 0.0))
        views.append(ViewSpec(K=K.copy(), world_to_cam=w2c, width=width, height=height,
                              name=f"image{i:0{digits}d}.png"))
    return views


# ------------------------------------------------------------------ object
def build_object(seed: int, focal: float) -> Scene:
    """The Blender-like object; ``focal`` (pixels) sets the texture resolution only.

    Layout in object units (pedestal top at z = 0), then scaled by ``S`` and
    shifted by ``z0`` into the world, so the object spans about [-1, 1.3] in z.
    """
    rng = np.random.default_rng([seed, 3])
    S, z0 = 1.15, -0.45
    d = 1.5 * focal / OBJECT_RADIUS

    def P(x, y, z):
        return np.array([x * S, y * S, z * S + z0])

    prims = []
    ped = Cylinder(name="pedestal", center=P(0, 0, -0.35), radius=0.75 * S, half_height=0.35 * S,
                   R=rotation(roll=rng.uniform(-np.pi, np.pi)))
    prims.append(_with_texture(ped, seed, 0, 2 * np.pi * 0.75 * S, 3 * 0.35 * S, d))
    half = np.array([0.5, 0.42, 0.4]) * rng.uniform(0.9, 1.1, 3)
    box = Box(name="box", center=P(0, 0, half[2]), half=half * S, R=rotation(roll=rng.uniform(-np.pi, np.pi)))
    prims.append(_with_texture(box, seed, 1, 6 * half.max() * S, 4 * half.max() * S, d))
    r = 0.35 * rng.uniform(0.9, 1.1)
    sph = Sphere(name="sphere", center=P(rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 2 * half[2] + r * 0.9),
                 radius=r * S, R=rotation(*rng.uniform(-np.pi, np.pi, 3)))
    prims.append(_with_texture(sph, seed, 2, 2 * np.pi * r * S, np.pi * r * S, d))
    a = rng.uniform(-np.pi, np.pi)
    small = Box(name="small-box", center=P(0.58 * math.cos(a), 0.58 * math.sin(a), 0.12), half=np.full(3, 0.12 * S),
                R=rotation(roll=rng.uniform(-np.pi, np.pi)))
    prims.append(_with_texture(small, seed, 3, 0.72 * S, 0.48 * S, d))
    b = a + np.pi * rng.uniform(0.6, 1.4)
    ball = Sphere(name="small-sphere", center=P(0.58 * math.cos(b), 0.58 * math.sin(b), 0.15), radius=0.15 * S,
                  R=rotation(*rng.uniform(-np.pi, np.pi, 3)))
    prims.append(_with_texture(ball, seed, 4, 2 * np.pi * 0.15 * S, np.pi * 0.15 * S, d))
    c = b + np.pi * rng.uniform(0.4, 0.8)
    post = Cylinder(name="post", center=P(0.6 * math.cos(c), 0.6 * math.sin(c), 0.3), radius=0.07 * S,
                    half_height=0.3 * S)
    prims.append(_with_texture(post, seed, 5, 2 * np.pi * 0.07 * S, 0.9 * S, d, text=False))
    lights = [Light(direction=(0.8, -0.6, 1.2), intensity=0.7), Light(direction=(-0.9, 0.7, 0.3), intensity=0.3)]
    return Scene(primitives=prims, lights=lights, ambient=0.32)


def object_views(seed: int, n_train: int, n_test: int, width: int, height: int) -> list[ViewSpec]:
    """Train: seeded random directions on the upper hemisphere; test: a spiral path. Radius 4."""
    rng = np.random.default_rng([seed, 4])
    f = 0.5 * width / math.tan(0.5 * OBJECT_CAMERA_ANGLE_X)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=np.float64)
    views = []

    def make(z: float, az: float, name: str, split: str):
        rxy = math.sqrt(max(0.0, 1 - z * z))
        eye = OBJECT_RADIUS * np.array([rxy * math.cos(az), rxy * math.sin(az), z])
        views.append(ViewSpec(K=K.copy(), world_to_cam=look_at_np(eye, (0, 0, 0), (0, 0, 1)), width=width,
                              height=height, name=name, split=split))

    for i in range(n_train):
        make(rng.uniform(0.08, 0.97), rng.uniform(-np.pi, np.pi), f"train/r_{i}.png", "train")
    for i in range(n_test):
        s = i / max(n_test, 1)
        elev = math.radians(30 + 12 * math.sin(2 * np.pi * 2 * s))
        make(math.sin(elev), -np.pi + 2 * np.pi * s, f"test/r_{i}.png", "test")
    return views

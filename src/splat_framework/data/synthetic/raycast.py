"""An analytic ray caster for the synthetic scenes (numpy, vectorised, float64).

This is deliberately independent of the Gaussian rasterizer: it intersects
rays with exact primitives (rectangles, spheres, oriented boxes, capped
cylinders) and returns, per ray, the nearest hit distance, the primitive id,
the outward surface normal and the surface texture coordinate. Texture
coordinates are attached to the surface in the primitive's own frame, so a
surface point has the same (primitive id, uv) from every view.

Every primitive has an ``atlas`` texture (a mip pyramid, see
:mod:`.textures`); ``uv`` is in [0, 1]^2 of that atlas (u along columns,
v along rows). Boxes use a 3x2 atlas (one cell per face), cylinders use the
upper two thirds for the side and two squares below for the caps.

Main entry point: :func:`cast_rays`. The per-primitive ``intersect_*``
functions return only the ray parameter ``t`` (``inf`` where missed), so the
tests can compare them with hand-computed intersections.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

EPS = 1e-9
T_MIN = 1e-6


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def rotation(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """[3, 3] rotation Rz(roll) @ Ry(yaw) @ Rx(pitch) (radians); columns are the local axes."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


# ------------------------------------------------------------------ primitives
@dataclass
class Primitive:
    """Base class. ``texture`` is a list of float32 [h, w, 3] mip levels (level 0 first).

    ``texel_density`` is the approximate number of level-0 texels per world
    unit on the surface (used to pick a mip level from the pixel footprint).
    """

    name: str = ""
    texture: list = field(default_factory=list, repr=False)
    texel_density: float = 1.0

    def describe(self) -> dict:
        raise NotImplementedError

    def corners(self) -> np.ndarray:
        """[k, 3] points whose convex hull contains the primitive (for culling)."""
        raise NotImplementedError


def _box_corners(center: np.ndarray, R: np.ndarray, half) -> np.ndarray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return center + (signs * np.asarray(half, dtype=np.float64)) @ R.T


@dataclass
class Quad(Primitive):
    """Two-sided rectangle: ``center + s * axis_u + r * axis_v`` with |s| <= half_u, |r| <= half_v.

    Texture u runs along ``axis_u`` and v along ``axis_v`` (v = row index, so
    choose ``axis_v`` pointing "down" in the image for readable text).
    Outward normal: ``axis_u x axis_v``.
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_u: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0]))
    axis_v: np.ndarray = field(default_factory=lambda: np.array([0, 1.0, 0]))
    half_u: float = 1.0
    half_v: float = 1.0

    def __post_init__(self):
        self.center = np.asarray(self.center, dtype=np.float64)
        self.axis_u = _unit(self.axis_u)
        self.axis_v = _unit(self.axis_v - np.dot(self.axis_v, self.axis_u) * self.axis_u)
        self.normal = np.cross(self.axis_u, self.axis_v)

    def describe(self) -> dict:
        return dict(type="quad", name=self.name, center=self.center.tolist(), axis_u=self.axis_u.tolist(),
                    axis_v=self.axis_v.tolist(), half_u=self.half_u, half_v=self.half_v)

    def corners(self) -> np.ndarray:
        su = np.array([-1, 1, 1, -1.0])[:, None] * self.half_u * self.axis_u
        sv = np.array([-1, -1, 1, 1.0])[:, None] * self.half_v * self.axis_v
        return self.center + su + sv


@dataclass
class Sphere(Primitive):
    """Sphere; ``R`` (columns = local axes) orients the texture (longitude about local z)."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 1.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        self.center = np.asarray(self.center, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)

    def describe(self) -> dict:
        return dict(type="sphere", name=self.name, center=self.center.tolist(), radius=self.radius,
                    R=self.R.tolist())

    def corners(self) -> np.ndarray:
        return _box_corners(self.center, np.eye(3), [self.radius] * 3)


@dataclass
class Box(Primitive):
    """Oriented box: local axes are the columns of ``R``, half sizes ``half``."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    half: np.ndarray = field(default_factory=lambda: np.ones(3))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        self.center = np.asarray(self.center, dtype=np.float64)
        self.half = np.asarray(self.half, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)

    def describe(self) -> dict:
        return dict(type="box", name=self.name, center=self.center.tolist(), half=self.half.tolist(),
                    R=self.R.tolist())

    def corners(self) -> np.ndarray:
        return _box_corners(self.center, self.R, self.half)


@dataclass
class Cylinder(Primitive):
    """Capped cylinder around the local z axis (column 2 of ``R``), |z| <= half_height."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 1.0
    half_height: float = 1.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        self.center = np.asarray(self.center, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)

    def describe(self) -> dict:
        return dict(type="cylinder", name=self.name, center=self.center.tolist(), radius=self.radius,
                    half_height=self.half_height, R=self.R.tolist())

    def corners(self) -> np.ndarray:
        return _box_corners(self.center, self.R, [self.radius, self.radius, self.half_height])


@dataclass
class Light:
    """Directional light: ``direction`` points from the surface towards the light."""

    direction: np.ndarray
    intensity: float

    def __post_init__(self):
        self.direction = _unit(self.direction)


@dataclass
class Scene:
    """Primitives + lighting. ``ambient`` is added to the Lambertian terms."""

    primitives: list
    lights: list
    ambient: float = 0.3

    def describe(self) -> dict:
        return dict(
            ambient=self.ambient,
            lights=[dict(direction=light.direction.tolist(), intensity=light.intensity) for light in self.lights],
            primitives=[p.describe() for p in self.primitives],
        )


# --------------------------------------------------------------- intersections
def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product with broadcasting ([3] or [N, 3] operands)."""
    return (a * b).sum(-1)


def _safe_div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    b = np.where(np.abs(b) < EPS, np.where(b < 0, -EPS, EPS), b)
    return a / b


def intersect_quad(q: Quad, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the hit with the rectangle, ``inf`` where missed."""
    t = _safe_div((q.center - o) @ q.normal, d @ q.normal)
    p = o + t[:, None] * d - q.center
    ok = (t > T_MIN) & (np.abs(p @ q.axis_u) <= q.half_u) & (np.abs(p @ q.axis_v) <= q.half_v)
    return np.where(ok, t, np.inf)


def intersect_sphere(s: Sphere, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[N] nearest positive ray parameter (unit or non-unit ``d``), ``inf`` where missed."""
    oc = o - s.center
    a = _dot(d, d)
    b = _dot(oc, d)
    c = _dot(oc, oc) - s.radius**2
    disc = b * b - a * c
    sq = np.sqrt(np.maximum(disc, 0.0))
    t0 = (-b - sq) / a
    t1 = (-b + sq) / a
    t = np.where(t0 > T_MIN, t0, t1)
    return np.where((disc >= 0) & (t > T_MIN), t, np.inf)


def _box_slabs(b: Box, o: np.ndarray, d: np.ndarray):
    ol = (o - b.center) @ b.R
    dl = d @ b.R
    inv = _safe_div(np.ones_like(dl), dl)
    t1 = (-b.half - ol) * inv
    t2 = (b.half - ol) * inv
    tn = np.minimum(t1, t2)
    tf = np.maximum(t1, t2)
    return ol, dl, tn, tf


def intersect_box(b: Box, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the first hit with the oriented box, ``inf`` where missed."""
    _, _, tn, tf = _box_slabs(b, o, d)
    tmin = tn.max(axis=1)
    tmax = tf.min(axis=1)
    t = np.where(tmin > T_MIN, tmin, tmax)
    return np.where((tmax >= tmin) & (t > T_MIN), t, np.inf)


def _cyl_parts(c: Cylinder, o: np.ndarray, d: np.ndarray):
    """Local origin/direction and the side / cap hit parameters (``inf`` where none).

    Only the first positive root of the side and the one cap plane the ray can
    enter through are tested: if the first side root is outside the height
    range, any later side hit is preceded by a cap hit.
    """
    ol = (o - c.center) @ c.R
    dl = d @ c.R
    h = c.half_height
    # side
    a = dl[:, 0] ** 2 + dl[:, 1] ** 2
    bb = ol[..., 0] * dl[:, 0] + ol[..., 1] * dl[:, 1]
    cc = ol[..., 0] ** 2 + ol[..., 1] ** 2 - c.radius**2
    disc = bb * bb - a * cc
    sq = np.sqrt(np.maximum(disc, 0.0))
    a_s = np.where(a < EPS, EPS, a)
    t0 = (-bb - sq) / a_s
    root = np.where(t0 > T_MIN, t0, (-bb + sq) / a_s)
    z = ol[..., 2] + root * dl[:, 2]
    good = (disc >= 0) & (a >= EPS) & (root > T_MIN) & (np.abs(z) <= h)
    t_side = np.where(good, root, np.inf)
    # cap: the plane on the origin's side when outside the slab, else the exit plane
    oz = np.broadcast_to(ol[..., 2], z.shape)
    hz = np.where(np.abs(oz) > h, np.sign(oz) * h, np.where(dl[:, 2] >= 0, h, -h))
    tc = _safe_div(hz - oz, dl[:, 2])
    x = ol[..., 0] + tc * dl[:, 0]
    y = ol[..., 1] + tc * dl[:, 1]
    good = (tc > T_MIN) & (x * x + y * y <= c.radius**2)
    t_cap = np.where(good, tc, np.inf)
    return ol, dl, t_side, t_cap


def intersect_cylinder(c: Cylinder, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the first hit with the capped cylinder, ``inf`` where missed."""
    _, _, ts, tc = _cyl_parts(c, o, d)
    return np.minimum(ts, tc)


def intersect(p: Primitive, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the first hit with any primitive type."""
    if isinstance(p, Quad):
        return intersect_quad(p, o, d)
    if isinstance(p, Sphere):
        return intersect_sphere(p, o, d)
    if isinstance(p, Box):
        return intersect_box(p, o, d)
    if isinstance(p, Cylinder):
        return intersect_cylinder(p, o, d)
    raise TypeError(f"unknown primitive {type(p).__name__}")


# ------------------------------------------------------------ surface attributes
def _surface(p: Primitive, o: np.ndarray, d: np.ndarray, t: np.ndarray):
    """Outward normal [n,3] and atlas uv [n,2] at the hits ``o + t d`` (all rays hit ``p``)."""
    x = o + t[:, None] * d
    if isinstance(p, Quad):
        rel = x - p.center
        u = (rel @ p.axis_u) / (2 * p.half_u) + 0.5
        v = (rel @ p.axis_v) / (2 * p.half_v) + 0.5
        n = np.broadcast_to(p.normal, x.shape)
        return n, np.stack([u, v], -1)
    if isinstance(p, Sphere):
        n = (x - p.center) / p.radius
        loc = n @ p.R
        u = np.arctan2(loc[:, 1], loc[:, 0]) / (2 * np.pi) + 0.5
        v = np.arccos(np.clip(loc[:, 2], -1.0, 1.0)) / np.pi
        return n, np.stack([u, v], -1)
    if isinstance(p, Box):
        loc = (x - p.center) @ p.R
        rel = loc / p.half  # in [-1, 1]; the face is the axis at +-1
        axis = np.argmax(np.abs(rel), axis=1)
        side = np.sign(rel[np.arange(len(rel)), axis])
        side = np.where(side == 0, 1.0, side)
        nl = np.zeros_like(loc)
        nl[np.arange(len(loc)), axis] = side
        n = nl @ p.R.T
        # face-local coordinates: the two other axes, in cyclic order
        a1 = (axis + 1) % 3
        a2 = (axis + 2) % 3
        idx = np.arange(len(loc))
        s = rel[idx, a1] * 0.5 + 0.5
        r = rel[idx, a2] * 0.5 + 0.5
        face = axis * 2 + (side > 0)
        col = face % 3
        row = face // 3
        pad = 0.02
        s = pad + (1 - 2 * pad) * np.clip(s, 0, 1)
        r = pad + (1 - 2 * pad) * np.clip(r, 0, 1)
        return n, np.stack([(col + s) / 3.0, (row + r) / 2.0], -1)
    if isinstance(p, Cylinder):
        loc = (x - p.center) @ p.R
        h = p.half_height
        radial = np.hypot(loc[:, 0], loc[:, 1]) / p.radius
        on_cap = np.abs(np.abs(loc[:, 2]) - h) < 1e-7 * max(1.0, h) + 1e-9
        on_cap &= radial < 1 - 1e-9  # rim points count as side
        nl = np.where(
            on_cap[:, None],
            np.stack([np.zeros_like(radial), np.zeros_like(radial), np.sign(loc[:, 2])], -1),
            np.stack([loc[:, 0] / p.radius, loc[:, 1] / p.radius, np.zeros_like(radial)], -1),
        )
        n = nl @ p.R.T
        side_u = np.arctan2(loc[:, 1], loc[:, 0]) / (2 * np.pi) + 0.5
        side_v = (np.clip(loc[:, 2] / h, -1, 1) * 0.5 + 0.5) * (2.0 / 3.0)
        cap_idx = (loc[:, 2] < 0).astype(np.float64)
        cs = np.clip(loc[:, 0] / p.radius, -1, 1) * 0.5 + 0.5
        cr = np.clip(loc[:, 1] / p.radius, -1, 1) * 0.5 + 0.5
        cap_u = (cap_idx + 0.04 + 0.92 * cs) / 2.0
        cap_v = 2.0 / 3.0 + (0.04 + 0.92 * cr) / 3.0
        u = np.where(on_cap, cap_u, side_u)
        v = np.where(on_cap, cap_v, side_v)
        return n, np.stack([u, v], -1)
    raise TypeError(f"unknown primitive {type(p).__name__}")


@dataclass
class Hits:
    """Result of :func:`cast_rays` for N rays.

    Attributes:
        t: [N] float64 ray parameter of the nearest hit (distance if ``dirs`` are
            unit), ``inf`` where nothing was hit.
        prim: [N] int64 primitive index into ``scene.primitives`` (material id), -1 = miss.
        normal: [N, 3] outward unit surface normal (0 where missed).
        uv: [N, 2] texture-atlas coordinate of the hit in [0, 1]^2 (0 where missed).
        points: [N, 3] world hit points (``origins + t * dirs``; 0 where missed).
    """

    t: np.ndarray
    prim: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    points: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def cast_rays(scene: Scene, origins: np.ndarray, dirs: np.ndarray, candidates: list | None = None) -> Hits:
    """Nearest intersection of each ray with the scene.

    Args:
        scene: the primitives.
        origins: [N, 3] ray origins (world), or [3] for one shared origin.
        dirs: [N, 3] ray directions (world; need not be unit, ``t`` is in units of ``|dir|``).
        candidates: optional acceleration: per primitive, an index array of the
            rays that may hit it (a conservative superset) or None for all rays.

    Returns:
        :class:`Hits` with t, prim (material id), normal, uv, points.
    """
    d = np.ascontiguousarray(np.asarray(dirs, dtype=np.float64)).reshape(-1, 3)
    o = np.asarray(origins, dtype=np.float64)
    shared = o.ndim == 1  # one origin for all rays: keep it [3] and let numpy broadcast
    if not shared:
        o = np.ascontiguousarray(np.broadcast_to(o, d.shape))
    n = len(d)
    best_t = np.full(n, np.inf)
    best_p = np.full(n, -1, dtype=np.int64)
    for i, prim in enumerate(scene.primitives):
        idx = None if candidates is None else candidates[i]
        if idx is None:
            t = intersect(prim, o, d)
            closer = t < best_t
            best_t = np.where(closer, t, best_t)
            best_p = np.where(closer, i, best_p)
        elif len(idx):
            t = intersect(prim, o if shared else o[idx], d[idx])
            closer = t < best_t[idx]
            best_t[idx[closer]] = t[closer]
            best_p[idx[closer]] = i
    normal = np.zeros((n, 3))
    uv = np.zeros((n, 2))
    for i, prim in enumerate(scene.primitives):
        sel = np.nonzero(best_p == i)[0]
        if len(sel) == 0:
            continue
        nn, uu = _surface(prim, o if shared else o[sel], d[sel], best_t[sel])
        normal[sel] = nn
        uv[sel] = uu
    hit = np.nonzero(best_p >= 0)[0]
    points = np.zeros((n, 3))
    points[hit] = (o if shared else o[hit]) + best_t[hit, None] * d[hit]
    return Hits(t=best_t, prim=best_p, normal=normal, uv=uv, points=points)

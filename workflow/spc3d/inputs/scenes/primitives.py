"""Textured ray-traced primitives, vectorised over all rays with numpy.

Arrays are **component-major**: points, directions and normals are (3, M), colours (3, M), so
every operation runs on contiguous 1-D rows (much faster than reducing over a length-3 last axis).
Every primitive answers, for M rays ``x = origin + t * dir``:

- ``intersect(origins, dirs) -> t``: (M,) hit parameter, ``inf`` on a miss (only ``t > EPS``);
  origins (3, 1) or (3, M), dirs (3, M), not necessarily unit length (``t`` in units of ``dir``);
- ``normal(points) -> (3, K)`` unit outward normal at hit points (3, K);
- ``uv(points) -> (u, v)`` texture coordinates (K,) each (one unit spans the texture image once);
- ``albedo(points, footprint) -> (3, K)`` linear RGB albedo by trilinear texture lookup;
  ``footprint`` (K,) is the world size of one sample there, which picks the mip level.

:func:`nearest` resolves occlusion (the nearest hit wins); :func:`occluded` answers shadow rays.
World convention of the built-in layouts: y up; ``v`` runs down the texture image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spc3d.inputs.scenes.textures import Texture

EPS = 1e-6
Y_AXIS = np.array([0.0, 1.0, 0.0])


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product of (3, ...) arrays (or a (3,) vector) over the first axis -> (...)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def rotate(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``M @ x`` for a (3, 3) matrix and (3, ...) points, written out (never depends on BLAS)."""
    return np.stack([M[i, 0] * x[0] + M[i, 1] * x[1] + M[i, 2] * x[2] for i in range(3)])


def yaw_matrix(deg: float) -> np.ndarray:
    """(3, 3) rotation about the world y axis by ``deg`` (x -> -z for positive angles)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True, eq=False)
class Plane:
    """A textured plane, infinite or a finite rectangle (``half`` = half extents along u, v).

    centre: (3,) a point of the plane, where uv = (0.5, 0.5); normal_vec, u_axis: (3,) unit and
    orthogonal; ``v_axis = u_axis x normal`` (for a wall facing the viewer, u right and v down).
    tile: world size (along u, v) of one span of the texture. shading: 0 = flat, 1 = full Lambert.
    """

    centre: np.ndarray
    normal_vec: np.ndarray
    u_axis: np.ndarray
    texture: Texture
    tile: tuple[float, float]
    half: tuple[float, float] = (np.inf, np.inf)
    shading: float = 0.5
    casts_shadow: bool = False
    v_axis: np.ndarray = field(init=False)

    def __post_init__(self):
        object.__setattr__(self, "v_axis", np.cross(self.u_axis, self.normal_vec))

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        denom = dot(dirs, self.normal_vec)
        ok = np.abs(denom) >= 1e-12
        t = dot(self.centre[:, None] - origins, self.normal_vec) / np.where(ok, denom, 1.0)
        ok &= t > EPS
        if np.isfinite(self.half[0]):
            rel = origins + t * dirs - self.centre[:, None]
            ok &= (np.abs(dot(rel, self.u_axis)) <= self.half[0]) & (np.abs(dot(rel, self.v_axis)) <= self.half[1])
        return np.where(ok, t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        return np.repeat(self.normal_vec[:, None], points.shape[1], axis=1)

    def uv(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = points - self.centre[:, None]
        return dot(rel, self.u_axis) / self.tile[0] + 0.5, dot(rel, self.v_axis) / self.tile[1] + 0.5

    def albedo(self, points: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        h, w = self.texture.shape
        density = max(w / self.tile[0], h / self.tile[1])  # texels per world unit
        return self.texture.sample(*self.uv(points), footprint * density)


def quad(
    centre,
    width: float,
    height: float,
    texture: Texture,
    yaw: float = 0.0,
    tile: tuple[float, float] | None = None,
    **kw,
) -> Plane:
    """Upright rectangle facing +z (towards the cameras) turned by ``yaw`` degrees about y; the
    texture spans it once (poster, card) unless ``tile`` (world size of one span) is given."""
    R = yaw_matrix(yaw)
    return Plane(
        np.asarray(centre, float), R[:, 2], R[:, 0], texture, tile or (width, height), (width / 2, height / 2), **kw
    )


def ground(y: float, texture: Texture, tile: float, **kw) -> Plane:
    """Infinite horizontal plane at height ``y`` (normal +y), texture repeated every ``tile``."""
    return Plane(np.array([0.0, y, 0.0]), Y_AXIS.copy(), np.array([1.0, 0.0, 0.0]), texture, (tile, tile), **kw)


def backdrop(z: float, texture: Texture, tile: tuple[float, float], centre_y: float = 0.0, **kw) -> Plane:
    """Infinite vertical plane at depth ``z`` facing +z (a wall or far backdrop)."""
    return Plane(
        np.array([0.0, centre_y, z]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), texture, tile, **kw
    )


@dataclass(frozen=True, eq=False)
class Sphere:
    """A UV-mapped sphere: u = longitude (turned by ``spin`` degrees about y), v = colatitude."""

    centre: np.ndarray
    radius: float
    texture: Texture
    spin: float = 0.0
    repeat: tuple[float, float] = (1.0, 1.0)
    shading: float = 1.0
    casts_shadow: bool = True

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        oc = origins - self.centre[:, None]
        a, b = dot(dirs, dirs), dot(dirs, oc)
        c = dot(oc, oc) - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t = (-b - root) / a
        t = np.where(t > EPS, t, (-b + root) / a)  # origin inside: the far root
        return np.where((disc >= 0) & (t > EPS), t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        return (points - self.centre[:, None]) / self.radius

    def uv(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = rotate(yaw_matrix(self.spin).T, self.normal(points))  # into the texture frame
        u = 0.5 + np.arctan2(q[0], q[2]) / (2 * np.pi)
        v = np.arccos(np.clip(q[1], -1.0, 1.0)) / np.pi
        return u * self.repeat[0], v * self.repeat[1]

    def albedo(self, points: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        h, w = self.texture.shape
        density = max(w * self.repeat[0] / (2 * np.pi), h * self.repeat[1] / np.pi) / self.radius
        return self.texture.sample(*self.uv(points), footprint * density)


@dataclass(frozen=True, eq=False)
class Box:
    """A box with half sizes ``half`` (3,), turned by ``yaw`` degrees about y.

    Per-face texture: the four sides use ``texture``, top and bottom ``top`` (default: the same);
    each face maps its own two local coordinates, one texture span per ``tile`` world units.
    """

    centre: np.ndarray
    half: np.ndarray
    texture: Texture
    tile: float
    yaw: float = 0.0
    top: Texture | None = None
    shading: float = 1.0
    casts_shadow: bool = True

    def _to_local(self, x: np.ndarray) -> np.ndarray:
        return rotate(yaw_matrix(self.yaw).T, x)

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        o, d = self._to_local(origins - self.centre[:, None]), self._to_local(dirs)
        tmin, tmax = np.full(d.shape[1], -np.inf), np.full(d.shape[1], np.inf)
        for a in range(3):  # slab test
            inv = 1.0 / np.where(np.abs(d[a]) < 1e-12, 1e-12, d[a])
            t1, t2 = (-self.half[a] - o[a]) * inv, (self.half[a] - o[a]) * inv
            tmin, tmax = np.maximum(tmin, np.minimum(t1, t2)), np.minimum(tmax, np.maximum(t1, t2))
        t = np.where(tmin > EPS, tmin, tmax)  # origin inside: the exit point
        return np.where((tmax >= tmin) & (t > EPS), t, np.inf)

    def _local(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local coordinates (3, K) and face axis (K,) 0/1/2 of surface points."""
        q = self._to_local(points - self.centre[:, None])
        return q, np.argmax(np.abs(q) / self.half[:, None], axis=0)

    def normal(self, points: np.ndarray) -> np.ndarray:
        q, axis = self._local(points)
        n = np.zeros_like(q)
        cols = np.arange(q.shape[1])
        n[axis, cols] = np.sign(q[axis, cols])
        return rotate(yaw_matrix(self.yaw), n)

    def uv(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        (x, y, z), axis = self._local(points)
        u = np.select([axis == 0, axis == 1], [-np.sign(x) * z, x], np.sign(z) * x)
        v = np.where(axis == 1, np.sign(y) * z, -y)  # v down the sides, towards the front on top
        return u / self.tile + 0.5, v / self.tile + 0.5

    def albedo(self, points: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        (u, v), (_, axis) = self.uv(points), self._local(points)
        out = np.empty((3, points.shape[1]))
        for tex, m in ((self.texture, axis != 1), (self.top or self.texture, axis == 1)):
            if m.any():
                out[:, m] = tex.sample(u[m], v[m], footprint[m] * tex.size / self.tile)
        return out


Primitive = Plane | Sphere | Box


def bounding_sphere(prim) -> tuple[np.ndarray, float] | None:
    """(centre (3,), radius) enclosing a finite primitive worth culling (boxes, rectangles), else None."""
    if isinstance(prim, Box):
        return prim.centre, float(np.linalg.norm(prim.half))
    if isinstance(prim, Plane) and np.isfinite(prim.half[0]):
        return prim.centre, float(np.hypot(*prim.half))
    return None


def candidates(prim, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray | None:
    """(M,) bool: rays that may hit ``prim`` (they cross its bounding sphere), or None (all may)."""
    bound = bounding_sphere(prim)
    if bound is None:
        return None
    oc = origins - bound[0][:, None]
    b = dot(dirs, oc)
    return (b * b - dot(dirs, dirs) * (dot(oc, oc) - bound[1] ** 2) >= 0) & ((b <= 0) | (dot(oc, oc) <= bound[1] ** 2))


def intersect_culled(prim, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """``prim.intersect`` (M,), exact primitive tests only on rays that cross its bounding sphere."""
    cand = candidates(prim, origins, dirs)
    if cand is None:
        return prim.intersect(origins, dirs)
    t = np.full(dirs.shape[1], np.inf)
    if cand.any():
        o = origins if origins.shape[1] == 1 else origins[:, cand]
        t[cand] = prim.intersect(o, dirs[:, cand])
    return t


def nearest(prims: tuple, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit over all primitives: t (M,) (inf where nothing is hit) and index (M,) (-1 there)."""
    best = np.full(dirs.shape[1], np.inf)
    index = np.full(dirs.shape[1], -1, dtype=np.int64)
    for k, prim in enumerate(prims):
        t = intersect_culled(prim, origins, dirs)
        closer = t < best
        best = np.where(closer, t, best)
        index[closer] = k
    return best, index


def occluded(prims: tuple, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(M,) True where a shadow-casting primitive lies along the ray (any distance > EPS)."""
    hit = np.zeros(dirs.shape[1], dtype=bool)
    for prim in prims:
        if prim.casts_shadow:
            hit |= np.isfinite(intersect_culled(prim, origins, dirs))
    return hit

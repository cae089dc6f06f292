"""Forward-facing capture rig and the ray tracer that renders a layout into LLFF-like views.

Rendering, per view and per chunk of pixel rows:

- ``ss x ss`` sub-pixel rays per pixel on a regular grid (offsets ``(k + 0.5) / ss``), averaged
  with a box filter in linear light (anti-aliasing), then sRGB-encoded (IEC 61966-2-1);
- ray directions are scaled so their camera-frame z component is 1, so the hit parameter ``t``
  *is* the z-depth of the hit in that camera;
- shading: albedo x (ambient + diffuse of one directional light x shadow visibility), mixed with a
  flat term by each primitive's ``shading`` weight (solids 1, planes lightly shaded). The light
  has a small angular size: each sub-sample of a pixel uses a slightly different light direction,
  so shadow edges come out soft after the box filter;
- depth: the z-depth of the ray through the **pixel centre** (no averaging across an occlusion
  edge, which would invent depths belonging to no surface).

Pixel centres sit at integer + 0.5 coordinates and the principal point is (W/2, H/2), matching
:mod:`spc3d.cameras`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spc3d.cameras import Cameras, look_at
from spc3d.inputs.scenes.primitives import dot, nearest, occluded, rotate
from spc3d.physics.spc import linear_to_srgb

RAYS_PER_CHUNK = 1 << 17  # bounds the working memory of one tracing step (~100 MB at most)


@dataclass(frozen=True)
class Rig:
    """A handheld forward-facing capture: camera centres on a jittered grid facing ``target``.

    centre, target: (3,) world points (mean camera centre, scene centre looked at).
    spread: (width, height) of the grid of camera centres, world units.
    jitter: position jitter as a fraction of the grid spacing; max_rot_deg: random tilt bound.
    """

    centre: tuple[float, float, float]
    target: tuple[float, float, float]
    spread: tuple[float, float]
    hfov_deg: float = 60.0
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    jitter: float = 0.3
    max_rot_deg: float = 1.5


@dataclass(frozen=True)
class Lighting:
    """One directional light (``direction`` points towards it) plus ambient, linear RGB."""

    direction: tuple[float, float, float]
    colour: tuple[float, float, float] = (0.75, 0.72, 0.66)
    ambient: tuple[float, float, float] = (0.25, 0.27, 0.31)
    softness: float = 0.05  # angular radius of the light, radians (soft shadow edges)

    @property
    def unit(self) -> np.ndarray:
        d = np.asarray(self.direction, float)
        return d / np.linalg.norm(d)

    @property
    def flat(self) -> np.ndarray:
        """Radiance factor of an unshaded surface (shading weight 0)."""
        return np.asarray(self.ambient) + 0.6 * np.asarray(self.colour)


@dataclass(frozen=True)
class Layout:
    """A built-in scene: primitives (nearest hit wins), the capture rig and the light."""

    name: str
    description: str
    primitives: tuple
    rig: Rig
    light: Lighting


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about unit ``axis`` (Rodrigues)."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def grid_offsets(views: int, spread: tuple[float, float]) -> np.ndarray:
    """(views, 2) offsets (right, up) on a rows x cols grid, swept row by row like a handheld capture."""
    rows = int(np.clip(round(np.sqrt(views * spread[1] / spread[0])), 1, views))
    cols = int(np.ceil(views / rows))
    xs = np.linspace(-0.5, 0.5, cols) if cols > 1 else np.zeros(1)
    ys = np.linspace(0.5, -0.5, rows) if rows > 1 else np.zeros(1)
    cells = [(xs[c if r % 2 == 0 else cols - 1 - c], ys[r]) for r in range(rows) for c in range(cols)]
    return np.asarray(cells[:views]) * np.asarray(spread)


def make_cameras(rig: Rig, views: int, height: int, width: int, seed: int) -> Cameras:
    """``views`` jittered forward-facing cameras (bounds left at zero: they come from the depth)."""
    rng = np.random.default_rng(seed)
    centre, target, up = (np.asarray(v, float) for v in (rig.centre, rig.target, rig.up))
    fwd = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(fwd, up) / np.linalg.norm(np.cross(fwd, up))
    cam_up = np.cross(right, fwd)
    spacing = np.asarray(rig.spread) / max(1.0, np.sqrt(views))
    jitter = rng.uniform(-1.0, 1.0, (views, 3)) * rig.jitter * np.array([spacing[0], spacing[1], spacing.mean()])
    axes = rng.normal(size=(views, 3))
    angles = np.radians(rig.max_rot_deg) * rng.uniform(0.0, 1.0, views)
    w2c = np.empty((views, 3, 4))
    for i, (dx, dy) in enumerate(grid_offsets(views, rig.spread)):
        c = centre + (dx + jitter[i, 0]) * right + (dy + jitter[i, 1]) * cam_up + jitter[i, 2] * fwd
        R = _rotation(axes[i] / np.linalg.norm(axes[i]), angles[i]) @ look_at(c, target, up)[:, :3]
        w2c[i] = np.concatenate([R, -R @ c[:, None]], axis=1)
    f = (width / 2) / np.tan(np.radians(rig.hfov_deg) / 2)
    intr = np.tile([f, f, width / 2, height / 2], (views, 1)).astype(np.float64)
    return Cameras(w2c, intr, height, width, np.zeros((views, 2)))


def pixel_rays(cams: Cameras, i: int, rows: slice, ss: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel rays of view ``i`` for image rows ``rows``.

    Returns the origin (3, 1), directions (3, M) with camera-frame z = 1, M = R*ss*W*ss ordered
    (row, sub-row, col, sub-col), and each ray's sub-sample index (sub-row, sub-col) as (2, M).
    """
    fx, fy, cx, cy = cams.intrinsics[i]
    sub = (np.arange(ss) + 0.5) / ss
    v = (np.arange(rows.start, rows.stop)[:, None] + sub[None, :]).ravel()  # (R*ss,)
    u = (np.arange(cams.width)[:, None] + sub[None, :]).ravel()  # (W*ss,)
    X, Y = np.meshgrid((u - cx) / fx, (v - cy) / fy)
    cam_dirs = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)])
    A, B = np.meshgrid(np.tile(np.arange(ss), cams.width), np.tile(np.arange(ss), rows.stop - rows.start))
    dirs = rotate(cams.w2c[i, :, :3].T, cam_dirs)  # camera -> world: R^T
    return cams.centers[i][:, None], dirs, np.stack([B.ravel(), A.ravel()])


def light_directions(light: Lighting, sub: np.ndarray, ss: int) -> np.ndarray:
    """(3, M) unit light directions spread over the light's disc by sub-sample index (2, M)."""
    L = light.unit
    e1 = np.cross(L, [0.0, 0.0, 1.0]) if abs(L[2]) < 0.9 else np.cross(L, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(L, e1)
    off = ((sub + 0.5) / ss * 2.0 - 1.0) * light.softness if ss > 1 else np.zeros(sub.shape)
    dirs = L[:, None] + off[1] * e1[:, None] + off[0] * e2[:, None]
    return dirs / np.sqrt(dot(dirs, dirs))


def surface(
    prims: tuple, points: np.ndarray, unit: np.ndarray, ends: np.ndarray, footprint: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normals facing the viewer (3, M), albedo (3, M) and shading weight (M,) at hit points (3, M).

    The rays are grouped by primitive: primitive k was hit by rays ``ends[k]:ends[k + 1]``.
    unit: (3, M) unit ray directions; footprint: (M,) world size of a sample at the hit for a
    surface facing the ray (grown at grazing angles here).
    """
    normals, albedo, weight = np.empty_like(points), np.empty_like(points), np.empty(points.shape[1])
    for k, prim in enumerate(prims):
        m = slice(ends[k], ends[k + 1])
        if m.start == m.stop:
            continue
        n = prim.normal(points[:, m])
        cos = dot(n, unit[:, m])
        normals[:, m] = n * np.where(cos > 0, -1.0, 1.0)  # two-sided: face the viewer
        weight[m] = prim.shading
        albedo[:, m] = prim.albedo(points[:, m], footprint[m] / np.maximum(np.abs(cos), 0.2))
    return normals, albedo, weight


def shade(layout: Layout, origin: np.ndarray, dirs: np.ndarray, sub: np.ndarray, ss: int, focal: float) -> np.ndarray:
    """Linear radiance (3, M) of rays (3, M) from ``origin`` (3, 1); every ray must hit something."""
    prims = layout.primitives
    t, index = nearest(prims, origin, dirs)
    if not np.isfinite(t).all():
        raise RuntimeError(f"layout {layout.name!r}: some rays hit nothing; enlarge its backdrop")
    order = np.argsort(index, kind="stable")  # group rays by primitive (contiguous slices)
    ends = np.searchsorted(index[order], np.arange(len(prims) + 1))
    t, dirs, sub = t[order], np.take(dirs, order, axis=1), np.take(sub, order, axis=1)
    points = origin + t * dirs
    unit = dirs / np.sqrt(dot(dirs, dirs))
    normals, albedo, weight = surface(prims, points, unit, ends, t / (focal * ss))
    L = light_directions(layout.light, sub, ss)
    lambert = np.maximum(dot(normals, L), 0.0)
    lit = lambert > 0
    start = points[:, lit] + normals[:, lit] * (1e-4 * (1.0 + t[lit]))
    lambert[lit] *= ~occluded(prims, start, L[:, lit])
    light = np.asarray(layout.light.ambient)[:, None] + np.asarray(layout.light.colour)[:, None] * lambert
    radiance = albedo * ((1 - weight) * layout.light.flat[:, None] + weight * light)
    out = np.empty_like(radiance)
    out[:, order] = radiance
    return out


def render_view(layout: Layout, cams: Cameras, i: int, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """View ``i``: sRGB image (H, W, 3) float32 in [0, 1] and z-depth (H, W) float32."""
    H, W = cams.height, cams.width
    image, depth = np.empty((H, W, 3)), np.empty((H, W))
    step = max(1, RAYS_PER_CHUNK // (W * ss * ss))
    for r0 in range(0, H, step):
        rows = slice(r0, min(H, r0 + step))
        origin, dirs, sub = pixel_rays(cams, i, rows, ss)
        radiance = shade(layout, origin, dirs, sub, ss, cams.intrinsics[i, 0])
        image[rows] = radiance.reshape(3, -1, ss, W, ss).mean(axis=(2, 4)).transpose(1, 2, 0)
        _, centre_dirs, _ = pixel_rays(cams, i, rows, 1)
        depth[rows] = nearest(layout.primitives, origin, centre_dirs)[0].reshape(-1, W)
    return linear_to_srgb(image).astype(np.float32), depth.astype(np.float32)


def depth_bounds(depth: np.ndarray) -> np.ndarray:
    """(near, far) of one view's depth (H, W), like LLFF's bounds from COLMAP point depths:
    0.9 x the 1st and 1.1 x the 99th percentile."""
    lo, hi = np.percentile(depth, [1.0, 99.0])
    return np.array([0.9 * lo, 1.1 * hi])

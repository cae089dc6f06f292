"""Deterministic procedural forward-facing captures in the LLFF layout (the built-in scenes).

No dataset can be downloaded, so the project's default scenes are ray traced: textured planes,
spheres and boxes (photographic textures from scikit-image's sample images) seen by ``views``
cameras on a jittered handheld-like grid, exactly like an LLFF capture: sRGB images, z-depth,
OpenCV world-to-camera poses with centred principal points and per-view (near, far) bounds taken
from the rendered depth (0.9 x 1st and 1.1 x 99th percentile, as LLFF does from COLMAP points).

Public API
----------
``LAYOUTS``                 name -> layout builder (``() -> Layout``)
``render_scene(...)``       -> :class:`spc3d.llff.SceneData` (images, depths, cameras, names, meta)
``write_builtin_scene(...)`` renders and writes the canonical LLFF folder via ``llff.write_scene``
``content(layout)``          the texture sources (photographs, procedural patterns) a layout shows
``shared_content(a, b)``     sources that layouts ``a`` and ``b`` have in common (must be none
                            between training and evaluation scenes)

Identical arguments give bit-identical images; ``seed`` only moves the cameras (grid jitter and a
small random tilt), the scene content is fixed per layout.
"""

from __future__ import annotations

import os
import time

import numpy as np

from spc3d.cameras import Cameras
from spc3d.inputs.scenes.layouts import LAYOUT_BUILDERS, LAYOUT_ROLES
from spc3d.inputs.scenes.render import Layout, depth_bounds, make_cameras, render_view
from spc3d.llff import SceneData, write_scene

LAYOUTS = dict(LAYOUT_BUILDERS)
MAX_VIEWS = 200

__all__ = ["LAYOUTS", "LAYOUT_ROLES", "Layout", "content", "render_scene", "shared_content", "write_builtin_scene"]


def content(layout: str) -> frozenset[str]:
    """Texture sources of every primitive of ``layout`` (sides and tops; plain paint is no content).

    Cheap: a layout is assembled without building any texture pyramid.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; available layouts: {', '.join(sorted(LAYOUTS))}")
    textures = [t for prim in LAYOUTS[layout]().primitives for t in (prim.texture, getattr(prim, "top", None)) if t]
    return frozenset(t.name for t in textures if t.name != "solid")


def shared_content(train: list[str], evaluate: list[str]) -> dict[str, tuple[list[str], list[str]]]:
    """Texture sources seen by a layout of ``train`` and one of ``evaluate``: source -> (train
    layouts, evaluation layouts) showing it. Names that are not built-in layouts are skipped."""
    a = {n: content(n) for n in train if n in LAYOUTS}
    b = {n: content(n) for n in evaluate if n in LAYOUTS}
    common = set().union(*a.values()) & set().union(*b.values()) if a and b else set()
    return {src: ([n for n in a if src in a[n]], [n for n in b if src in b[n]]) for src in sorted(common)}


def _check_args(layout: str, height: int, width: int, views: int, supersample: int) -> None:
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; available layouts: {', '.join(sorted(LAYOUTS))}")
    for name, value, lo, hi in (
        ("views", views, 2, MAX_VIEWS),
        ("height", height, 8, None),
        ("width", width, 8, None),
        ("supersample", supersample, 1, None),
    ):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        if value < lo or (hi is not None and value > hi):
            bound = f"in [{lo}, {hi}]" if hi is not None else f">= {lo}"
            raise ValueError(f"{name} must be {bound}, got {value}")


def render_scene(
    layout: str, height: int, width: int, views: int = 24, supersample: int = 3, seed: int = 0
) -> SceneData:
    """Render built-in ``layout`` as ``views`` forward-facing views of (height, width) pixels.

    Returns SceneData with images (N, H, W, 3) float32 sRGB in [0, 1], depths (N, H, W) float32
    (z in the camera frame, of the ray through each pixel centre), cameras (OpenCV w2c, fx = fy,
    principal point (W/2, H/2), bounds from the depth), names ``image000``... and meta
    {"layout", "description", "seed", "settings"}.
    """
    _check_args(layout, height, width, views, supersample)
    scene = LAYOUTS[layout]()
    cams = make_cameras(scene.rig, views, height, width, seed)
    images = np.empty((views, height, width, 3), np.float32)
    depths = np.empty((views, height, width), np.float32)
    for i in range(views):
        images[i], depths[i] = render_view(scene, cams, i, supersample)
    bounds = np.stack([depth_bounds(d) for d in depths])
    cams = Cameras(cams.w2c, cams.intrinsics, height, width, bounds)
    settings = {
        "height": height,
        "width": width,
        "views": views,
        "supersample": supersample,
        "hfov_deg": scene.rig.hfov_deg,
        "depth": "z-depth of the pixel-centre ray",
    }
    meta = {"layout": layout, "description": scene.description, "seed": seed, "settings": settings}
    return SceneData(images, cams, [f"image{i:03d}" for i in range(views)], depths, meta)


def write_builtin_scene(
    layout: str,
    out_dir: str | os.PathLike,
    height: int,
    width: int,
    views: int = 24,
    supersample: int = 3,
    seed: int = 0,
) -> SceneData:
    """Render ``layout`` and write it as the canonical LLFF scene folder ``out_dir`` (atomically).

    ``scene.json`` records {"source": "builtin", "layout", "seed", "settings", "wall_s"}.
    Returns the rendered scene.
    """
    start = time.perf_counter()
    scene = render_scene(layout, height, width, views, supersample, seed)
    record = {
        "source": "builtin",
        "layout": layout,
        "seed": seed,
        "settings": scene.meta["settings"],
        "wall_s": round(time.perf_counter() - start, 3),
    }
    write_scene(out_dir, scene, record)
    return scene

"""Turn a scene specification into the canonical scene folder (``results/scenes/{scene}``).

A spec is a plain dict, as the workflow builds it from the config:

    {"kind": "builtin", "layout": "courtyard", "height": 96, "width": 128, "views": 24,
     "supersample": 3, "seed": 0}
    {"kind": "llff", "path": "../shared/data/llff/fern", "factor": 8, "width": 128}
    {"kind": "colmap", "path": "data/garden", "width": 128, "factor": 1, "undistort": False}

All end as the same LLFF-layout folder at the working resolution (see :mod:`spc3d.llff`), so every
later step reads one format whatever the origin of the scene. ``factor`` (default 1) and
``undistort`` (default False) of a COLMAP-format scene are optional (see
:func:`spc3d.colmap_scene.load_colmap`); :func:`scene_layout` tells the two folder layouts apart.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

from . import llff

log = logging.getLogger(__name__)


def prepare_scene(spec: dict, out_dir: str | os.PathLike) -> None:
    """Render or import the scene described by ``spec`` into ``out_dir`` (atomically)."""
    kind = spec.get("kind")
    if kind == "builtin":
        from .scenes import write_builtin_scene

        keys = ("height", "width", "views", "supersample", "seed")
        write_builtin_scene(spec["layout"], out_dir, **{k: spec[k] for k in keys})
    elif kind == "llff":
        import_llff(spec["path"], out_dir, spec["factor"], spec["width"])
    elif kind == "colmap":
        import_colmap(
            spec["path"], out_dir, spec["width"], factor=spec.get("factor", 1), undistort=spec.get("undistort", False)
        )
    else:
        raise ValueError(f"scene spec kind must be 'builtin', 'llff' or 'colmap', got {kind!r} in {spec}")


def named_spec(name: str, width: int, llff_root: str | os.PathLike) -> dict | None:
    """The spec of a built-in layout, or else of the LLFF folder ``llff_root/name``, at ``width`` with
    the default settings (built-in: 4:3, 24 views, 3x supersampling, seed 0; LLFF: ``images_8``);
    None when ``name`` is neither. For tools and benchmarks; the workflow builds specs from its config
    (:func:`spc3d.workflow.scene_specs`)."""
    from .scenes import LAYOUTS

    if name in LAYOUTS:
        return {
            "kind": "builtin",
            "layout": name,
            "height": width * 3 // 4,
            "width": width,
            "views": 24,
            "supersample": 3,
            "seed": 0,
        }
    path = Path(llff_root) / name
    return {"kind": "llff", "path": str(path), "factor": 8, "width": width} if path.is_dir() else None


def import_llff(src: str | os.PathLike, out_dir: str | os.PathLike, factor: int, width: int) -> None:
    """Read a real LLFF folder at ``factor``, area-downscale to ``width``, write it canonically."""
    t0 = time.perf_counter()
    scene = llff.load_llff(src, factor=factor, width=width)
    log.info("loaded %d views of %s at %dx%d", len(scene.names), src, scene.cameras.width, scene.cameras.height)
    record = {
        "source": "llff",
        "path": str(src),
        "factor": factor,
        "settings": {"factor": factor, "width": width},
        "seed": None,
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    llff.write_scene(out_dir, scene, record)


def import_colmap(
    src: str | os.PathLike, out_dir: str | os.PathLike, width: int, factor: int = 1, undistort: bool = False
) -> None:
    """Read a COLMAP-format scene (images/ + sparse/0) at ``factor``, area-downscale to ``width``,
    write it canonically (with ``intrinsics.npy`` when LLFF's hwf cannot hold the intrinsics)."""
    from .colmap_scene import load_colmap

    t0 = time.perf_counter()
    scene = load_colmap(src, factor=factor, width=width, undistort=undistort)
    log.info(
        "loaded %d views of %s (COLMAP %s) at %dx%d",
        len(scene.names),
        src,
        scene.meta["colmap"]["format"],
        scene.cameras.width,
        scene.cameras.height,
    )
    record = {
        "source": "colmap",
        "path": str(src),
        "factor": factor,
        "settings": {"factor": factor, "width": width, "undistort": undistort},
        "seed": None,
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    llff.write_scene(out_dir, scene, record)


LAYOUTS = {
    "llff": "poses_bounds.npy + images/ (or images_N/)",
    "colmap": "images/ + sparse/0/ (cameras, images, points3D as .bin or .txt)",
}


def scene_layout(folder: str | os.PathLike) -> str:
    """``"llff"`` or ``"colmap"``: the layout of a real scene folder (see :data:`LAYOUTS`).

    A folder with both (NeRF's LLFF downloads ship sparse/0 beside poses_bounds.npy) reads as LLFF,
    and the log says so; kind "colmap" reads its sparse/0 instead. A folder with neither is refused
    with what it holds.
    """
    from .colmap_scene import find_model, listing

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"scene folder {folder} does not exist")
    is_llff = (folder / "poses_bounds.npy").is_file() and any(p.is_dir() for p in folder.glob("images*"))
    is_colmap = (folder / "images").is_dir() and find_model(folder) is not None
    if is_llff and is_colmap:
        log.info(
            "%s holds an LLFF (poses_bounds.npy) and a COLMAP (%s) layout: read as LLFF; use kind 'colmap' "
            "to read the COLMAP model instead",
            folder,
            find_model(folder).relative_to(folder),
        )
    if is_llff or is_colmap:
        return "llff" if is_llff else "colmap"
    sparse = folder / "sparse" / "0" if (folder / "sparse" / "0").is_dir() else folder / "sparse"
    found = listing(folder) + (f"; {sparse.relative_to(folder)}/ holds: {listing(sparse)}" if sparse.is_dir() else "")
    raise FileNotFoundError(
        f"{folder} is neither an LLFF scene ({LAYOUTS['llff']}) nor a COLMAP-format scene "
        f"({LAYOUTS['colmap']}); it holds: {found}"
    )

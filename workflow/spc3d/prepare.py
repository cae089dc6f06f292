"""Turn a scene specification into the canonical scene folder (``results/scenes/{scene}``).

A spec is a plain dict, as the workflow builds it from the config:

    {"kind": "builtin", "layout": "courtyard", "height": 96, "width": 128, "views": 24,
     "supersample": 3, "seed": 0}
    {"kind": "llff", "path": "../shared/data/llff/fern", "factor": 8, "width": 128}

Both end as the same LLFF-layout folder at the working resolution (see :mod:`spc3d.llff`), so every
later step reads one format whatever the origin of the scene.
"""

from __future__ import annotations

import logging
import os
import time

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
    else:
        raise ValueError(f"scene spec kind must be 'builtin' or 'llff', got {kind!r} in {spec}")


def import_llff(src: str | os.PathLike, out_dir: str | os.PathLike, factor: int, width: int) -> None:
    """Read a real LLFF folder at ``factor``, area-downscale to ``width``, write it canonically."""
    t0 = time.perf_counter()
    scene = llff.load_llff(src, factor=factor, width=width)
    log.info("loaded %d views of %s at %dx%d", len(scene.names), src, scene.cameras.width, scene.cameras.height)
    record = {"source": "llff", "path": str(src), "factor": factor,
              "settings": {"factor": factor, "width": width}, "seed": None,
              "wall_s": round(time.perf_counter() - t0, 3)}
    llff.write_scene(out_dir, scene, record)

"""A scene's inputs, which every combination reads: its folder (rule ``prepare_scene``) and its SPC
frames (rule ``simulate_scene``).

**The scene folder** (``results/scenes/{scene}``) comes from a scene specification, a plain dict
as the workflow builds it from the config:

    {"kind": "builtin", "layout": "courtyard", "height": 96, "width": 128, "views": 24,
     "supersample": 3, "seed": 0}
    {"kind": "llff", "path": "../shared/data/llff/fern", "factor": 8, "width": 128}
    {"kind": "colmap", "path": "data/garden", "width": 128, "factor": 1, "undistort": False}
    {"kind": "capture", "path": "data/my_spad_scene", "max_features": 4096, "seed": 0, "overrides": {"q": 0.3}}

All end as the same LLFF-layout folder at the working resolution (see :mod:`spc3d.llff`), so every
later step reads one format whatever the origin of the scene. ``factor`` (default 1) and
``undistort`` (default False) of a COLMAP-format scene are optional (see
:func:`spc3d.inputs.colmap_scene.load_colmap`); :func:`scene_layout` tells the two folder layouts apart.
A captured SPAD scene (:mod:`spc3d.captures.folders`) keeps its sensor's size, and its SPC folder holds
its own frames, read instead of simulated (:mod:`spc3d.captures.importing`).

**The SPC frames** (``results/spc/{scene}/``) are simulated from the scene's views, with their
physics inversions, one file per view and kind, stems as the scene's images:

    frames/{name}.npz    K bit-packed binary frames (K, H, W, 3) — the raw measurement
    binary/{name}.png    frame 0 as an 8-bit 0/255 image (the paper's K = 1 input, source ``none``)
    capture/{name}.png   one frame at the capture resolution, area-averaged to the working size:
                         the fraction k/S² of ones among each pixel's S x S sub-pixels, 16-bit
                         (S = ``capture_factor``; S = 1: frame 0 itself), see :func:`capture_frame`
    average/{name}.png   the K-frame mean S/K, 16-bit (what a user sees by averaging frames)
    mle/{name}.exr       the K-frame maximum-likelihood flux estimate, photons/s (linear)
    spc.json             physics parameters, the (calibrated) flux scale, seed, timing, statistics

The flux scale is the simulated camera's exposure, set from the scene's *training* views (as an
auto-exposing camera meters what it captures for training; the scored, held-out views of
:func:`spc3d.cameras.split_views` do not set it). ``spc.json`` names those views
(``held_out_views``) and counts the views metered (``metered_views``), and reports the exposure
as the camera would, in its ``exposure`` block (:func:`spc3d.physics.record.exposure_record`:
photons per pixel and frame at scene linear intensity 1, and whether the camera chose it): a SPAD
user knows the exposure each capture was taken with, so every non-oracle row's display level
comes from it and the scene's own photons (:mod:`spc3d.inputs.exposure`); a dark scene then
displays dark. ``spc.json``'s ``mean_mle_psnr_exact_gain_db`` (the MLE of all K frames shown at
that exposure) is a diagnostic of the simulation for the data summary, not a table row.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.physics import spc
from spc3d.physics.flux_scale import calibrate_flux_scale, dark_floor
from spc3d.physics.record import check_capture_factor, exposure_record, frame_warnings
from spc3d.pixels import psnr

log = logging.getLogger(__name__)


def prepare_scene(spec: dict, out_dir: str | os.PathLike) -> None:
    """Render or import the scene described by ``spec`` into ``out_dir`` (atomically)."""
    kind = spec.get("kind")
    if kind == "builtin":
        from spc3d.inputs.scenes import write_builtin_scene

        keys = ("height", "width", "views", "supersample", "seed")
        write_builtin_scene(spec["layout"], out_dir, **{k: spec[k] for k in keys})
    elif kind == "llff":
        import_llff(spec["path"], out_dir, spec["factor"], spec["width"])
    elif kind == "colmap":
        import_colmap(
            spec["path"], out_dir, spec["width"], factor=spec.get("factor", 1), undistort=spec.get("undistort", False)
        )
    else:  # a capture's scene folder: spc3d.captures.importing.import_capture_scene (a room above)
        raise ValueError(f"scene spec kind must be 'builtin', 'llff' or 'colmap', got {kind!r} in {spec}")


def named_spec(name: str, width: int, llff_root: str | os.PathLike) -> dict | None:
    """The spec of a built-in layout, or else of the LLFF folder ``llff_root/name``, at ``width`` with
    the default settings (built-in: 4:3, 24 views, 3x supersampling, seed 0; LLFF: ``images_8``);
    None when ``name`` is neither. For tools and benchmarks; the workflow builds specs from its config
    (:func:`spc3d.jobs.scene_specs`)."""
    from spc3d.inputs.scenes import LAYOUTS

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
    files, poses_bounds = llff.llff_contents(src, factor)
    record["warnings"] = llff.rig_warnings(poses_bounds, files)  # simulate_scene carries them to the captions
    for warning in record["warnings"]:
        log.warning("%s: %s", src, warning)
    llff.write_scene(out_dir, scene, record)


def import_colmap(
    src: str | os.PathLike, out_dir: str | os.PathLike, width: int, factor: int = 1, undistort: bool = False
) -> None:
    """Read a COLMAP-format scene (images/ + sparse/0) at ``factor``, area-downscale to ``width``,
    write it canonically (with ``intrinsics.npy`` when LLFF's hwf cannot hold the intrinsics)."""
    from spc3d.inputs.colmap_scene import load_colmap

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
    from spc3d.inputs.colmap_scene import find_model, listing

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


def resolve_flux_scale(
    images: np.ndarray, params: spc.SPCParams, flux_scale: float | None, target_detection: float
) -> tuple[float, bool]:
    """The given flux scale, or one calibrated on ``images`` to the mean detection target."""
    if flux_scale is not None:
        if not np.isfinite(flux_scale) or flux_scale <= 0:
            raise ValueError(f"spc.flux_scale={flux_scale}: must be a positive number (or null to calibrate)")
        return float(flux_scale), False
    return calibrate_flux_scale(images, params, target_detection), True


def simulate_view(
    srgb: np.ndarray, flux_scale: float, params: spc.SPCParams, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """All products of one view: frames (K,H,W,3) bool, binary, average, mle (linear flux)."""
    frames = spc.simulate_frames(srgb, flux_scale, params, rng)
    S = frames.sum(0, dtype=np.int64)
    return {
        "frames": frames,
        "binary": frames[0].astype(np.float32),
        "average": (S / params.frames).astype(np.float32),
        "mle": spc.mle_flux(S, params.frames, params).astype(np.float32),
    }


def capture_frame(
    srgb: np.ndarray, flux_scale: float, params: spc.SPCParams, capture_factor: int, rng: np.random.Generator
) -> np.ndarray:
    """One binary frame at ``capture_factor`` (S) x the working resolution per axis, area-averaged
    back: (H, W, 3) float32 fractions k/S² of ones among each pixel's S x S sub-pixels.

    The paper's single-stage baselines most plausibly saw full-resolution binary frames that their
    loaders area-downsampled. The working image is the only image there is, so the S x S sub-pixels
    of a pixel share its flux (nearest upsampling); each draws its own bit, with the main frames'
    physics (:func:`spc3d.physics.spc.simulate_frames`, one frame, same flux scale and mode) from ``rng``.
    Drawn in bands of rows, so memory stays bounded at large S.
    """
    S = check_capture_factor(capture_factor)
    one = dataclasses.replace(params, frames=1)
    h, w, c = srgb.shape
    band = max(1, 2**22 // (w * S * S * c))  # working rows per draw: ~4M sub-pixel values
    out = np.empty((h, w, c), np.float32)
    for r in range(0, h, band):
        rows = srgb[r : r + band]
        fine = np.repeat(np.repeat(rows, S, axis=0), S, axis=1)  # (rows*S, W*S, C)
        bits = spc.simulate_frames(fine, flux_scale, one, rng)[0]
        k = bits.reshape(len(rows), S, w, S, c).sum((1, 3), dtype=np.int64)
        out[r : r + band] = k / (S * S)
    return out


def capture_rng(seed: int, scene: str, view: int) -> np.random.Generator:
    """The capture frame's stream: fixed by (seed, scene, view), apart from the main frames' own."""
    return spc.view_rng(seed, f"{scene}/capture", view)


def write_view(out: Path, name: str, products: dict[str, np.ndarray]) -> None:
    packed, shape = spc.pack_frames(products["frames"])
    io.save_frames(out / "frames" / f"{name}.npz", packed, shape)
    io.write_image(out / "binary" / f"{name}.png", products["binary"])
    io.write_image(out / "capture" / f"{name}.png", products["capture"], bits=16)
    io.write_image(out / "average" / f"{name}.png", products["average"], bits=16)
    io.write_image(out / "mle" / f"{name}.exr", products["mle"])


def simulate_scene(
    scene_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    params: spc.SPCParams,
    flux_scale: float | None = None,
    target_detection: float = 0.5,
    seed: int = 0,
    capture_factor: int = 1,
) -> dict:
    """Simulate every view of a canonical scene folder into ``out_dir`` (atomically); return the record.

    A calibrated flux scale (``flux_scale`` None) is metered on the training views only (the
    held-out views of :func:`spc3d.cameras.split_views` are scored and must not set the exposure).
    ``capture_factor``: S of the capture frame (:func:`capture_frame`; 1: frame 0).
    """
    t0 = time.perf_counter()
    S = check_capture_factor(capture_factor)
    scene = llff.read_scene(scene_dir)
    name = Path(scene_dir).name
    train, test = split_views(len(scene.names))
    scale, calibrated = resolve_flux_scale(scene.images[train], params, flux_scale, target_detection)
    log.info("%s: flux_scale %.4g photons/s (%s)", name, scale, "calibrated" if calibrated else "given")
    stats = []
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i, view in enumerate(tqdm(scene.names, desc=f"spc {name}", unit="view")):
            products = simulate_view(scene.images[i], scale, params, spc.view_rng(seed, name, i))
            products["capture"] = (
                products["binary"]
                if S == 1
                else capture_frame(scene.images[i], scale, params, S, capture_rng(seed, name, i))
            )
            write_view(tmp, view, products)
            stats.append(view_stats(scene.images[i], products, scale))
        record = {
            "scene": name,
            "params": dataclasses.asdict(params),
            "exposure": exposure_record(
                params.q * params.exposure_s * scale,
                "auto" if calibrated else "fixed",
                target_detection=target_detection if calibrated else None,
                metered_views=len(train) if calibrated else None,
            ),
            "flux_scale": scale,
            "flux_scale_calibrated": calibrated,
            "target_detection": target_detection if calibrated else None,
            "metered_views": len(train) if calibrated else None,
            "held_out_views": [scene.names[i] for i in test],
            "capture_factor": S,
            "seed": seed,
            "views": len(scene.names),
            **summarise(stats),
            "wall_s": round(time.perf_counter() - t0, 3),
        }
        # The scene's own warnings (an LLFF folder's implausible poses: spc3d.llff.rig_warnings) join
        # the frames' here: spc.json's warnings are what the tables' captions name.
        scene_warnings = list(scene.meta.get("warnings") or [])
        record["warnings"] = scene_warnings + frame_warnings(record["mean_detection_rate"], dark_floor(params))
        for warning in record["warnings"]:
            log.warning("%s: %s", name, warning)
        io.write_json(tmp / "spc.json", record)
    return record


def view_stats(gt_srgb: np.ndarray, products: dict[str, np.ndarray], flux_scale: float) -> dict[str, float]:
    exact = spc.linear_to_srgb(np.clip(products["mle"] / flux_scale, 0.0, 1.0))  # diagnostic: the exact gain
    return {
        "detection_rate": float(products["binary"].mean()),
        "saturated_fraction": float((products["average"] >= 1.0).mean()),
        "mle_psnr_exact_gain_db": psnr(exact, gt_srgb),
    }


def summarise(stats: list[dict[str, float]]) -> dict[str, float]:
    """Means over views of :func:`view_stats` (``mean_`` prefixed)."""
    return {f"mean_{k}": float(np.mean([s[k] for s in stats])) for k in stats[0]}

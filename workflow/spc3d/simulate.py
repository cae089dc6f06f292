"""Simulate the SPC frames of a scene folder (the ``simulate_scene`` rule), with their physics inversions.

Output folder (``results/spc/{scene}/``), one file per view and kind, stems as the scene's images:

    frames/{name}.npz    K bit-packed binary frames (K, H, W, 3) — the raw measurement
    binary/{name}.png    frame 0 as an 8-bit 0/255 image (the paper's K = 1 input, source ``none``)
    average/{name}.png   the K-frame mean S/K, 16-bit (what a user sees by averaging frames)
    mle/{name}.exr       the K-frame maximum-likelihood flux estimate, photons/s (linear)
    spc.json             physics parameters, the (calibrated) flux scale, seed, timing, statistics

The flux scale is the simulated camera's exposure, set from the scene (as an auto-exposing camera
does); nothing downstream of a non-oracle row reads it: the MLE rows' display gain is metered from
the frames (:mod:`spc3d.exposure`). ``spc.json``'s ``mean_mle_psnr_exact_gain_db`` (the MLE shown
at that exact gain) is a diagnostic of the simulation for the data summary, not a table row.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import io, llff, spc
from .flux_scale import calibrate_flux_scale
from .metrics import psnr

log = logging.getLogger(__name__)


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


def write_view(out: Path, name: str, products: dict[str, np.ndarray]) -> None:
    packed, shape = spc.pack_frames(products["frames"])
    io.save_frames(out / "frames" / f"{name}.npz", packed, shape)
    io.write_image(out / "binary" / f"{name}.png", products["binary"])
    io.write_image(out / "average" / f"{name}.png", products["average"], bits=16)
    io.write_image(out / "mle" / f"{name}.exr", products["mle"])


def simulate_scene(
    scene_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    params: spc.SPCParams,
    flux_scale: float | None = None,
    target_detection: float = 0.5,
    seed: int = 0,
) -> dict:
    """Simulate every view of a canonical scene folder into ``out_dir`` (atomically); return the record."""
    t0 = time.perf_counter()
    scene = llff.read_scene(scene_dir)
    name = Path(scene_dir).name
    scale, calibrated = resolve_flux_scale(scene.images, params, flux_scale, target_detection)
    log.info("%s: flux_scale %.4g photons/s (%s)", name, scale, "calibrated" if calibrated else "given")
    stats = []
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i, view in enumerate(tqdm(scene.names, desc=f"spc {name}", unit="view")):
            products = simulate_view(scene.images[i], scale, params, spc.view_rng(seed, name, i))
            write_view(tmp, view, products)
            stats.append(view_stats(scene.images[i], products, scale))
        record = {
            "scene": name,
            "params": dataclasses.asdict(params),
            "flux_scale": scale,
            "flux_scale_calibrated": calibrated,
            "target_detection": target_detection if calibrated else None,
            "seed": seed,
            "views": len(scene.names),
            **summarise(stats),
            "wall_s": round(time.perf_counter() - t0, 3),
        }
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


def read_spc_record(spc_dir: str | os.PathLike) -> dict:
    return io.read_json(Path(spc_dir) / "spc.json")


def params_from_record(record: dict) -> spc.SPCParams:
    return spc.SPCParams(**record["params"])

"""LLFF-style augmentation of training views (the paper's zoom, rotation, shear and flip).

Each sample picks a training view of a training scene (not one of its held-out views, every 8th:
they validate stage 1) and one random affine map about the image centre,

    A = C · Flip · Rot(θ) · Shear(γ) · Zoom(s) · C⁻¹,   s log-uniform, θ, γ uniform, flip with p,

warped in linear light (so edges blend as light does) with reflected borders (no black corners
that a translator would learn), saved as 8-bit sRGB. The SPC frames of the pair are simulated
from exactly that saved image with the scene's flux scale, so pairs are pixel-aligned and at the
scene's photon level. Everything is deterministic by (seed, scene, sample index). The same maps
(:func:`sample_params`, :func:`warp_linear`) draw stage 1's online batches (:mod:`spc3d.translate.online`).

Output (``results/augment/{scene}/``): ``rgb/{i:05d}.png``, ``frames/{i:05d}.npz`` (K packed
frames), ``binary/{i:05d}.png`` (frame 0) and ``augment.json`` (every sample's parameters).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from skimage.transform import AffineTransform, warp
from tqdm import tqdm

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.physics import spc
from spc3d.physics.record import camera_exposure, exposure_record, params_from_record, read_spc_record
from spc3d.specs.translators import AugmentSettings

log = logging.getLogger(__name__)


def sample_params(rng: np.random.Generator, s: AugmentSettings) -> dict:
    """One random draw of the affine parameters."""
    return {
        "zoom": float(np.exp(rng.uniform(np.log(s.zoom[0]), np.log(s.zoom[1])))),
        "rotation_deg": float(rng.uniform(-s.rotation_deg, s.rotation_deg)),
        "shear_deg": float(rng.uniform(-s.shear_deg, s.shear_deg)),
        "flip": bool(rng.random() < s.flip_prob),
    }


def affine_matrix(p: dict, height: int, width: int) -> np.ndarray:
    """(3, 3) map from source to output pixel coordinates (x, y) for the parameters ``p``.

    Coordinates are scikit-image's (pixel centres at integers), so the image centre is at
    ((W - 1) / 2, (H - 1) / 2) and a flip maps column x to W - 1 - x exactly.
    """
    cx, cy = (width - 1) / 2, (height - 1) / 2
    c = np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1.0]])
    c_inv = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]])
    core = AffineTransform(
        scale=p["zoom"], rotation=np.radians(p["rotation_deg"]), shear=np.radians(p["shear_deg"])
    ).params
    flip = np.diag([-1.0 if p["flip"] else 1.0, 1.0, 1.0])
    return c @ flip @ core @ c_inv


def warp_linear(linear: np.ndarray, p: dict, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Warp a linear-light (H, W, C) image by the parameters ``p`` (bilinear, reflected borders).

    ``window = (y, x, h, w)`` computes only that window of the warped image (the same pixels as
    cropping the full result: the map and the borders stay those of the whole image), float64.
    """
    height, width = linear.shape[:2]
    inverse = AffineTransform(matrix=affine_matrix(p, height, width)).inverse
    shape = None
    if window is not None:
        y, x, h, w = window
        inverse = AffineTransform(matrix=inverse.params @ np.array([[1.0, 0, x], [0, 1.0, y], [0, 0, 1.0]]))
        shape = (h, w)
    return warp(linear, inverse, output_shape=shape, order=1, mode="reflect", preserve_range=True)


def augment_image(srgb: np.ndarray, p: dict) -> np.ndarray:
    """Warp an sRGB (H, W, 3) image by the parameters ``p`` (in linear light, reflected borders)."""
    lin = warp_linear(spc.srgb_to_linear(srgb), p)
    return spc.linear_to_srgb(np.clip(lin, 0.0, 1.0)).astype(np.float32)


def augment_scene(
    scene_dir: str | os.PathLike,
    spc_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    count: int,
    settings: AugmentSettings,
    seed: int = 0,
) -> dict:
    """Write ``count`` augmented (RGB, binary frames) pairs of one training scene (atomically)."""
    t0 = time.perf_counter()
    scene, name = llff.read_scene(scene_dir), Path(scene_dir).name
    spc_record = read_spc_record(spc_dir)
    params, flux_scale = params_from_record(spc_record), spc_record["flux_scale"]
    views, _ = split_views(len(scene.names))  # the held-out views validate stage 1 (translate.validate)
    samples = []
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i in tqdm(range(count), desc=f"augment {name}", unit="pair"):
            rng = spc.view_rng(seed, f"{name}/augment", i)
            view = int(views[rng.integers(len(views))])
            p = sample_params(rng, settings)
            samples.append(
                write_pair(
                    tmp, i, scene.images[view], p, flux_scale, params, spc.view_rng(seed, f"{name}/augment-spc", i)
                )
                | {"view": scene.names[view]}
            )
        record = {
            "scene": name,
            "count": count,
            "settings": asdict(settings),
            "seed": seed,
            "flux_scale": flux_scale,
            "exposure": spc_record.get("exposure") or exposure_record(camera_exposure(spc_record), "auto"),
            "spc_params": spc_record["params"],
            "samples": samples,
            "wall_s": round(time.perf_counter() - t0, 3),
        }
        io.write_json(tmp / "augment.json", record)
    log.info("%s: %d pairs in %.1f s", name, count, record["wall_s"])
    return record


def write_pair(
    out: Path, i: int, srgb: np.ndarray, p: dict, flux_scale: float, params: spc.SPCParams, rng: np.random.Generator
) -> dict:
    """Augment one view, save it, simulate its frames from the saved 8-bit image; return ``p``."""
    path = out / "rgb" / f"{i:05d}.png"
    io.write_image(path, augment_image(srgb, p))
    frames = spc.simulate_frames(io.read_rgb(path), flux_scale, params, rng)
    io.save_frames(out / "frames" / f"{i:05d}.npz", *spc.pack_frames(frames))
    io.write_image(out / "binary" / f"{i:05d}.png", frames[0].astype(np.float32))
    return dict(p)

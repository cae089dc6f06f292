"""Display exposure of the photon-fed rows without ground truth: the camera's reported exposure.

A SPAD user knows the exposure each capture was taken with, including an automatic exposure the
camera chose itself: ``spc.json``'s ``exposure`` block (:func:`spc3d.physics.record.exposure_record`)
reports H, the signal photons a pixel detects per frame at scene linear intensity 1. The flux per
unit linear intensity is then F = H / (q T), and a flux estimate φ̂ (photons/s,
:func:`spc3d.physics.spc.mle_flux`) becomes displayable linear light at the gain

    g = k F        linear = φ̂ / g

where k is the one number the rule learns, fitted once on the *training* scenes (where ground
truth is known) with the same estimator and the same K, to minimise their sRGB mean squared error
over all their views (:func:`fit_level`). A dark scene exposed longer then displays dark, as it
is: the display follows the scene's own photon rates and its known exposure, never its images.
Two gains are written, because two different fluxes are shown:

    level             k of the MLE image itself (biased at small K: a pixel firing once in K = 1
                      frames is clamped at ln 2 / (qT), so its flux is under- or overestimated)
    level_likelihood  1: the SPAD likelihood recovers the flux itself, whose display at F is the
                      scene's linear intensity by the camera model (fitting k on the training
                      scenes' true flux gives exactly 1, see the tests)

The translators use the same exposure (:mod:`spc3d.translate.camera`). A capture that reports no
exposure is metered at import (its training views' mean flux shown at :data:`PREVIEW_LEVEL`,
:func:`spc3d.captures.importing.metered_exposure`).

``capture=True`` reads the capture-resolution frame instead (``capture/`` of
:mod:`spc3d.inputs.build`, K = 1): each pixel's k ones among S² sub-pixel trials, φ̂ = mle_flux(k, S²).

The SPAD-likelihood objective turns rendered linear intensity into flux with the second gain
(:class:`spc3d.reconstruct.objectives.BernoulliObjective`).

Files: ``calibrate_display`` writes ``results/calibration/display-k{K}.json``; ``write_display``
writes a scene's ``results/mle/{scene}/k{K}/`` (``images/*.png`` and ``display.json``).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from spc3d import io, llff
from spc3d.physics import sensors, spc
from spc3d.physics.record import camera_exposure, check_capture_factor, params_from_record, read_spc_record

RULE = (
    "display gain g = k F, F = the camera's reported exposure as flux per unit linear intensity "
    "(spc.json exposure / (q T)); k fitted on the training scenes (same K) to minimise their sRGB MSE "
    "over all their views; the SPAD likelihood's flux is shown at k = 1"
)
PREVIEW_LEVEL = 0.18  # average metering: the mean flux is shown at 18 % linear grey (a camera's default)
LEVEL_RANGE = (0.05, 20.0)  # k searched: from 20x brighter to 20x darker than the exposure says


def mle_views(spc_dir: str | os.PathLike, K: int, capture: bool = False) -> tuple[list[str], np.ndarray]:
    """(view names, (N, H, W, 3) float32 MLE flux of each view's first ``K`` frames).

    ``capture``: the MLE of the capture-resolution frame instead (K must be 1): k = round(v S²)
    ones among S² trials per pixel and channel (:func:`capture_factor`). A captured scene's capture
    frame is its frame 0 (S = 1), read from ``frames/`` through its sensor as for K = 1.
    """
    from spc3d.physics.record import spc_sensor

    spc_dir = Path(spc_dir)
    params = params_from_record(read_spc_record(spc_dir))
    if capture and K != 1:
        raise ValueError(f"capture=True meters the one capture-resolution frame per view: K must be 1, got K = {K}")
    if K > params.frames:
        raise ValueError(f"K = {K} frames asked of {spc_dir}, which stores K = {params.frames} per view")
    sensor = spc_sensor(spc_dir)  # a capture: demosaiced, hot pixels filled (None: the simulator's RGB)
    S = capture_factor(spc_dir) if capture and sensor is None else 1
    names, out = [], []
    for path in sorted((spc_dir / "frames").glob("*.npz")):
        if S > 1:  # k ones among S² sub-pixels, stored exactly as k/S² in 16 bits
            counts = np.rint(io.read_rgb(spc_dir / "capture" / f"{path.stem}.png") * (S * S)).astype(np.int64)
        else:
            counts = spc.unpack_frames(*io.load_frames(path))[:K].sum(0, dtype=np.int64)
        if sensor is None:
            phi = spc.mle_flux(counts, S * S * K, params)
        else:
            phi = sensors.mle_rgb(counts, K, params, sensor[0], ~sensor[1])
        out.append(phi.astype(np.float32))
        names.append(path.stem)
    if not names:
        raise FileNotFoundError(f"{spc_dir / 'frames'} holds no .npz frames (run simulate_scene first)")
    return names, np.stack(out)


def capture_factor(spc_dir: str | os.PathLike) -> int:
    """S of an SPC folder's capture frame (``spc.json`` ``capture_factor``; 1 for a folder without one)."""
    return check_capture_factor(read_spc_record(spc_dir).get("capture_factor", 1))


def flux_per_linear(spc_dir: str | os.PathLike) -> float:
    """F: the flux (photons/s) at scene linear intensity 1 that the camera's reported exposure
    implies (``exposure.photons_per_frame`` / (q T))."""
    record = read_spc_record(spc_dir)
    p = params_from_record(record)
    return camera_exposure(record, f"{Path(spc_dir) / 'spc.json'}") / (p.q * p.exposure_s)


def display_srgb(phi: np.ndarray, gain: float) -> np.ndarray:
    """sRGB in [0, 1] of flux ``phi`` shown at ``gain`` (linear = phi / gain, clipped to [0, 1])."""
    return spc.linear_to_srgb(np.clip(phi / gain, 0.0, 1.0)).astype(np.float32)


def metered_gain(phi: np.ndarray, level: float) -> float:
    """The average-metering gain of a preview: mean flux shown at linear ``level`` (a floor keeps it
    positive: a scene with no detection at all gets the unit gain)."""
    mean = float(np.mean(phi, dtype=np.float64))
    return mean / level if mean > 0 else 1.0


def scene_error(shown: np.ndarray, gt: np.ndarray, flux: float) -> Callable[[float], float]:
    """k -> the sRGB MSE against ``gt`` of flux ``shown`` displayed at gain k ``flux`` (F).

    The pixels are grouped by their value of ``shown`` once, so each k costs one sRGB encoding per
    distinct value rather than per pixel: an MLE image takes K + 1 values per channel (K frames),
    and :func:`fit_level` evaluates each scene at ~120 levels. Per group u (n pixels, truths y):
    sum (s_u - y)^2 = n s_u^2 - 2 s_u sum y + sum y^2, all in float64.
    """
    if shown.shape != gt.shape:
        raise ValueError(f"scene_error: the shown flux has shape {shown.shape} but its ground truth {gt.shape}")
    if not (math.isfinite(flux) and flux > 0):
        raise ValueError(f"scene_error: the flux per linear intensity must be finite and > 0, got {flux!r}")
    values, inverse = np.unique(shown, return_inverse=True)
    inverse = inverse.ravel()
    truth = gt.astype(np.float64, copy=False).ravel()
    count = np.bincount(inverse, minlength=values.size).astype(np.float64)
    total = np.bincount(inverse, weights=truth, minlength=values.size)
    squares = float(np.dot(truth, truth))

    def error(level: float) -> float:
        s = display_srgb(values, level * flux).astype(np.float64)
        return max(float(count @ (s * s) - 2.0 * (total @ s) + squares), 0.0) / truth.size  # >= 0: a sum of squares

    return error


def fit_level(shown: list[np.ndarray], gts: list[np.ndarray], fluxes: list[float]) -> tuple[float, list[float]]:
    """The level k minimising the summed sRGB MSE against ``gts`` of ``shown`` displayed at gain
    k F (``fluxes``: each scene's F), and each scene's own best level (a diagnostic: how much the
    scenes disagree). Golden-section search on log k over :data:`LEVEL_RANGE` (the error is
    unimodal in k: too bright, right, too dark)."""
    if not shown or not len(shown) == len(gts) == len(fluxes):
        raise ValueError(
            f"fit_level: need matching non-empty lists of flux stacks, ground truths and exposures, got "
            f"{len(shown)}, {len(gts)} and {len(fluxes)}"
        )
    errors = [scene_error(v, g, f) for v, g, f in zip(shown, gts, fluxes)]

    def best(error) -> float:
        lo, hi = math.log(LEVEL_RANGE[0]), math.log(LEVEL_RANGE[1])
        r = (math.sqrt(5) - 1) / 2
        a, b = hi - r * (hi - lo), lo + r * (hi - lo)
        fa, fb = error(math.exp(a)), error(math.exp(b))
        for _ in range(60):  # the bracket shrinks by 0.618 per step: 60 steps reach ~1e-12 of its width
            if fa < fb:
                hi, b, fb = b, a, fa
                a = hi - r * (hi - lo)
                fa = error(math.exp(a))
            else:
                lo, a, fa = a, b, fb
                b = lo + r * (hi - lo)
                fb = error(math.exp(b))
        return math.exp((lo + hi) / 2)

    level = best(lambda k: sum(error(k) for error in errors))
    return level, [best(error) for error in errors]


def calibrate_display(
    scene_dirs: list[str], spc_dirs: list[str], K: int, out_json: str | os.PathLike, capture: bool = False
) -> dict:
    """Fit the display level k on training scenes (ground truth, frames, exposure); write ``out_json``.
    ``capture``: fit the capture frame's display (:func:`mle_views`)."""
    t0 = time.perf_counter()
    if not scene_dirs:
        raise ValueError(
            "the display level of the mle / bernoulli rows is fitted on the training scenes, but none "
            "was given (scenes.train is empty)"
        )
    phis, gts, fluxes, factors = [], [], [], set()
    for scene_dir, spc_dir in zip(scene_dirs, spc_dirs):
        names, phi = mle_views(spc_dir, K, capture)
        scene = llff.read_scene(scene_dir)
        phis.append(phi)
        gts.append(scene.images[[scene.names.index(n) for n in names]])
        fluxes.append(flux_per_linear(spc_dir))
        factors.add(capture_factor(spc_dir) if capture else 1)
    if len(factors) > 1:
        raise ValueError(f"training scenes {list(spc_dirs)} have capture frames of different capture_factor {factors}")
    level, per_scene = fit_level(phis, gts, fluxes)
    names = [Path(d).name for d in scene_dirs]
    record = {
        "K": K,
        "capture_factor": factors.pop(),
        "level": level,
        "level_likelihood": 1.0,
        "rule": RULE,
        "training_scenes": names,
        "per_scene_level": dict(zip(names, per_scene)),
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    io.write_json(out_json, record)
    return record


def write_display(
    spc_dir: str | os.PathLike,
    calibration: str | os.PathLike,
    K: int,
    out_dir: str | os.PathLike,
    capture: bool = False,
) -> dict:
    """A scene's MLE images of its first ``K`` frames (``capture``: of its capture frame) at the
    gain of its reported exposure and the fitted level; an image for every view (no ground truth read)."""
    t0 = time.perf_counter()
    cal = io.read_json(calibration)
    S = capture_factor(spc_dir) if capture else 1
    if (cal["K"], cal.get("capture_factor", 1)) != (K, S):
        raise ValueError(
            f"{calibration} was fitted for K = {cal['K']}, capture_factor = {cal.get('capture_factor', 1)}; "
            f"this display of {spc_dir} is K = {K}, capture_factor = {S} (capture={capture}): "
            "calibrate_display with the same K and capture"
        )
    names, phi = mle_views(spc_dir, K, capture)
    flux = flux_per_linear(spc_dir)
    gain = cal["level"] * flux
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for name, view in zip(names, phi):
            io.write_image(tmp / "images" / f"{name}.png", display_srgb(view, gain))
        record = {
            "scene": Path(spc_dir).name,
            "K": K,
            "capture_factor": S,
            "gain": gain,
            "level": cal["level"],
            "gain_likelihood": cal.get("level_likelihood", 1.0) * flux,
            "level_likelihood": cal.get("level_likelihood", 1.0),
            "flux_per_linear": flux,
            "exposure": read_spc_record(spc_dir).get("exposure"),
            "rule": RULE,
            "calibration": str(calibration),
            "views": len(names),
            "wall_s": round(time.perf_counter() - t0, 3),
        }
        io.write_json(tmp / "display.json", record)
    return record


def read_gain(display_dir: str | os.PathLike, likelihood: bool = False) -> float:
    """The gain of a scene's rows at one K (``display.json`` of :func:`write_display`): the MLE
    image's, or (``likelihood``) the one for the flux the SPAD likelihood recovers."""
    return float(io.read_json(Path(display_dir) / "display.json")["gain_likelihood" if likelihood else "gain"])

"""Display exposure of the physics rows without ground truth: average metering, fitted on training scenes.

The maximum-likelihood flux φ̂ of a view (photons/s, :func:`spc3d.physics.spc.mle_flux`) must be divided
by a gain g to become displayable linear light. The exact gain is the scene's ``flux_scale``, but
the simulator set that from the scene's ground-truth images: a row that used it would read the
evaluation ground truth (an oracle). A real SPAD user has the frames, q, T, dcr and the training
scenes, so the MLE and SPAD-likelihood rows use

    g = mean(φ̂ over every pixel, channel and training view of the scene's first K frames) / k

the average-metering rule of a camera's auto exposure: the scene's mean estimated flux is shown at
linear level k. Only the training views are metered: the held-out views of
:func:`spc3d.cameras.split_views` are scored, and no non-oracle row may read their frames (their
images are still written, as outputs; ``display.json`` counts ``metered_views`` of ``views``).
The level is fitted once on the *training* scenes (where ground truth is known), with the same
estimator, the same K and the same metering, to minimise their sRGB mean squared error over all
their views (:func:`fit_level`); it is the only number the rule learns, like the translators learn
brightness from the same scenes. Two levels are fitted, because two different fluxes are shown:

    level             the MLE image itself (biased at small K: a pixel firing once in K = 1 frames is
                      clamped at ln 2 / (qT), so the mean MLE flux underestimates the scene's)
    level_likelihood  the flux the SPAD likelihood recovers, which is unbiased: on the training
                      scenes that is their true flux (their exposure times their ground truth)

``capture=True`` meters the capture-resolution frame instead (``capture/`` of
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
from spc3d.cameras import split_views
from spc3d.physics import sensors, spc
from spc3d.physics.record import check_capture_factor, params_from_record, read_spc_record

RULE = (
    "display gain g = mean MLE flux of the scene's first K frames (training views only) / k; k fitted "
    "on the training scenes (same K, same metering) to minimise their sRGB MSE over all their views"
)
PREVIEW_LEVEL = 0.18  # average metering: the mean flux is shown at 18 % linear grey (a camera's default)
LEVEL_RANGE = (1e-3, 1.0)  # linear display levels searched for k (1e-3: almost black; 1: full white)


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


def metered(spc_dir: str | os.PathLike, names: list[str]) -> np.ndarray:
    """(N,) bool: the views of ``names`` the display meters, all but the scored (held-out) ones,
    which ``spc.json`` names (``held_out_views``; without it: :func:`spc3d.cameras.split_views` of
    ``names``, which are in the scene's order: both are sorted by name)."""
    held_out = read_spc_record(spc_dir).get("held_out_views")
    if held_out is None:
        held_out = [names[i] for i in split_views(len(names))[1]]
    held_out = set(held_out)
    keep = np.array([n not in held_out for n in names])
    if not keep.any():
        raise ValueError(f"{spc_dir}: every view {names} is held out; the display meters training views only")
    return keep


def display_srgb(phi: np.ndarray, gain: float) -> np.ndarray:
    """sRGB in [0, 1] of flux ``phi`` shown at ``gain`` (linear = phi / gain, clipped to [0, 1])."""
    return spc.linear_to_srgb(np.clip(phi / gain, 0.0, 1.0)).astype(np.float32)


def metered_gain(phi: np.ndarray, level: float) -> float:
    """The average-metering gain: mean flux shown at linear ``level`` (a floor keeps it positive:
    a scene with no detection at all gets the dark-count-free unit gain)."""
    return _gain(float(np.mean(phi, dtype=np.float64)), level)


def _gain(mean: float, level: float) -> float:
    return mean / level if mean > 0 else 1.0


def scene_error(meter: np.ndarray, gt: np.ndarray, shown: np.ndarray | None = None) -> Callable[[float], float]:
    """k -> the sRGB MSE against ``gt`` of ``shown`` (default: ``meter``) displayed at the gain
    metered from ``meter`` at level k.

    The pixels are grouped by their value of ``shown`` once, so each k costs one sRGB encoding per
    distinct value rather than per pixel: an MLE image takes K + 1 values per channel (K frames),
    and :func:`fit_level` evaluates each scene at ~120 levels. Per group u (n pixels, truths y):
    sum (s_u - y)^2 = n s_u^2 - 2 s_u sum y + sum y^2, all in float64.
    """
    shown = meter if shown is None else shown
    if shown.shape != gt.shape:
        raise ValueError(f"scene_error: the shown flux has shape {shown.shape} but its ground truth {gt.shape}")
    values, inverse = np.unique(shown, return_inverse=True)
    inverse = inverse.ravel()
    truth = gt.astype(np.float64, copy=False).ravel()
    count = np.bincount(inverse, minlength=values.size).astype(np.float64)
    total = np.bincount(inverse, weights=truth, minlength=values.size)
    squares = float(np.dot(truth, truth))
    mean = float(np.mean(meter, dtype=np.float64))

    def error(level: float) -> float:
        s = display_srgb(values, _gain(mean, level)).astype(np.float64)
        return max(float(count @ (s * s) - 2.0 * (total @ s) + squares), 0.0) / truth.size  # >= 0: a sum of squares

    return error


def fit_level(
    phis: list[np.ndarray], gts: list[np.ndarray], shown: list[np.ndarray] | None = None
) -> tuple[float, list[float]]:
    """The level k minimising the summed sRGB MSE against ``gts`` of ``shown`` (default: ``phis``)
    displayed at the gain metered from ``phis`` at k, and each scene's own best level (a
    diagnostic: how much the scenes disagree). Golden-section search on log k over
    :data:`LEVEL_RANGE` (the error is unimodal in k: too dark, right, too bright)."""
    shown = shown if shown is not None else [None] * len(phis)
    if not phis or len(phis) != len(gts) or len(shown) != len(phis):
        raise ValueError(
            f"fit_level: need matching non-empty lists of flux stacks and ground truths, got {len(phis)} and {len(gts)}"
        )
    errors = [scene_error(p, g, v) for p, g, v in zip(phis, gts, shown)]

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
    """Fit the display level on training scenes (ground truth + their frames); write ``out_json``.

    Each scene's gain is metered on its training views, as :func:`write_display` meters, and the
    error is taken over all its views (a training scene's ground truth is there to be used).
    ``capture``: fit the capture frame's display (:func:`mle_views`)."""
    t0 = time.perf_counter()
    if not scene_dirs:
        raise ValueError(
            "the display level of the mle / bernoulli rows is fitted on the training scenes, but none "
            "was given (scenes.train is empty)"
        )
    meters, phis, gts, fluxes, factors = [], [], [], [], set()
    for scene_dir, spc_dir in zip(scene_dirs, spc_dirs):
        names, phi = mle_views(spc_dir, K, capture)
        scene = llff.read_scene(scene_dir)
        gt = scene.images[[scene.names.index(n) for n in names]]
        meters.append(phi[metered(spc_dir, names)])
        phis.append(phi)
        gts.append(gt)
        fluxes.append(spc.flux_from_srgb(gt, read_spc_record(spc_dir)["flux_scale"]))  # a training scene's truth
        factors.add(capture_factor(spc_dir) if capture else 1)
    if len(factors) > 1:
        raise ValueError(f"training scenes {list(spc_dirs)} have capture frames of different capture_factor {factors}")
    level, per_scene = fit_level(meters, gts, phis)
    level_likelihood, per_scene_likelihood = fit_level(meters, gts, fluxes)
    names = [Path(d).name for d in scene_dirs]
    record = {
        "K": K,
        "capture_factor": factors.pop(),
        "level": level,
        "level_likelihood": level_likelihood,
        "rule": RULE,
        "training_scenes": names,
        "per_scene_level": dict(zip(names, per_scene)),
        "per_scene_level_likelihood": dict(zip(names, per_scene_likelihood)),
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
    gain metered on its training views; an image for every view (no ground truth read)."""
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
    keep = metered(spc_dir, names)
    gain = metered_gain(phi[keep], cal["level"])
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for name, view in zip(names, phi):
            io.write_image(tmp / "images" / f"{name}.png", display_srgb(view, gain))
        record = {
            "scene": Path(spc_dir).name,
            "K": K,
            "capture_factor": S,
            "gain": gain,
            "level": cal["level"],
            "gain_likelihood": metered_gain(phi[keep], cal["level_likelihood"]),
            "level_likelihood": cal["level_likelihood"],
            "mean_flux": float(np.mean(phi[keep], dtype=np.float64)),
            "rule": RULE,
            "calibration": str(calibration),
            "views": len(names),
            "metered_views": int(keep.sum()),
            "held_out_views": [n for n, k in zip(names, keep) if not k],
            "wall_s": round(time.perf_counter() - t0, 3),
        }
        io.write_json(tmp / "display.json", record)
    return record


def read_gain(display_dir: str | os.PathLike, likelihood: bool = False) -> float:
    """The metered gain of a scene's rows at one K (``display.json`` of :func:`write_display`): the
    MLE image's, or (``likelihood``) the one for the flux the SPAD likelihood recovers."""
    return float(io.read_json(Path(display_dir) / "display.json")["gain_likelihood" if likelihood else "gain"])

"""The simulated camera's exposure: the flux scale that gives a scene a target mean detection rate.

``calibrate_flux_scale`` sets photons/s at linear intensity 1 so that the mean probability of a
detection per frame over a scene's images equals the target (0.5 by default: every region stays
visible, paper section 3.1), under the simulator's own detection model (:func:`frame_probability`,
both modes of :mod:`spc3d.physics.spc`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from spc3d.physics.spc import (
    SPCParams,
    _bad,
    _check_srgb,
    _real,
    count_variance,
    detection_probability,
    expected_counts,
    srgb_to_linear,
)

_CALIBRATION_SAMPLES = 2**20  # at most this many pixel values enter the calibration (deterministic stride)


def _linear_histogram(srgb_images: Sequence[np.ndarray] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct linear values of (a strided subsample of) all images and their weights (sum 1)."""
    if isinstance(srgb_images, np.ndarray):  # (N, H, W, C) stack, or one (H, W, C) image
        images = list(srgb_images) if srgb_images.ndim == 4 else [srgb_images]
    else:
        images = list(srgb_images)
    if not images:
        raise ValueError("srgb_images: no images given; need a list of (H, W, C) or an (N, H, W, C) array")
    images = [_check_srgb(im, f"srgb_images[{i}]") for i, im in enumerate(images)]
    stride = max(1, -(-sum(im.size for im in images) // _CALIBRATION_SAMPLES))
    channels = images[0].shape[-1]
    while math.gcd(stride, channels) != 1:  # a stride sharing a factor with C would skip channels
        stride += 1
    sample = np.concatenate([im.reshape(-1)[::stride] for im in images])
    values, counts = np.unique(srgb_to_linear(sample).astype(np.float64), return_counts=True)
    return values, counts / counts.sum()


def frame_probability(phi: np.ndarray, params: SPCParams) -> np.ndarray:
    """P(bit = 1) of one frame under the simulator's own model (``params.mode``).

    ``bernoulli``: the exact 1 - exp(-lam*T). ``paper``: P(Normal(eq. 1, eq. 2) count rounds above
    0) = P(z > (1/2 - mean)/sd) = ndtr((mean - 1/2)/sd), the probability of :func:`spc3d.physics.spc._paper_frames`.
    """
    if params.mode == "bernoulli":
        return detection_probability(np.asarray(phi, dtype=np.float64), params)
    from scipy.special import ndtr

    mean = expected_counts(phi, params)
    sd = np.sqrt(count_variance(phi, params))
    with np.errstate(divide="ignore", invalid="ignore"):  # sd = 0 only at lam*T ~ 0: never fires
        return np.where(sd > 0, ndtr((mean - 0.5) / np.where(sd > 0, sd, 1.0)), 0.0)


def dark_floor(params: SPCParams) -> float:
    """P(bit = 1) with no light at all: what dark counts alone fire (the least any exposure gives)."""
    return float(frame_probability(np.zeros(1), params)[0])


def detection_span(params: SPCParams, flux_scale: float) -> tuple[float, float]:
    """P(bit = 1) of a pixel at 1 % linear grey and at white (linear 1) for a fixed ``flux_scale``:
    the span a scene's pixels can cover (a black pixel sits at :func:`dark_floor`)."""
    with np.errstate(over="ignore"):
        p = frame_probability(np.array([0.01, 1.0]) * flux_scale, params)
    return float(p[0]), float(p[1])


def _mean_detection(values: np.ndarray, weights: np.ndarray, s: float, params: SPCParams) -> float:
    with np.errstate(over="ignore"):  # huge trial scales: lam*T -> inf gives p = 1, as it should
        # np.sum, not a BLAS dot: OpenBLAS threads idle-spin under load (15 ms for 18k values)
        return float(np.sum(weights * frame_probability(s * values, params)))


def calibrate_flux_scale(
    srgb_images: Sequence[np.ndarray] | np.ndarray, params: SPCParams, target_mean_detection: float = 0.5
) -> float:
    """Flux scale s whose mean detection probability over all images equals the target.

    srgb_images: list of float (H, W, C) or one (N, H, W, C) array, sRGB in [0, 1]; at most 2**20
    values are used (deterministic stride). The detection probability is the simulator's own
    (:func:`frame_probability`, so ``paper`` mode reaches its target too). The mean is monotone in
    s, from the dark-count floor at s = 0 up to 1 (less if some pixels are black), so a geometric
    bisection finds s to a relative tolerance of 1e-6. A mean target keeps all regions visible
    (paper section 3.1).
    """
    values, weights = _linear_histogram(srgb_images)
    target = _real("target_mean_detection", target_mean_detection, "must be a probability")
    p_dark = dark_floor(params)
    black = float(weights[values == 0.0].sum())
    p_max = 1.0 - black * (1.0 - p_dark)  # black pixels stay at p_dark for every s
    if not (p_dark < target < p_max):
        raise _bad(
            "target_mean_detection",
            target_mean_detection,
            f"reachable mean detection probabilities are ({p_dark:.6g}, {p_max:.6g}): the floor "
            f"is the dark-count probability 1 - exp(-dcr*T) at flux_scale 0, the ceiling is 1 "
            f"minus the share of black pixels ({black:.3%}) that stay at the floor",
        )

    def mean_p(s: float) -> float:
        return _mean_detection(values, weights, s, params)

    lo = hi = 1.0 / (params.q * params.exposure_s * float(np.sum(weights * values)))  # mean lam*T ~ 1
    while mean_p(lo) >= target:
        lo /= 10.0  # terminates: mean_p -> p_dark < target as s -> 0
    while mean_p(hi) <= target:
        hi *= 10.0  # mean_p -> p_max > target as s -> inf, but stop before s overflows
        if hi > 1e300:
            raise _bad(
                "target_mean_detection",
                target_mean_detection,
                f"too close to the reachable ceiling {p_max:.6g} to calibrate",
            )
    for _ in range(100):  # geometric bisection; ~25 steps from a factor-10 bracket to 1e-6
        if hi <= lo * (1.0 + 1e-6):
            break
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if mean_p(mid) < target else (lo, mid)
    return math.sqrt(lo * hi)

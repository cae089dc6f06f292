"""A no-reference score of novel views: how well a row's renders explain the held-out views' photons.

A scene without reference RGB views (a capture without ``images/``) cannot be scored by PSNR, but
its held-out views still have their binary frames, which no row trained on. A render that is
right up to exposure predicts every pixel's firing probability

    p = 1 - exp(-(q g m + dcr) T),   m = sum_c w_c linear_c  (the channels the pixel sees)

for one gain ``g`` (photons/s at linear 1) per row. The score is the Bernoulli negative
log-likelihood of the held-out frames at the gain that fits them best, in nats per bit, minus the
same for the per-pixel maximum-likelihood rates (the frames' own entropy, the floor no render can
beat):

    excess = NLL(renders, best g) - NLL(per-pixel rates)   >= 0, lower is better.

The gain is fitted on the held-out frames themselves, the same way for every row, so it measures
structure and colour, not exposure; rows of one scene are compared at equal K.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.optimize import minimize_scalar

from spc3d.physics import spc
from spc3d.physics.sensors import bernoulli_nll_terms, cfa_mask

DEFINITION = (
    "Bernoulli NLL of the held-out views' binary frames under the renders at the best single gain, "
    "minus that of the per-pixel MLE rates (nats per bit; 0 = explains the photons as well as any image can)"
)
SEARCH = math.log(1e4)  # the gain is searched within x/÷ 1e4 of the moment estimate


def _entropy(fraction: np.ndarray) -> np.ndarray:
    """The NLL at the per-pixel MLE rate: the binary entropy of the fraction (0 log 0 = 0)."""
    f = np.clip(fraction, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(np.where(f > 0, f * np.log(f), 0.0) + np.where(f < 1, (1 - f) * np.log1p(-f), 0.0))
    return h


def heldout_photon_score(
    renders: list[np.ndarray],
    fractions: list[np.ndarray],
    frames: int,
    params: spc.SPCParams,
    pattern=None,
    valid: np.ndarray | None = None,
) -> dict:
    """Score sRGB ``renders`` (H, W, 3) against the held-out firing ``fractions`` of ``frames``
    frames each ((H, W) for a sensor ``pattern``; (H, W, 3) for the simulator's RGB frames);
    ``valid`` (H, W) False at hot pixels."""
    if not renders or len(renders) != len(fractions):
        raise ValueError(f"{len(renders)} renders for {len(fractions)} held-out views; need one per view, at least one")
    mixes, targets = [], []
    for img, frac in zip(renders, fractions):
        linear = spc.srgb_to_linear(np.clip(img, 0.0, 1.0)).astype(np.float64)
        mix = linear if pattern is None else (linear * cfa_mask(pattern, *frac.shape, np.float64)).sum(-1)
        keep = valid if pattern is not None and valid is not None else np.ones(frac.shape, bool)
        if mix.shape != frac.shape:
            raise ValueError(f"render {img.shape} does not match the held-out frames {frac.shape}")
        mixes.append(mix[keep])
        targets.append(frac[keep].astype(np.float64))
    mix, target = np.concatenate(mixes), np.concatenate(targets)
    q, t, dcr = params.q, params.exposure_s, params.dark_count_rate
    rate = -math.log1p(-min(float(target.mean()), 1 - 1e-6)) / t  # detections/s of the mean pixel
    g0 = max(rate - dcr, 1e-9) / (q * max(float(mix.mean()), 1e-9))

    mix_t, target_t = torch.from_numpy(mix), torch.from_numpy(target)

    def nll(log_g: float) -> float:  # the stage-2 likelihood's terms; λT > 0 as its objective clamps it
        lam_t = ((q * math.exp(log_g) * mix_t + dcr) * t).clamp_min(1e-12)
        return float(bernoulli_nll_terms(lam_t, target_t).mean())

    best = minimize_scalar(nll, bounds=(math.log(g0) - SEARCH, math.log(g0) + SEARCH), method="bounded")
    floor = float(_entropy(target).mean())
    return {
        "excess_nll": best.fun - floor,
        "nll": best.fun,
        "floor_nll": floor,
        "gain_fitted": math.exp(best.x),
        "frames": frames,
        "views": len(renders),
        "measurements": int(target.size),
        "definition": DEFINITION,
    }

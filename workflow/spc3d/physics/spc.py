"""Single-photon camera (SPAD) physics: 1-bit frames, flux estimates (the exposure calibration is :mod:`.flux_scale`).

Physics
-------
A pixel (one colour channel) receives photons at flux ``phi`` (photons/s) as a Poisson process; a
fraction ``q`` (quantum efficiency) is detected and thermal dark counts add a Poisson rate ``dcr``,
so detections arrive at rate ``lam = q*phi + dcr``. After each detection a passive SPAD is blind
for the dead time ``tau`` (non-paralyzable: arrivals during it are lost and do not extend it).
Counts in an exposure ``T`` form a renewal process with, asymptotically in ``T/tau`` (paper eqs. 1-2)

    E[N]   = lam*T / (1 + lam*tau)
    Var[N] = lam*T / (1 + lam*tau)**3

A 1-bit frame reports ``N >= 1``. The detector is live at t = 0, so the first detection happens iff
the first arrival falls inside the exposure, and dead time cannot change that:
``P(N >= 1) = 1 - exp(-lam*T)``, computed as ``-expm1(-lam*T)``.

Modes (``SPCParams.mode``)
--------------------------
``"bernoulli"`` (exact, default)
    bit ~ Bernoulli(1 - exp(-lam*T)). Sampled by comparing raw uint32 random words against a
    per-pixel threshold ``floor(p * 2**32)``: probabilities are resolved to 2**-32 (p < 2**-32
    never fires, p = 1 fires with probability 1 - 2**-32); no float conversion, which makes it
    faster than ``rng.random(...) < p``.
``"paper"`` (the paper's simulator, section 3.1)
    N ~ Normal(E[N], Var[N]) from eqs. 1-2, rounded, clipped to [0, T/tau] (no upper clip when
    tau = 0: the Poisson limit), bit = N > 0. This fires with probability P(Normal > 1/2), which is
    biased against the exact P(N >= 1): far too low at low flux (lam*T = 0.01 gives ~5e-7 instead
    of ~0.01) and somewhat too high near lam*T ~ 1 (0.69 instead of 0.63 for tau -> 0). Frames
    are drawn as z > (1/2 - E[N]) / sd[N] for standard normal z, which gives the same bits.

Images enter as sRGB in [0, 1]: ``phi = flux_scale * srgb_to_linear(srgb)`` (linear light inside
the physics). Inverses: ``mle_flux`` (K 1-bit frames) and ``deadtime_flux`` (multi-bit counts).
All physics runs in float64.
"""

from __future__ import annotations

import math
import numbers
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from spc3d.pixels import linear_to_srgb, srgb_to_linear  # noqa: F401  (the simulator's colour, as spc.*)

MODES = ("bernoulli", "paper")
_TWO32 = 2.0**32


def _bad(name: str, value: object, rule: str) -> ValueError:
    return ValueError(f"{name}={value!r}: {rule}")


def _real(name: str, value: object, rule: str) -> float:
    """``value`` as a float; non-numbers raise ValueError with ``rule`` (NaN is left to the caller)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _bad(name, value, rule)
    return float(value)


def _integer(name: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise _bad(name, value, f"must be an integer >= {minimum}")
    return int(value)


@dataclass(frozen=True)
class SPCParams:
    """Camera settings; validated on construction."""

    q: float = 0.45  # quantum efficiency (photon detection probability), in (0, 1]
    tau_d: float = 150e-9  # dead time after each detection, seconds, >= 0
    exposure_s: float = 1e-4  # exposure T of one 1-bit frame, seconds, > 0
    dark_count_rate: float = 100.0  # dark counts per second, >= 0
    mode: str = "bernoulli"  # "bernoulli" (exact P(N >= 1)) or "paper" (Normal counts, eqs. 1-2)
    frames: int = 1  # K, number of independent 1-bit frames per view, >= 1

    def __post_init__(self) -> None:
        checks = (  # (field, value, predicate, rule); comparisons are False for NaN, so NaN fails
            ("q", self.q, lambda v: 0.0 < v <= 1.0, "quantum efficiency must be in (0, 1]"),
            ("tau_d", self.tau_d, lambda v: 0.0 <= v < math.inf, "dead time must be finite and >= 0 s"),
            ("exposure_s", self.exposure_s, lambda v: 0.0 < v < math.inf, "exposure must be finite and > 0 s"),
            (
                "dark_count_rate",
                self.dark_count_rate,
                lambda v: 0.0 <= v < math.inf,
                "dark count rate must be finite and >= 0 counts/s",
            ),
        )
        for name, value, ok, rule in checks:
            if not ok(_real(name, value, rule)):
                raise _bad(name, value, rule)
        if self.mode not in MODES:
            raise _bad("mode", self.mode, f"unknown SPC mode; use one of {MODES}")
        _integer("frames", self.frames, 1)


# --------------------------------------------------------------------------------------------
# colour (the sRGB transfer: spc3d.pixels, imported above) and flux


def _check_flux_scale(flux_scale: float) -> float:
    rule = "flux scale (photons/s at sRGB 1.0) must be finite and >= 0"
    s = _real("flux_scale", flux_scale, rule)
    if not (0.0 <= s < math.inf):
        raise _bad("flux_scale", flux_scale, rule)
    return s


def flux_from_srgb(srgb: np.ndarray, flux_scale: float) -> np.ndarray:
    """Photon flux phi (photons/s per pixel and channel), float64, same shape as ``srgb``.

    Dark counts are not added here: they enter the detection rate as ``q*phi + dcr``.
    """
    s = _check_flux_scale(flux_scale)
    phi = srgb_to_linear(srgb).astype(np.float64)  # in the input precision, then float64 physics
    phi *= s
    return phi


def _check_flux(phi: np.ndarray, name: str = "phi", what: str = "photon flux (photons/s)") -> np.ndarray:
    """float64 copy/view of ``phi``; ValueError counting the NaN, negative and infinite values."""
    phi = np.asarray(phi, dtype=np.float64)
    if phi.size and not (phi.min() >= 0.0 and phi.max() < math.inf):  # min/max propagate NaN
        nan, neg, inf = int(np.isnan(phi).sum()), int((phi < 0).sum()), int(np.isinf(phi).sum())
        rest = phi[~np.isnan(phi)]
        low = rest.min() if rest.size else math.nan
        raise ValueError(
            f"{name}: {nan} NaN, {neg} negative and {inf} infinite values out of {phi.size} "
            f"(minimum {float(low)!r}); {what} must be finite and >= 0"
        )
    return phi


# --------------------------------------------------------------------------------------------
# detection statistics (all take phi of any shape and return the same shape, float64)


def detection_rate(phi: np.ndarray, params: SPCParams) -> np.ndarray:
    """Detection rate lam = q*phi + dcr (counts/s, before dead time)."""
    phi = _check_flux(phi)
    lam = np.multiply(phi, params.q, out=np.empty_like(phi))  # fresh array (0-d for scalars)
    lam += params.dark_count_rate
    return lam


def detection_probability(phi: np.ndarray, params: SPCParams) -> np.ndarray:
    """Exact P(N >= 1) = 1 - exp(-lam*T) of one 1-bit frame (dead time does not change it)."""
    x = detection_rate(phi, params)
    x *= -params.exposure_s
    np.expm1(x, out=x)  # exp(-lam*T) - 1 without cancellation at small lam*T
    return np.negative(x, out=x)


def expected_counts(phi: np.ndarray, params: SPCParams) -> np.ndarray:
    """Renewal-model mean count E[N] = lam*T / (1 + lam*tau) (paper eq. 1)."""
    lam = detection_rate(phi, params)
    return lam / (1.0 + lam * params.tau_d) * params.exposure_s  # lam/(1+lam*tau) <= 1/tau: no overflow


def count_variance(phi: np.ndarray, params: SPCParams) -> np.ndarray:
    """Renewal-model count variance Var[N] = lam*T / (1 + lam*tau)**3 (paper eq. 2)."""
    lam = detection_rate(phi, params)
    d = 1.0 + lam * params.tau_d
    return lam / d * params.exposure_s / d / d  # divide step by step: (1 + lam*tau)**3 can overflow


# --------------------------------------------------------------------------------------------
# frame simulation


def _span(a: np.ndarray) -> str:
    """'[min, max] (NaN: n)' of an array, for error messages (no all-NaN warnings)."""
    rest = a[~np.isnan(a)]
    span = f"[{float(rest.min())}, {float(rest.max())}]" if rest.size else "[]"
    return f"{span} (NaN: {a.size - rest.size})"


def _check_srgb(srgb: np.ndarray, name: str = "srgb") -> np.ndarray:
    srgb = np.asarray(srgb)
    if srgb.ndim != 3:
        raise ValueError(f"{name}: shape {srgb.shape} must be (H, W, C), a 3-D image")
    if not np.issubdtype(srgb.dtype, np.floating):
        raise ValueError(f"{name}: dtype {srgb.dtype} must be floating point with values in [0, 1]")
    if srgb.size and not (srgb.min() >= 0.0 and srgb.max() <= 1.0):  # min/max propagate NaN
        raise ValueError(f"{name}: values span {_span(srgb)}; sRGB values must lie in [0, 1]")
    return srgb


def _uniform_uint32(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` uniform uint32 words: raw 64-bit outputs viewed as uint32 pairs."""
    return rng.bit_generator.random_raw((count + 1) // 2).view(np.uint32)[:count]


def _bernoulli_frames(phi: np.ndarray, params: SPCParams, rng: np.random.Generator) -> np.ndarray:
    """(K, *phi.shape) bool: bit = u < floor(p * 2**32) for uniform uint32 u."""
    scaled = detection_probability(phi, params)
    scaled *= _TWO32  # exact (power-of-two scaling)
    np.minimum(scaled, _TWO32 - 1.0, out=scaled)  # p = 1 would need 2**32: fires w.p. 1 - 2**-32
    thr = scaled.astype(np.uint32)  # truncation = floor for these non-negative values
    out = np.empty((params.frames,) + phi.shape, dtype=bool)
    step = max(1, 2**21 // max(phi.size, 1))  # frames per draw: ~8 MB of raw words at a time
    for k in range(0, params.frames, step):
        block = out[k : k + step]
        np.less(_uniform_uint32(rng, block.size).reshape(block.shape), thr, out=block)
    return out


def _paper_sampler(phi: np.ndarray, params: SPCParams) -> Callable[[np.random.Generator], np.ndarray]:
    """Draw function for the paper's counts: rint(Normal(eq. 1, eq. 2)) clipped to [0, T/tau]."""
    mean = expected_counts(phi, params)
    sd = np.sqrt(count_variance(phi, params))
    # T/tau is the most a dead-time-limited detector can count; tau = 0 is the Poisson limit.
    upper = params.exposure_s / params.tau_d if params.tau_d > 0 else math.inf

    def draw(rng: np.random.Generator) -> np.ndarray:
        return np.clip(np.rint(mean + sd * rng.standard_normal(mean.shape)), 0.0, upper)

    return draw


def _paper_frames(phi: np.ndarray, params: SPCParams, rng: np.random.Generator) -> np.ndarray:
    """(K, *phi.shape) bool: bit = (paper-model count > 0), one normal draw per bit.

    clip(rint(m + s*z), 0, T/tau) > 0 exactly when m + s*z > 1/2 (rint rounds 1/2 down to 0 and
    the clip keeps positive counts positive), i.e. when z > (1/2 - m)/s: the same bits as counts
    from ``_paper_sampler`` with the same draws (up to rounding at the boundary), minus three
    full-image passes per frame.
    """
    mean = expected_counts(phi, params)
    sd = np.sqrt(count_variance(phi, params))
    with np.errstate(divide="ignore"):  # sd = 0 only where lam*T ~ 0: z_min = +inf, never fires
        z_min = (0.5 - mean) / sd
    out = np.empty((params.frames,) + phi.shape, dtype=bool)
    for k in range(params.frames):
        np.greater(rng.standard_normal(phi.shape), z_min, out=out[k])
    return out


_SAMPLERS = {"bernoulli": _bernoulli_frames, "paper": _paper_frames}


def simulate_frames(srgb: np.ndarray, flux_scale: float, params: SPCParams, rng: np.random.Generator) -> np.ndarray:
    """K independent 1-bit frames of one sRGB image.

    srgb: float (H, W, C) in [0, 1]. Returns bool (K, H, W, C), K = ``params.frames``.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: got {type(rng).__name__}, need a numpy.random.Generator (see view_rng)")
    phi = flux_from_srgb(_check_srgb(srgb), flux_scale)
    return _SAMPLERS[params.mode](phi, params, rng)


def simulate_plane(phi: np.ndarray, params: SPCParams, rng: np.random.Generator) -> np.ndarray:
    """K independent 1-bit frames of a flux map of any shape (photons/s; one value per pixel of a
    sensor plane): bool (K, *phi.shape), drawn with the sampler of ``params.mode``."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: got {type(rng).__name__}, need a numpy.random.Generator (see view_rng)")
    return _SAMPLERS[params.mode](_check_flux(phi), params, rng)


def view_rng(seed: int, scene: str, view: int) -> np.random.Generator:
    """PCG64 generator fixed by (seed, scene name, view index); independent of PYTHONHASHSEED."""
    seed, view = _integer("seed", seed, 0), _integer("view", view, 0)
    if not isinstance(scene, str):
        raise _bad("scene", scene, "scene name must be a str")
    scene_key = zlib.crc32(scene.encode("utf-8"))  # stable 32-bit hash (Python's hash() is salted)
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, scene_key, view])))


# --------------------------------------------------------------------------------------------
# storage


def pack_frames(frames: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    """bool (K, H, W, C) -> (uint8 1-D of ceil(size/8) bytes, little bit order; shape)."""
    frames = np.asarray(frames)
    if frames.dtype != np.bool_:
        raise ValueError(f"frames: dtype {frames.dtype} must be bool")
    return np.packbits(frames.reshape(-1), bitorder="little"), tuple(int(n) for n in frames.shape)


def unpack_frames(packed: np.ndarray, shape: Sequence[int]) -> np.ndarray:
    """Inverse of ``pack_frames``: uint8 1-D + shape -> bool array of that shape."""
    shape = tuple(int(n) for n in shape)
    count = math.prod(shape)
    packed = np.asarray(packed)
    if packed.dtype != np.uint8 or packed.ndim != 1 or packed.size != (count + 7) // 8:
        raise ValueError(
            f"packed: {packed.dtype} array of shape {packed.shape} does not hold "
            f"shape {shape}; need uint8 1-D with {(count + 7) // 8} bytes"
        )
    return np.unpackbits(packed, count=count, bitorder="little").view(bool).reshape(shape)


# --------------------------------------------------------------------------------------------
# flux estimates


def mle_flux(frames_sum: np.ndarray, K: int, params: SPCParams) -> np.ndarray:
    """Maximum-likelihood flux from S ones among K 1-bit frames (any shape -> same shape, float64).

    phi_hat = (min(-ln(1 - S/K), ln K + ln 2) / T - dcr) / q, clipped at 0. The clamp replaces
    the infinite estimate of saturated pixels (S = K) by ln(2K), above the S = K-1 value ln K, so
    the estimate stays finite and non-decreasing in S (quanta burst photography's merge). Dark
    counts are subtracted as their expected rate; where that makes the estimate negative (dark
    noise), it is clipped to 0, the smallest physical flux.
    """
    K = _integer("K", K, 1)
    S = np.asarray(frames_sum, dtype=np.float64)
    if S.size and not (S.min() >= 0.0 and S.max() <= K):
        raise ValueError(
            f"frames_sum: values span {_span(S)}; the number of ones among K={K} frames must lie in [0, {K}]"
        )
    cap = math.log(K) + math.log(2.0)
    saturated = S >= K
    y = -np.log1p(-np.where(saturated, 0.0, S / K))  # S == K masked: log1p(-1) would warn
    y = np.minimum(np.where(saturated, cap, y), cap)
    return np.maximum((y / params.exposure_s - params.dark_count_rate) / params.q, 0.0)


def deadtime_flux(counts: np.ndarray, params: SPCParams) -> np.ndarray:
    """Flux from multi-bit counts with dead time (inverse of eq. 1), any shape -> same, float64.

    lam_hat = N / (T - N*tau), phi_hat = (lam_hat - dcr) / q clipped at 0 (dark noise can push
    it below zero). N is clamped to at most T/tau - 1/2: eq. 1 never reaches T/tau, and at
    N = T/tau (where the paper's counts are clipped) the inverse is infinite; half a count of
    margin keeps the denominator >= tau/2. When T < tau the margin is T/(2 tau) instead, so the
    bound stays positive.
    """
    N = _check_flux(counts, "counts", "photon counts")
    T, tau = params.exposure_s, params.tau_d
    if tau > 0:
        N = np.minimum(N, T / tau - min(0.5, T / (2.0 * tau)))
        denom = np.maximum(T - N * tau, min(0.5, T / (2.0 * tau)) * tau)  # same bound, rounding-proof
    else:
        denom = T
    return np.maximum((N / denom - params.dark_count_rate) / params.q, 0.0)

"""SPC physics: detection statistics, frame simulation, calibration, flux inversion, validation."""

import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from spc3d.physics import spc
from spc3d.physics.flux_scale import calibrate_flux_scale, frame_probability

pytestmark = pytest.mark.filterwarnings("error")  # any RuntimeWarning (overflow, log(0), ...) fails

DEFAULT = spc.SPCParams()


def _params(**kw) -> spc.SPCParams:
    return spc.SPCParams(**kw)


def _normal_sf(z: float) -> float:
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def _binomial_tol(p: np.ndarray, n: int, k: float = 5.0) -> np.ndarray:
    return k * np.sqrt(p * (1 - p) / n) + 1e-9


# ---------------------------------------------------------------------------------------- colour


def test_srgb_curves_invert_and_match_iec_values():
    x = np.linspace(0.0, 1.0, 10_001)
    assert np.allclose(spc.linear_to_srgb(spc.srgb_to_linear(x)), x, atol=1e-12)
    assert spc.srgb_to_linear(0.5) == pytest.approx(0.214041140, rel=1e-8)
    assert spc.linear_to_srgb(0.0031308) == pytest.approx(0.04044994, rel=1e-6)  # the knee
    assert np.all(np.diff(spc.srgb_to_linear(x)) > 0)
    assert spc.srgb_to_linear(np.array([-0.5, 2.0])).tolist() == [0.0, 1.0]  # clipped
    assert spc.srgb_to_linear(np.zeros(2, np.float32)).dtype == np.float32


# ------------------------------------------------------------------------------ detection stats


def test_srgb_curves_clip_to_the_unit_range():
    """Both curves clip their input to [0, 1] (a render above 1 displays as white, not brighter)."""
    for curve in (spc.srgb_to_linear, spc.linear_to_srgb):
        assert curve(np.array([-0.5, 0.0, 1.0, 1.5])).tolist() == pytest.approx([0.0, 0.0, 1.0, 1.0], abs=1e-12)


@pytest.mark.parametrize("T", [1e-12, 1e-9, 1e-6, 1e-4, 1.0, 1e3])
@pytest.mark.parametrize("tau", [0.0, 150e-9])
@pytest.mark.parametrize("dcr", [0.0, 100.0])
def test_statistics_finite_and_monotone_at_extremes(T, tau, dcr):
    params = _params(exposure_s=T, tau_d=tau, dark_count_rate=dcr)
    phi = np.concatenate([[0.0], np.logspace(-6, 15, 400)])
    p = spc.detection_probability(phi, params)
    mean, var = spc.expected_counts(phi, params), spc.count_variance(phi, params)
    for a in (p, mean, var):
        assert np.all(np.isfinite(a))
    assert np.all((p >= 0) & (p <= 1)) and np.all(np.diff(p) >= 0)
    assert np.all(np.diff(mean) >= 0) and np.all(var >= 0)
    if tau > 0:
        assert np.all(mean <= T / tau * (1 + 1e-12))  # a dead-time-limited detector saturates


def test_paper_moments_equal_equations_and_poisson_limit():
    phi = np.array([0.0, 1e3, 1e6, 1e9])
    lam = DEFAULT.q * phi + DEFAULT.dark_count_rate
    a, T = lam * DEFAULT.tau_d, DEFAULT.exposure_s
    assert np.allclose(spc.expected_counts(phi, DEFAULT), lam * T / (1 + a), rtol=1e-14)
    assert np.allclose(spc.count_variance(phi, DEFAULT), lam * T / (1 + a) ** 3, rtol=1e-14)
    poisson = _params(tau_d=0.0)
    assert np.allclose(spc.count_variance(phi, poisson), spc.expected_counts(phi, poisson), rtol=1e-14)


# ---------------------------------------------------------------------------- frame simulation


LEVELS = np.array([0.0, 0.02, 0.1, 0.3, 0.5, 0.8, 1.0])


def _level_image() -> np.ndarray:
    """(7, 4, 3) float32 image: row i holds sRGB level LEVELS[i]."""
    return np.broadcast_to(LEVELS[:, None, None], (7, 4, 3)).astype(np.float32)


def test_bernoulli_bit_rate_matches_detection_probability():
    params, scale, K = _params(frames=4096), 1e5, 4096
    frames = spc.simulate_frames(_level_image(), scale, params, np.random.default_rng(0))
    assert frames.shape == (K, 7, 4, 3) and frames.dtype == bool
    p = spc.detection_probability(spc.flux_from_srgb(LEVELS, scale), params)
    rate = frames.mean(axis=(0, 2, 3))  # per level, n = K * 12 bits
    assert np.all(np.abs(rate - p) <= _binomial_tol(p, K * 12) + 2.0**-32)
    assert p[0] < 0.02 and 0.005 < p[1] < 0.02 and 0.5 < p[4] < 0.7 and p[-1] > 0.98  # all regimes


@pytest.mark.parametrize("mode", ["bernoulli", "paper"])
def test_a_sensor_plane_of_any_shape_fires_at_its_detection_probability(mode):
    """simulate_plane (a mosaic sensor's plane, spc3d.physics.sensors) draws K frames of a flux map
    of any shape with the sampler of the mode, the same draws as simulate_frames of that flux."""
    params, K = replace(_params(frames=2048), mode=mode), 2048
    phi = spc.flux_from_srgb(np.broadcast_to(LEVELS[:, None], (7, 5)), 1e5)  # (7, 5): no channel axis
    frames = spc.simulate_plane(phi, params, np.random.default_rng(3))
    assert frames.shape == (K, 7, 5) and frames.dtype == bool
    if mode == "bernoulli":
        p = spc.detection_probability(phi[:, 0], params)
        assert np.all(np.abs(frames.mean(axis=(0, 2)) - p) <= _binomial_tol(p, K * 5) + 2.0**-32)
    srgb = np.broadcast_to(LEVELS[:, None, None], (7, 5, 1)).astype(np.float64)
    same = spc.simulate_frames(srgb, 1e5, params, np.random.default_rng(3))[..., 0]
    assert np.array_equal(frames, same)
    with pytest.raises(TypeError, match=r"^rng: got int, need a numpy\.random\.Generator \(see view_rng\)$"):
        spc.simulate_plane(phi, params, 3)
    with pytest.raises(ValueError, match="phi"):
        spc.simulate_plane(-phi, params, np.random.default_rng(3))


def test_bernoulli_is_deterministic_per_generator():
    params = _params(frames=3)
    a = spc.simulate_frames(_level_image(), 3e4, params, spc.view_rng(7, "fern", 2))
    b = spc.simulate_frames(_level_image(), 3e4, params, spc.view_rng(7, "fern", 2))
    c = spc.simulate_frames(_level_image(), 3e4, params, spc.view_rng(7, "fern", 3))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("lam_t", [0.01, 0.05])
def test_paper_mode_underestimates_detection_at_low_flux(lam_t):
    # The paper's Normal+round recipe fires when N(m, s) > 1/2 (m ~ s^2 ~ lam*T at low flux), which
    # is far below the exact 1 - exp(-lam*T): the documented low-flux bias.
    params = _params(mode="paper", tau_d=0.0, dark_count_rate=0.0, frames=400)
    phi = lam_t / (params.q * params.exposure_s)
    img = np.full((50, 50, 3), spc.linear_to_srgb(phi / 1e6), dtype=np.float64)
    frames = spc.simulate_frames(img, 1e6, params, np.random.default_rng(1))
    n = frames.size
    exact = float(spc.detection_probability(phi, params))
    predicted = _normal_sf((0.5 - lam_t) / math.sqrt(lam_t))  # P(N(m, m) > 1/2)
    assert abs(frames.mean() - predicted) <= 5 * math.sqrt(predicted * (1 - predicted) / n) + 1e-6
    assert frames.mean() < 0.5 * exact


def test_paper_mode_overestimates_detection_near_one_photon():
    params = _params(mode="paper", tau_d=0.0, dark_count_rate=0.0, frames=200)
    phi = 1.0 / (params.q * params.exposure_s)  # lam*T = 1
    img = np.full((50, 50, 3), spc.linear_to_srgb(phi / 1e6))
    rate = spc.simulate_frames(img, 1e6, params, np.random.default_rng(2)).mean()
    assert abs(rate - _normal_sf(-0.5)) < 0.005 and rate > 1 - math.exp(-1) + 0.04


def test_paper_counts_without_dead_time_are_poisson_moments():
    params = _params(mode="paper", tau_d=0.0)
    phi = np.full(200_000, 50.0 / (params.q * params.exposure_s))  # lam*T ~ 50 (+ dark counts)
    counts = spc._paper_sampler(phi, params)(np.random.default_rng(3))
    m = float(spc.expected_counts(phi[:1], params)[0])
    n = counts.size
    assert abs(counts.mean() - m) <= 5 * math.sqrt(m / n)
    assert abs(counts.var() - (m + 1 / 12)) <= 5 * m * math.sqrt(2 / n)  # rounding adds 1/12
    assert np.all(counts == np.rint(counts))


def test_paper_frames_are_thresholded_paper_counts():
    params = _params(mode="paper", frames=3)
    img = np.random.default_rng(11).random((6, 7, 3))
    frames = spc.simulate_frames(img, 3e4, params, np.random.default_rng(12))
    draw, rng = spc._paper_sampler(spc.flux_from_srgb(img, 3e4), params), np.random.default_rng(12)
    counts = np.stack([draw(rng) for _ in range(3)])
    assert np.array_equal(frames, counts > 0) and 0.2 < frames.mean() < 0.8


def test_paper_counts_are_clipped_to_dead_time_limit():
    params = _params(mode="paper", tau_d=1e-6, exposure_s=1e-5)  # at most T/tau = 10 counts
    counts = spc._paper_sampler(np.full(10_000, 1e12), params)(np.random.default_rng(4))
    assert counts.max() == 10 and counts.min() >= 0  # the limit is reached, not a lower one
    # T/tau = 2 at lam*tau = 1: E[N] = 1, sd 0.5, so unclipped draws would reach 3 (mutation testing).
    short = _params(mode="paper", tau_d=1e-6, exposure_s=2e-6)
    phi = (1e6 - short.dark_count_rate) / short.q
    counts = spc._paper_sampler(np.full(10_000, phi), short)(np.random.default_rng(4))
    assert counts.max() == 2 and counts.min() == 0
    frames = spc.simulate_frames(np.ones((5, 5, 3)), 1e12, replace(params, frames=4), np.random.default_rng(5))
    assert frames.all()


@pytest.mark.parametrize("mode", spc.MODES)
@pytest.mark.parametrize("T", [1e-12, 1e-4, 1e3])
@pytest.mark.parametrize("K", [1, 4096])
def test_saturated_and_dark_frames_at_extremes(mode, T, K):
    rng = np.random.default_rng(6)
    dark = _params(mode=mode, exposure_s=T, dark_count_rate=0.0, frames=K)
    assert not spc.simulate_frames(np.zeros((3, 5, 3)), 1e15, dark, rng).any()
    bright = _params(mode=mode, exposure_s=T, frames=K)
    frames = spc.simulate_frames(np.ones((3, 5, 3)), 1e15, bright, rng)
    assert frames.shape == (K, 3, 5, 3)
    if T >= 1e-4:
        assert frames.all()  # p = 1 - 2**-32 at most: a miss in 184k bits has odds ~4e-5
    phi_hat = spc.mle_flux(frames.sum(axis=0), K, bright)
    assert np.all(np.isfinite(phi_hat)) and np.all(phi_hat >= 0)
    assert np.all(np.isfinite(spc.mle_flux(np.zeros((3, 5, 3), int), K, bright)))


# --------------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("q", 0.0, r"q=0.0: quantum efficiency must be in \(0, 1\]"),
        ("q", 1.2, r"q=1.2: quantum efficiency"),
        ("q", float("nan"), r"q=nan"),
        ("q", "0.5", r"q='0.5'"),
        ("tau_d", -1e-9, r"tau_d=-1e-09: dead time"),
        ("exposure_s", 0.0, r"exposure_s=0.0: exposure must be finite and > 0"),
        ("exposure_s", -1e-4, r"exposure_s=-0.0001"),
        ("exposure_s", float("inf"), r"exposure_s=inf"),
        ("dark_count_rate", float("nan"), r"dark_count_rate=nan"),
        ("mode", "poisson", r"mode='poisson': unknown SPC mode; use one of \('bernoulli', 'paper'\)"),
        ("frames", 0, r"frames=0: must be an integer >= 1"),
        ("frames", 2.0, r"frames=2.0"),
        ("frames", True, r"frames=True"),
    ],
)
def test_params_validation_names_field_and_value(field, value, match):
    with pytest.raises(ValueError, match=match):
        spc.SPCParams(**{field: value})


@pytest.mark.parametrize(
    "field, value", [("q", 1.0), ("tau_d", 0.0), ("dark_count_rate", 0.0), ("exposure_s", 1e-12), ("frames", 1)]
)
def test_params_accept_the_edges_of_their_ranges(field, value):
    """An ideal detector (q = 1), no dead time, no dark counts, one frame: the closed ends of the
    ranges are valid settings (mutation testing: ``<=`` turned into ``<`` went unnoticed)."""
    assert getattr(spc.SPCParams(**{field: value}), field) == value


@pytest.mark.parametrize("field", ["tau_d", "dark_count_rate"])
def test_params_refuse_infinite_rates_and_times(field):
    with pytest.raises(ValueError, match=rf"{field}=inf: .*must be finite"):
        spc.SPCParams(**{field: float("inf")})


def test_params_are_frozen_and_one_frame_by_default():
    """Frozen: a camera shared by every view of a scene cannot be changed by one of them; K = 1 (the
    paper's single binary frame) unless asked."""
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT.q = 0.9
    assert DEFAULT.frames == 1
    assert spc.simulate_frames(np.full((2, 3, 3), 0.5), 1e4, DEFAULT, np.random.default_rng(0)).shape == (1, 2, 3, 3)


def test_flux_scale_zero_and_below_one_are_valid_and_infinity_is_not():
    img = np.full((2, 2, 3), 0.5)
    assert spc.flux_from_srgb(img, 0.0).max() == 0.0  # no light: a valid (black) exposure
    assert spc.flux_from_srgb(img, 0.5).max() == pytest.approx(0.5 * spc.srgb_to_linear(0.5))
    with pytest.raises(ValueError, match=r"flux_scale=inf: flux scale .* must be finite and >= 0"):
        spc.flux_from_srgb(img, float("inf"))


@pytest.mark.parametrize(
    "phi, match",
    [
        (np.array([0.0, 0.5, -1.0, np.nan]), r"phi: 1 NaN, 1 negative and 0 infinite values out of 4"),
        (np.array([1.0, -2.0, -3.0]), r"phi: 0 NaN, 2 negative .*minimum -3.0"),
        (np.array([np.nan, 1.0]), r"phi: 1 NaN, 0 negative .*minimum 1.0"),
        (np.array([np.inf]), r"phi: .*1 infinite"),
    ],
)
def test_flux_validation(phi, match):
    for f in (spc.detection_probability, spc.expected_counts):
        with pytest.raises(ValueError, match=match):
            f(phi, DEFAULT)


@pytest.mark.parametrize(
    "img, match",
    [
        (np.zeros((4, 4)), r"srgb: shape \(4, 4\) must be \(H, W, C\)"),
        (np.zeros((2, 4, 4, 3)), r"srgb: shape \(2, 4, 4, 3\)"),
        (np.zeros((4, 4, 3), np.uint8), r"srgb: dtype uint8 must be floating"),
        (np.full((4, 4, 3), 1.5), r"srgb: values span \[1.5, 1.5\]"),
        (np.full((4, 4, 3), np.nan), r"NaN: 48"),
        (np.array([[[0.5, np.nan, 1.5]]]), r"values span \[0.5, 1.5\] \(NaN: 1\)"),
    ],
)
def test_simulate_frames_validation(img, match):
    with pytest.raises(ValueError, match=match):
        spc.simulate_frames(img, 1e4, DEFAULT, np.random.default_rng())


def test_other_argument_validation():
    img, rng = np.zeros((2, 2, 3)), np.random.default_rng()
    with pytest.raises(ValueError, match=r"flux_scale=-1.0"):
        spc.simulate_frames(img, -1.0, DEFAULT, rng)
    with pytest.raises(ValueError, match=r"flux_scale=nan"):
        spc.flux_from_srgb(img, float("nan"))
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        spc.simulate_frames(img, 1.0, DEFAULT, 42)
    with pytest.raises(ValueError, match=r"K=0: must be an integer >= 1"):
        spc.mle_flux(np.zeros(3), 0, DEFAULT)
    with pytest.raises(ValueError, match=r"frames_sum: values span \[0.0, 5.0\].*K=4"):
        spc.mle_flux(np.array([0, 5]), 4, DEFAULT)
    with pytest.raises(ValueError, match=r"frames_sum: values span \[-1.0"):
        spc.mle_flux(np.array([-1, 2]), 4, DEFAULT)
    with pytest.raises(ValueError, match=r"frames_sum: values span \[\] \(NaN: 1\)"):
        spc.mle_flux(np.array([np.nan]), 4, DEFAULT)
    with pytest.raises(ValueError, match=r"counts: 0 NaN, 1 negative"):
        spc.deadtime_flux(np.array([-1.0]), DEFAULT)
    with pytest.raises(ValueError, match=r"view=-1"):
        spc.view_rng(0, "fern", -1)


# ------------------------------------------------------------------------- storage and seeding


@pytest.mark.parametrize("shape", [(1, 1, 1, 1), (3, 5, 7, 3), (2, 3, 1, 1), (1, 13, 11, 3), (2, 2, 2, 2)])
def test_pack_unpack_round_trip(shape):
    frames = np.random.default_rng(8).random(shape) < 0.3
    packed, got_shape = spc.pack_frames(frames)
    assert packed.dtype == np.uint8 and packed.ndim == 1 and packed.size == -(-frames.size // 8)
    assert got_shape == shape and np.array_equal(spc.unpack_frames(packed, got_shape), frames)
    with pytest.raises(ValueError, match="does not hold shape"):
        spc.unpack_frames(packed[:-1], shape)


def test_unpack_refuses_other_dtypes_ranks_and_sizes_naming_the_bytes_needed():
    packed, shape = spc.pack_frames(np.ones((1, 8, 8, 1), bool))  # 64 bits: 8 bytes
    for bad in (packed.astype(np.int16), packed.reshape(2, 4), packed[:7]):
        with pytest.raises(ValueError, match=r"does not hold shape \(1, 8, 8, 1\); need uint8 1-D with 8 bytes$"):
            spc.unpack_frames(bad, shape)


def test_frames_draw_one_raw_word_per_two_bits():
    """A view's K frames consume exactly ceil(bits / 2) raw 64-bit words of its generator, so the
    same seed gives the same frames (and the same stream after them) as the data already written."""
    rng, ref = np.random.default_rng(7), np.random.default_rng(7)
    spc.simulate_frames(np.full((2, 2, 3), 0.5), 1e4, _params(frames=3), rng)  # 36 bits: 18 words
    ref.bit_generator.random_raw(18)
    assert rng.bit_generator.random_raw(2).tolist() == ref.bit_generator.random_raw(2).tolist()


def test_view_and_seed_zero_are_valid():
    first = spc.view_rng(0, "room", 0).bit_generator.random_raw(2).tolist()
    assert first != spc.view_rng(0, "room", 1).bit_generator.random_raw(2).tolist()


def test_view_rng_is_stable_across_interpreters():
    # Python's str hash is salted per process; the scene key must not depend on it.
    code = "from spc3d.physics import spc; print(spc.view_rng(3, 'room', 5).bit_generator.random_raw(4).tolist())"
    package_root = str(Path(spc.__file__).resolve().parents[1])
    here = spc.view_rng(3, "room", 5).bit_generator.random_raw(4).tolist()
    for salt in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": salt, "PYTHONPATH": package_root}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert out.stdout.strip() == str(here)
    assert spc.view_rng(3, "rooms", 5).bit_generator.random_raw(4).tolist() != here
    assert spc.view_rng(4, "room", 5).bit_generator.random_raw(4).tolist() != here


# -------------------------------------------------------------------------------- calibration


def _scenes() -> np.ndarray:
    rng = np.random.default_rng(9)
    return rng.random((3, 40, 50, 3)).astype(np.float32) ** 2


@pytest.mark.parametrize("target", [0.05, 0.5, 0.9])
def test_calibration_hits_target(target):
    imgs = _scenes()
    for given in (imgs, list(imgs)):
        s = calibrate_flux_scale(given, DEFAULT, target)
        p = spc.detection_probability(spc.flux_from_srgb(imgs, s), DEFAULT)
        assert abs(p.mean() - target) < 1e-4


@pytest.mark.parametrize("target", [0.1, 0.5, 0.9])
def test_paper_mode_calibration_hits_target_in_its_own_frames(target):
    """Paper mode fires less than the exact model at low flux (P(Normal > 1/2), not 1 - e^-x):
    its calibration uses its own probability, so simulated paper frames reach the target."""
    imgs = _scenes()
    params = spc.SPCParams(mode="paper", frames=64)
    s = calibrate_flux_scale(imgs, params, target)
    p = frame_probability(spc.flux_from_srgb(imgs, s), params)
    assert abs(p.mean() - target) < 1e-4
    rng = np.random.default_rng(4)
    fired = np.mean([spc.simulate_frames(im, s, params, rng).mean() for im in imgs])
    assert abs(fired - target) < 0.003  # Monte Carlo of the sampler itself: 3 x 64 x 6000 bits
    exact = calibrate_flux_scale(imgs, spc.SPCParams(frames=64), target)
    assert s != pytest.approx(exact, rel=1e-3)


def test_calibration_subsample_keeps_all_channels():
    # 3.1M values -> stride 3 would see only the red channel; the stride is made coprime to C.
    img = np.empty((1000, 1024, 3), np.float32)
    img[..., 0], img[..., 1], img[..., 2] = 1.0, 0.2, 0.05
    s = calibrate_flux_scale([img], DEFAULT, 0.5)
    p = spc.detection_probability(spc.flux_from_srgb(img[:1, :3], s), DEFAULT)
    assert abs(p.mean() - 0.5) < 1e-3


def test_calibration_rejects_unreachable_targets():
    imgs = _scenes()
    p_dark = -math.expm1(-DEFAULT.dark_count_rate * DEFAULT.exposure_s)
    for bad in (0.0, p_dark, 1.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"target_mean_detection=.*reachable mean detection"):
            calibrate_flux_scale(imgs, DEFAULT, bad)
    half_black = np.zeros((1, 4, 4, 3))
    half_black[:, :2] = 0.5
    with pytest.raises(ValueError, match=r"share of black pixels \(50.000%\)"):
        calibrate_flux_scale(half_black, DEFAULT, 0.8)
    assert calibrate_flux_scale(half_black, DEFAULT, 0.4) > 0
    with pytest.raises(ValueError, match=r"srgb_images\[0\]: shape"):
        calibrate_flux_scale([np.zeros((4, 4))], DEFAULT)


# ---------------------------------------------------------------------------- flux inversion


@pytest.mark.parametrize("K", [1, 2, 64, 4096])
@pytest.mark.parametrize("T", [1e-12, 1e-4, 1e3])
def test_mle_flux_finite_and_monotone(K, T):
    params = _params(exposure_s=T)
    S = np.arange(K + 1)
    phi = spc.mle_flux(S, K, params)
    assert np.all(np.isfinite(phi)) and np.all(phi >= 0) and np.all(np.diff(phi) >= 0)
    lam_cap = (math.log(K) + math.log(2)) / T  # the saturated (S = K) clamp
    assert phi[-1] == pytest.approx(max(lam_cap - params.dark_count_rate, 0) / params.q, rel=1e-12)
    assert phi[0] == 0.0  # all-dark: dark counts subtracted, clipped at zero


def test_mle_flux_inverts_detection_probability():
    K = 1_000_000
    phi = np.array([1e2, 1e3, 1e4, 5e4, 1e5])
    p = spc.detection_probability(phi, DEFAULT)
    S = np.round(K * p)
    phi_hat = spc.mle_flux(S, K, DEFAULT)
    # binomial sd of S/K mapped through d(phi)/dp = 1 / (q T (1 - p))
    tol = 5 * np.sqrt(p * (1 - p) / K) / (DEFAULT.q * DEFAULT.exposure_s * (1 - p))
    assert np.all(np.abs(phi_hat - phi) <= tol)
    assert np.allclose(spc.detection_probability(phi_hat, DEFAULT), S / K, rtol=1e-12)


def test_mle_of_simulated_frames_recovers_flux():
    K, scale = 4096, 1e5
    params = _params(frames=K)
    frames = spc.simulate_frames(_level_image(), scale, params, np.random.default_rng(10))
    phi = spc.flux_from_srgb(LEVELS, scale)
    p = spc.detection_probability(phi, params)
    S = frames.sum(axis=0).mean(axis=(1, 2)) * 1.0  # per-level mean ones count
    phi_hat = spc.mle_flux(np.round(S), K, params)
    tol = 5 * np.sqrt(p * (1 - p) / (12 * K)) / (params.q * params.exposure_s * (1 - p)) + 0.5 / (
        K * params.q * params.exposure_s * (1 - p)
    )  # binomial over 12 pixels + rounding of S
    assert np.all(np.abs(phi_hat - phi)[1:] <= tol[1:])
    # every pixel alone too (n = K bits each), below saturation (the last level has p > 0.98)
    px_hat = spc.mle_flux(frames.sum(axis=0), K, params)  # (7, 4, 3)
    px_tol = 5 * np.sqrt(p * (1 - p) / K) / (params.q * params.exposure_s * (1 - p))
    assert np.all(np.abs(px_hat - phi[:, None, None])[1:-1] <= px_tol[1:-1, None, None])


@pytest.mark.parametrize("tau", [0.0, 150e-9])
def test_deadtime_flux_inverts_expected_counts(tau):
    params = _params(tau_d=tau)
    phi = np.logspace(3, 10, 50)  # up to lam*tau ~ 700 when tau > 0
    phi_hat = spc.deadtime_flux(spc.expected_counts(phi, params), params)
    assert np.allclose(phi_hat, phi, rtol=1e-2)
    assert np.all(np.diff(phi_hat) > 0)


def test_deadtime_flux_clamps_saturated_counts():
    params = _params(tau_d=1e-6, exposure_s=1e-5)  # T/tau = 10
    phi = spc.deadtime_flux(np.array([0.0, 5.0, 9.5, 10.0, 1e9]), params)
    assert np.all(np.isfinite(phi)) and np.all(np.diff(phi) >= 0)
    assert phi[2] == pytest.approx(phi[3], rel=1e-12) and phi[3] == phi[4]  # N <= T/tau - 1/2
    assert phi[0] == 0.0
    short = _params(tau_d=1e-6, exposure_s=1e-7)  # T < tau: margin shrinks to T/(2 tau)
    assert np.all(np.isfinite(spc.deadtime_flux(np.array([0.0, 1.0, 3.0]), short)))
    # There N is clamped to T/(2 tau), so lam = N / (T - N tau) = 1/tau (mutation testing: T/(3 tau) passed).
    expected = (1.0 / short.tau_d - short.dark_count_rate) / short.q
    assert spc.deadtime_flux(np.array([1.0]), short)[0] == pytest.approx(expected, rel=1e-9)

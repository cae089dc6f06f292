"""The Monte-Carlo renewal simulator against exact results and the paper's eqs. (1)-(2)."""

import math

import numpy as np
import pytest

from spc3d.physics import spc
from spc3d.physics.montecarlo import simulate_counts

pytestmark = pytest.mark.filterwarnings("error")

TAU = 150e-9
PARAMS = spc.SPCParams(tau_d=TAU, dark_count_rate=100.0)
LOADS = [1e-3, 1e-2, 1e-1, 1.0, 10.0]  # lam*tau, from photon-starved to 10x dead-time saturated


def _flux_for_load(load: float, params: spc.SPCParams) -> float:
    """Photon flux whose detection rate q*phi + dcr equals load/tau."""
    return (load / params.tau_d - params.dark_count_rate) / params.q


def _sample_stats(counts: np.ndarray) -> tuple[float, float, float, float]:
    """Mean, variance and their standard errors (variance SE from the fourth central moment)."""
    n = counts.size
    c = counts - counts.mean()
    var = float(np.mean(c**2))
    return float(counts.mean()), var, math.sqrt(var / n), math.sqrt(max(np.mean(c**4) - var**2, 0) / n)


@pytest.mark.parametrize("load", LOADS)
def test_mc_mean_matches_exact_renewal_asymptote(load):
    # Checks the simulator itself: counting from a live start at t = 0 equals an ordinary renewal
    # process (period mu = tau + 1/lam, variance 1/lam^2) observed on [-tau, T], whose mean is
    # (T + tau)/mu + (sigma^2 - mu^2)/(2 mu^2) + o(1) (the O(1) term that eq. 1 omits).
    lam, T = load / TAU, 200 * TAU
    counts = simulate_counts(lam, T, TAU, 40_000, np.random.default_rng(1))
    mean, _, se, _ = _sample_stats(counts)
    mu = TAU + 1 / lam
    exact = (T + TAU) / mu + (lam**-2 - mu**2) / (2 * mu**2)
    assert abs(mean - exact) <= 5 * se + 1e-3 * exact


@pytest.mark.parametrize("load", LOADS)
def test_mc_mean_and_variance_match_paper_equations(load):
    # Eqs. (1)-(2) are asymptotic in T/tau with O(1) corrections (~0.4 counts in the mean, ~0.1 in
    # the variance at lam*tau = 10), so T grows with the load and a small relative term is allowed.
    phi = _flux_for_load(load, PARAMS)
    T = 200 * TAU * (1 + load)
    params = spc.SPCParams(tau_d=TAU, exposure_s=T, dark_count_rate=PARAMS.dark_count_rate)
    lam = float(spc.detection_rate(phi, params))
    counts = simulate_counts(lam, T, TAU, 10_000, np.random.default_rng(2))
    mean, var, se_mean, se_var = _sample_stats(counts)
    eq1, eq2 = float(spc.expected_counts(phi, params)), float(spc.count_variance(phi, params))
    assert abs(mean - eq1) <= 5 * se_mean + 5e-3 * eq1
    assert abs(var - eq2) <= 5 * se_var + 2e-2 * eq2


@pytest.mark.parametrize("load", LOADS)
def test_mc_detection_probability_is_unaffected_by_dead_time(load):
    # T = tau/load gives lam*T = 1 for every load: P(N >= 1) = 1 - 1/e whatever the dead time.
    phi = _flux_for_load(load, PARAMS)
    params = spc.SPCParams(tau_d=TAU, exposure_s=TAU / load, dark_count_rate=PARAMS.dark_count_rate)
    n = 40_000
    counts = simulate_counts(
        float(spc.detection_rate(phi, params)), params.exposure_s, TAU, n, np.random.default_rng(3)
    )
    p = float(spc.detection_probability(phi, params))
    assert p == pytest.approx(1 - math.exp(-1), rel=1e-9)
    assert abs(np.mean(counts >= 1) - p) <= 5 * math.sqrt(p * (1 - p) / n)


def test_mc_without_dead_time_is_poisson():
    counts = simulate_counts(5e5, 1e-4, 0.0, 20_000, np.random.default_rng(4))  # lam*T = 50
    mean, var, se_mean, se_var = _sample_stats(counts)
    assert abs(mean - 50) <= 5 * se_mean and abs(var - 50) <= 5 * se_var


def test_mc_edge_cases_and_validation():
    rng = np.random.default_rng(5)
    assert not simulate_counts(0.0, 1.0, TAU, 10, rng).any()
    with pytest.raises(ValueError, match=r"rate\*T=.*expected arrivals"):
        simulate_counts(1e12, 1.0, TAU, 10, rng)
    with pytest.raises(ValueError, match="rate=-1.0"):
        simulate_counts(-1.0, 1.0, TAU, 10, rng)
    with pytest.raises(ValueError, match="T=0"):
        simulate_counts(1.0, 0, TAU, 10, rng)
    with pytest.raises(ValueError, match="n_trials=0"):
        simulate_counts(1.0, 1.0, TAU, 0, rng)

"""Monte-Carlo renewal simulator of a non-paralyzable SPAD (reference for the tests of ``spc``).

Detections arrive as a Poisson process of rate ``rate`` (= q*phi + dcr). The detector is live at
t = 0; after each detection it is blind for ``tau_d`` and arrivals in that window are lost. The
Poisson process is memoryless, so the next detection is the previous one + tau_d + Exp(rate).
Counts are the detections inside [0, T]. Vectorised across trials: the loop runs over detection
index (about rate*T/(1 + rate*tau_d) steps), each step drawing one exponential per live trial.
"""

from __future__ import annotations

import math

import numpy as np

MAX_EXPECTED_COUNTS = 1e5  # rate*T above this would take too long and hold too much memory


def simulate_counts(rate: float, T: float, tau_d: float, n_trials: int, rng: np.random.Generator) -> np.ndarray:
    """Detection counts in [0, T] of ``n_trials`` independent exposures; int64 (n_trials,)."""
    if not (0.0 <= rate < math.inf):
        raise ValueError(f"rate={rate!r}: detection rate must be finite and >= 0 counts/s")
    if not (0.0 < T < math.inf):
        raise ValueError(f"T={T!r}: exposure must be finite and > 0 s")
    if not (0.0 <= tau_d < math.inf):
        raise ValueError(f"tau_d={tau_d!r}: dead time must be finite and >= 0 s")
    if isinstance(n_trials, bool) or not isinstance(n_trials, int) or n_trials < 1:
        raise ValueError(f"n_trials={n_trials!r}: must be an integer >= 1")
    if rate * T > MAX_EXPECTED_COUNTS:
        raise ValueError(
            f"rate*T={rate * T:.3g}: more than {MAX_EXPECTED_COUNTS:.0e} expected arrivals "
            f"per trial; lower the rate or the exposure"
        )
    counts = np.zeros(n_trials, dtype=np.int64)
    if rate == 0.0:
        return counts  # no arrivals at all
    scale = 1.0 / rate
    live = np.arange(n_trials)  # trials whose latest detection time is still inside [0, T]
    t = rng.standard_exponential(n_trials) * scale  # first detection: the detector starts live
    while live.size:
        inside = t <= T
        live, t = live[inside], t[inside]
        counts[live] += 1
        t = t + tau_d + rng.standard_exponential(live.size) * scale
    return counts

"""The simulator checked against a real SPAD capture: frame means of one scene at several K.

A real capture often comes as means of K = 1, 4, ..., K_ref binary frames of one static scene
(:func:`spc3d.captures.photon_cubes.read_frame_mean`). From the longest mean the detection
probability of every pixel is estimated, p̂ = S/K_ref, and with it the photons detected per frame,
λT = q φ T + dcr T = -log(1 - p) (:func:`lam_t`, the simulator's own MLE with its reasoned clamp at
p̂ = 1). The simulator then draws frames from λT (:func:`simulate_means`) and every statistic below
is computed on the real and on the simulated means alike:

``nested_ratio``   Σ (m_K - m_ref)² / Σ p̂(1 - p̂)/K: the spread of a K-mean around the reference in
                   units of the binomial variance. Its expectation depends on whether the K frames
                   are among the reference's: independent frames give (1 + K/K_ref)/(1 - 1/K_ref),
                   frames nested in the reference (1 - K/K_ref)/(1 - 1/K_ref), since then
                   Var(m_K - m_ref) = p(1-p)(1/K - 1/K_ref) (:func:`ratio_predictions`).
``disjoint_ratio`` Σ (m_K - m_rest)² / Σ v (1/K + 1/(K_ref - K)), m_rest the mean of the reference's
                   other K_ref - K frames (valid when nested) and v = p̂(1-p̂) K_ref/(K_ref - 1) (unbiased):
                   1 for independent Bernoulli bits whatever p is.
``violations``     pixels where a shorter mean cannot be part of a longer one (fewer ones in the
                   longer, or more new ones than new frames): 0 when nested.
``histogram_tv``   total-variation distance between the histogram of the counts S_K and its exact
                   expectation given S_ref when nested: hypergeometric(K_ref, S_ref, K) per pixel
                   (exchangeable frames; no parameter estimated).
``neighbour_corr`` correlation of the residuals m_K - m_rest of neighbouring pixels (right, down,
                   diagonal): 0 without crosstalk (a detection in one pixel triggering its neighbour).
``hot``, ``cold``  hot pixels (:func:`spc3d.physics.hot_pixels.detect_hot_pixels` on S_ref) and cold
                   (dead) ones: the hot pixels of the complement K_ref - S_ref, pixels that fire far
                   *less* than their neighbours. The simulation for these draws from λT with the
                   flagged pixels replaced by their neighbours' median: what the simulator makes of a
                   scene, which has neither.

Intervals: the real figures get a bootstrap over square pixel blocks (:func:`block_bootstrap`: the
blocks are resampled with replacement, so correlation within a block is kept); the simulated ones
the 2.5-97.5 % range over independent simulator draws.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.stats import hypergeom

from spc3d.physics import spc
from spc3d.physics.hot_pixels import detect_hot_pixels, neighbour_median

# Unit physics: q = 1, T = 1 s, no dark counts, no dead time: a "flux" in these units is λT itself,
# the photons (and dark counts) detected per frame, which is all one pixel's bits determine.
UNIT = spc.SPCParams(q=1.0, tau_d=0.0, exposure_s=1.0, dark_count_rate=0.0)
NEIGHBOURS = {"right": (0, 1), "down": (1, 0), "diagonal": (1, 1)}


def lam_t(counts: np.ndarray, frames: int) -> np.ndarray:
    """Detections per frame λT = -log1p(-S/K) of every pixel (float64), the simulator's MLE
    (:func:`spc3d.physics.spc.mle_flux` in unit physics): a pixel that fired in every frame has
    no finite estimate and is clamped at ln(2K), above the S = K - 1 value ln K."""
    return spc.mle_flux(counts, frames, UNIT)


def simulate_means(lam: np.ndarray, ks: Sequence[int], rng: np.random.Generator, nested: bool = True) -> dict:
    """{K: counts (H, W) int64} of frames the simulator draws from ``lam`` (λT per pixel): nested,
    the first K of max(ks) frames for every K (as a capture's prefix means); else independent
    frames for each K."""
    ks = sorted(ks)
    params = dataclasses.replace(UNIT, frames=ks[-1])
    if not nested:
        return {k: spc.simulate_plane(lam, dataclasses.replace(UNIT, frames=k), rng).sum(0, dtype=np.int64) for k in ks}
    cum = np.cumsum(spc.simulate_plane(lam, params, rng), axis=0, dtype=np.int64)
    return {k: cum[k - 1] for k in ks}


def ratio_predictions(k: int, k_ref: int) -> dict:
    """Expected :func:`nested_ratio` terms for independent and for nested frames (see the module)."""
    return {"independent": (1 + k / k_ref) / (1 - 1 / k_ref), "nested": (1 - k / k_ref) / (1 - 1 / k_ref)}


# --------------------------------------------------------------------------------------------
# block sums and the bootstrap


def block_sums(values: np.ndarray, block: int) -> np.ndarray:
    """(n_blocks,) sums of (H, W) ``values`` over square blocks of ``block`` pixels (the partial
    blocks at the right and bottom edges are dropped; NaN counts as 0)."""
    h, w = (values.shape[0] // block) * block, (values.shape[1] // block) * block
    if h == 0 or w == 0:
        raise ValueError(f"block={block} is larger than the image {values.shape}: use a smaller block")
    v = np.nan_to_num(values[:h, :w].astype(np.float64))
    return v.reshape(h // block, block, w // block, block).sum(axis=(1, 3)).reshape(-1)


def block_bootstrap(
    parts: Sequence[np.ndarray], statistic, draws: int, rng: np.random.Generator, level: float = 0.95
) -> tuple[float, float]:
    """Percentile interval of ``statistic(*sums)`` with the blocks of every ``parts`` array (block
    sums, one per block, all alike) resampled together ``draws`` times."""
    n = len(parts[0])
    idx = rng.integers(0, n, size=(draws, n))
    values = statistic(*(p[idx].sum(1) for p in parts))
    lo, hi = np.nanquantile(values, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


@dataclasses.dataclass
class Figure:
    """One statistic: its value and the per-block parts it is a function of (for the bootstrap)."""

    value: float
    parts: tuple[np.ndarray, ...]
    statistic: object  # callable(*sums) -> value(s)

    def interval(self, draws: int, rng: np.random.Generator) -> tuple[float, float]:
        return block_bootstrap(self.parts, self.statistic, draws, rng)


def _ratio(a, b):
    return a / b


def _figure(statistic, arrays: Sequence[np.ndarray], block: int) -> Figure:
    parts = tuple(block_sums(a, block) for a in arrays)
    return Figure(float(statistic(*(p.sum() for p in parts))), parts, statistic)


# --------------------------------------------------------------------------------------------
# the statistics


def binomial_variance(counts_ref: np.ndarray, k_ref: int) -> np.ndarray:
    """Unbiased per-pixel p(1-p) from S_ref ones among K_ref frames: p̂(1-p̂) K_ref/(K_ref - 1)."""
    p = counts_ref / k_ref
    return p * (1 - p) * k_ref / (k_ref - 1)


def nested_ratio(counts: np.ndarray, k: int, counts_ref: np.ndarray, k_ref: int, block: int) -> Figure:
    p = counts_ref / k_ref
    return _figure(_ratio, [(counts / k - p) ** 2, p * (1 - p) / k], block)


def disjoint_ratio(counts: np.ndarray, k: int, counts_ref: np.ndarray, k_ref: int, block: int) -> Figure:
    rest = (counts_ref - counts) / (k_ref - k)
    expected = binomial_variance(counts_ref, k_ref) * (1 / k + 1 / (k_ref - k))
    return _figure(_ratio, [(counts / k - rest) ** 2, expected], block)


def violations(counts_short: np.ndarray, k_short: int, counts_long: np.ndarray, k_long: int) -> int:
    """Pixels whose shorter mean cannot be the first frames of the longer: S_long < S_short, or
    S_long - S_short > K_long - K_short."""
    more = counts_long - counts_short
    return int(((more < 0) | (more > k_long - k_short)).sum())


def hypergeometric_histogram(counts_ref: np.ndarray, k_ref: int, k: int) -> np.ndarray:
    """(k + 1,) expected number of pixels with each count S_k when the k frames are k of the
    reference's K_ref exchangeable frames: Σ_pixels hypergeom(K_ref, S_ref, k)."""
    values, n = np.unique(counts_ref, return_counts=True)
    s = np.arange(k + 1)
    return (n[:, None] * hypergeom.pmf(s[None, :], k_ref, values[:, None], k)).sum(0)


def histogram_tv(counts: np.ndarray, k: int, counts_ref: np.ndarray, k_ref: int) -> float:
    """Total-variation distance between the histogram of S_k and its hypergeometric expectation."""
    seen = np.bincount(counts.reshape(-1), minlength=k + 1)[: k + 1] / counts.size
    expected = hypergeometric_histogram(counts_ref, k_ref, k) / counts.size
    return float(0.5 * np.abs(seen - expected).sum())


def _corr(ab, aa, bb):
    return ab / np.sqrt(aa * bb)


def neighbour_corr(
    counts: np.ndarray, k: int, counts_ref: np.ndarray, k_ref: int, offset: tuple[int, int], block: int
) -> Figure:
    """Correlation of the residuals m_K - m_rest at pixels ``offset`` (dy, dx) apart (residuals of
    disjoint frames: mean 0 at every p, so the scene's texture does not enter)."""
    r = counts / k - (counts_ref - counts) / (k_ref - k)
    r = r - r.mean()
    dy, dx = offset
    h, w = r.shape
    a, b = r[: h - dy, : w - dx], r[dy:, dx:]
    return _figure(_corr, [a * b, a * a, b * b], block)


def outliers(counts_ref: np.ndarray, k_ref: int, threshold: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """(hot, cold) (H, W) bool: pixels firing far above / below their neighbours over K_ref frames."""
    hot, _ = detect_hot_pixels(counts_ref, k_ref, None, threshold)
    cold, _ = detect_hot_pixels(k_ref - counts_ref, k_ref, None, threshold)
    return hot, cold


def clean_scene(lam: np.ndarray, flagged: np.ndarray, window: int = 5) -> np.ndarray:
    """λT with the ``flagged`` pixels replaced by the median of their unflagged neighbours: the scene
    the simulator would be given, without the sensor's hot and dead pixels."""
    values = np.where(flagged, np.nan, lam)
    med = neighbour_median(values, np.zeros(lam.shape, int), window)
    return np.where(flagged, np.nan_to_num(med, nan=float(np.nanmedian(values))), lam)


# --------------------------------------------------------------------------------------------
# the whole check


def _range(values: Sequence[float]) -> tuple[float, float, float]:
    v = np.asarray(values, dtype=np.float64)
    lo, hi = np.quantile(v, [0.025, 0.975])
    return float(v.mean()), float(lo), float(hi)


def statistics(counts: dict, k_ref: int, block: int, threshold: float = 6.0) -> dict:
    """Every statistic of the module on one set of means {K: counts}, with their :class:`Figure`
    where a bootstrap applies. Keys: (name, K or pair or direction)."""
    ref = counts[k_ref]
    ks = sorted(k for k in counts if k != k_ref)
    out: dict = {}
    for k in ks:
        out["nested_ratio", k] = nested_ratio(counts[k], k, ref, k_ref, block)
        out["disjoint_ratio", k] = disjoint_ratio(counts[k], k, ref, k_ref, block)
        out["histogram_tv", k] = histogram_tv(counts[k], k, ref, k_ref)
    chain = [*ks, k_ref]
    for a, b in zip(chain[:-1], chain[1:]):
        out["violations", (a, b)] = violations(counts[a], a, counts[b], b)
    for name, offset in NEIGHBOURS.items():
        out["neighbour_corr", name] = neighbour_corr(counts[ks[0]], ks[0], ref, k_ref, offset, block)
    hot, cold = outliers(ref, k_ref, threshold)
    out["hot", None], out["cold", None] = int(hot.sum()), int(cold.sum())
    out["detection_rate", ks[0]] = float(counts[ks[0]].mean() / ks[0])
    return out


def compare(
    real: dict, k_ref: int, draws: int, seed: int = 0, block: int = 16, bootstrap: int = 1000, threshold: float = 6.0
) -> dict:
    """Real means {K: counts} against ``draws`` simulator draws from the reference's λT.

    Returns {"real": {key: (value, lo, hi)}, "sim": {key: (mean, lo, hi)}, "independent":
    {key: (mean, lo, hi)} (violations of independent draws, for scale), "predictions": {K: {...}},
    "pixels", "frames"}. Keys as :func:`statistics`; intervals as the module says.
    """
    rng = np.random.default_rng(seed)
    real_stats = statistics(real, k_ref, block, threshold)
    real_out = {}
    for key, fig in real_stats.items():
        if isinstance(fig, Figure):
            real_out[key] = (fig.value, *fig.interval(bootstrap, rng))
        else:
            real_out[key] = (fig, fig, fig)
    lam = lam_t(real[k_ref], k_ref)
    hot, cold = outliers(real[k_ref], k_ref, threshold)
    ks = sorted(real)
    sim_values: dict = {}
    indep_values: dict = {}
    for _ in range(draws):
        sim = simulate_means(lam, ks, rng)
        stats = statistics(sim, k_ref, block, threshold)
        clean = statistics(simulate_means(clean_scene(lam, hot | cold), ks, rng), k_ref, block, threshold)
        for key, fig in stats.items():
            value = clean[key] if key[0] in ("hot", "cold") else fig
            sim_values.setdefault(key, []).append(value.value if isinstance(value, Figure) else value)
        indep = simulate_means(lam, ks, rng, nested=False)
        chain = ks
        for a, b in zip(chain[:-1], chain[1:]):
            indep_values.setdefault(("violations", (a, b)), []).append(violations(indep[a], a, indep[b], b))
        for k in ks[:-1]:
            indep_values.setdefault(("nested_ratio", k), []).append(
                nested_ratio(indep[k], k, indep[k_ref], k_ref, block).value
            )
    h, w = real[k_ref].shape
    return {
        "real": real_out,
        "sim": {key: _range(v) for key, v in sim_values.items()},
        "independent": {key: _range(v) for key, v in indep_values.items()},
        "predictions": {k: ratio_predictions(k, k_ref) for k in ks[:-1]},
        "pixels": h * w,
        "shape": (h, w),
        "frames": {int(k): int(k) for k in ks},
        "k_ref": k_ref,
        "draws": draws,
        "bootstrap": bootstrap,
        "block": block,
        "hot": np.argwhere(hot).tolist(),
        "cold": np.argwhere(cold).tolist(),
    }

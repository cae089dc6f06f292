"""The paper's claims and this project's, decided from the numbers: ``results/tables/findings.{md,json,html}``.

A claim compares rows of the tables on **paired** units: the same scene, seed and held-out view
scored for both rows (PSNR, dB). Its effect is the mean paired difference with a 95 % bootstrap
interval (units resampled with replacement, 10,000 times, fixed seed; the *expanded* percentile
interval, which keeps its coverage at the handful of units a CPU run has). The verdict:

    HOLDS           the interval lies above 0 (for every comparison the claim needs)
    DOES NOT HOLD   the interval lies below 0 (for at least one)
    INCONCLUSIVE    otherwise, or too few paired units (< 3), or a row is missing

A claim that a row is *best* compares it with every other row of its group and reports the
closest; claims compare rows of equal photon budget K only. Views of one scene are not
independent, so with one scene and one seed the interval describes these views, not scenes in
general: n is printed with every claim, and more scenes and seeds (``seeds: N``) widen the base.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from . import io
from .workflow import STAGE1_METHODS

METRIC = "psnr"
LEVEL = 0.95
N_BOOT = 10_000
MIN_UNITS = 3


def per_view(metrics_files: list[str | os.PathLike]) -> pd.DataFrame:
    """One row per (combination, scene, seed, view) with its PSNR and the row's K."""
    rows = []
    for path in metrics_files:
        rec = io.read_json(path)
        for v in rec.get("per_view") or []:  # a row that was not reconstructed has no views
            rows.append(
                {
                    "combination": rec["combination"],
                    "scene": rec["scene"],
                    "seed": rec.get("seed"),
                    "view": v["view"],
                    "K": rec.get("frames"),
                    METRIC: v[METRIC],
                }
            )
    return pd.DataFrame(rows, columns=["combination", "scene", "seed", "view", "K", METRIC])


def paired(df: pd.DataFrame, a: str, b: str) -> np.ndarray:
    """PSNR of row ``a`` minus row ``b`` on the units both were scored on (scene, seed, view)."""
    keys = ["scene", "seed", "view"]
    x = df[df["combination"] == a].set_index(keys)[METRIC]
    y = df[df["combination"] == b].set_index(keys)[METRIC]
    both = x.index.intersection(y.index)
    return (x.loc[both] - y.loc[both]).to_numpy(dtype=np.float64)


def expanded_level(n: int, level: float = LEVEL) -> float:
    """The nominal level of the *expanded* percentile bootstrap (Hesterberg 2015): the plain
    percentile interval is too narrow for small n (it behaves like z·s/√n with the biased s); the
    expanded one takes the percentiles at the level whose normal quantile is √(n/(n-1))·t_{n-1},
    so it matches the t interval's width for normal data and stays a bootstrap interval otherwise."""
    from scipy import stats

    if n < 2:
        return level
    z = math.sqrt(n / (n - 1)) * stats.t.ppf((1 + level) / 2, n - 1)
    return float(2 * stats.norm.cdf(z) - 1)


def bootstrap(
    diffs: np.ndarray, n_boot: int = N_BOOT, level: float = LEVEL, seed: int = 0
) -> tuple[float, float, float]:
    """(mean, low, high): the mean of ``diffs`` and its expanded percentile bootstrap interval."""
    diffs = np.asarray(diffs, dtype=np.float64)
    if diffs.size == 0 or not np.isfinite(diffs).all():
        raise ValueError(
            f"bootstrap: need finite paired differences, got {diffs.size} values "
            f"({int((~np.isfinite(diffs)).sum())} not finite)"
        )
    rng = np.random.default_rng(seed)
    means = diffs[rng.integers(0, diffs.size, size=(n_boot, diffs.size))].mean(axis=1)
    wide = expanded_level(diffs.size, level)
    lo, hi = np.quantile(means, [(1 - wide) / 2, (1 + wide) / 2])
    return float(diffs.mean()), float(lo), float(hi)


@dataclass
class Comparison:
    better: str  # the row claimed better
    worse: str
    n: int
    mean: float | None = None
    low: float | None = None
    high: float | None = None

    @property
    def verdict(self) -> str:
        if self.mean is None or self.n < MIN_UNITS:
            return "INCONCLUSIVE"
        return "HOLDS" if self.low > 0 else "DOES NOT HOLD" if self.high < 0 else "INCONCLUSIVE"


def compare(df: pd.DataFrame, better: str, worse: str) -> Comparison:
    diffs = paired(df, better, worse)
    if diffs.size < MIN_UNITS or not np.isfinite(diffs).all():
        return Comparison(better, worse, int(diffs.size))
    return Comparison(better, worse, int(diffs.size), *bootstrap(diffs))


def verdict(comparisons: list[Comparison]) -> str:
    """HOLDS if every comparison holds, DOES NOT HOLD if any fails clearly, else INCONCLUSIVE."""
    verdicts = [c.verdict for c in comparisons]
    if not verdicts:
        return "INCONCLUSIVE"
    if "DOES NOT HOLD" in verdicts:
        return "DOES NOT HOLD"
    return "HOLDS" if all(v == "HOLDS" for v in verdicts) else "INCONCLUSIVE"


def claims(rows: set[str], nerf: str) -> list[tuple[str, str, list[tuple[str, str]]]]:
    """(who claims it, statement, [(better row, worse row), ...]) for the rows that ran (K = 1 rows)."""
    two_stage = [f"{m}+{f}" for m in STAGE1_METHODS for f in (nerf, "3dgs") if f"{m}+{f}" in rows]
    out = [
        (
            "paper",
            f"Pix2PixHD + NeRF [{nerf}] is the best two-stage combination",
            [(f"pix2pixhd+{nerf}", r) for r in two_stage if r != f"pix2pixhd+{nerf}"],
        ),
        (
            "paper",
            "Pix2PixHD + 3DGS beats every two-stage combination with another translator",
            [("pix2pixhd+3dgs", r) for r in two_stage if not r.startswith("pix2pixhd+")],
        ),
        (
            "paper",
            f"Two-stage beats single-stage with NeRF [{nerf}] (Pix2PixHD + NeRF vs NeRF on binary)",
            [(f"pix2pixhd+{nerf}", f"none+{nerf}")],
        ),
        (
            "paper",
            "Two-stage beats single-stage with 3DGS (Pix2PixHD + 3DGS vs 3DGS on binary)",
            [("pix2pixhd+3dgs", "none+3dgs")],
        ),
        (
            "paper",
            "Denoise-then-reconstruct (Restormer, diffusion as DiffBIR stand-in) is worse than Pix2PixHD",
            [(f"pix2pixhd+{f}", f"{d}+{f}") for d in ("restormer", "diffusion") for f in (nerf, "3dgs")],
        ),
        (
            "ours",
            "The SPAD likelihood on binary frames (3DGS) beats the best two-stage row at equal K",
            [("bernoulli+3dgs", r) for r in two_stage],
        ),
        ("ours", "The SPAD likelihood beats the MLE image at equal K (both + 3DGS)", [("bernoulli+3dgs", "mle+3dgs")]),
    ]
    return [(who, text, [(a, b) for a, b in pairs if a in rows and b in rows]) for who, text, pairs in out]


def evaluate_claims(df: pd.DataFrame, nerf: str) -> list[dict]:
    """Every claim with its comparisons, the decisive one, the verdict and n."""
    k1 = df[df["K"].isna() | (df["K"] == df["K"].min())]  # equal budgets: the smallest K (gt has none)
    results = []
    for who, text, pairs in claims(set(k1["combination"]), nerf):
        comps = [compare(k1, a, b) for a, b in pairs]
        scored = [c for c in comps if c.mean is not None]
        closest = min(scored, key=lambda c: c.low) if scored else max(comps, key=lambda c: c.n, default=None)
        results.append(
            {
                "claim": text,
                "by": who,
                "verdict": verdict(comps),
                "closest": closest.__dict__ if closest else None,
                "comparisons": [c.__dict__ | {"verdict": c.verdict} for c in comps],
                "n": min((c.n for c in comps), default=0),
            }
        )
    return results


def markdown(results: list[dict]) -> str:
    lines = [
        "# Findings",
        "",
        f"Each claim: mean paired PSNR difference (dB) over scenes × seeds × held-out views, with its "
        f"{LEVEL:.0%} bootstrap interval ({N_BOOT:,} resamples); HOLDS / DOES NOT HOLD when the interval "
        f"excludes 0, else INCONCLUSIVE. A 'best' claim shows its closest competitor. Rows of equal K only.",
        "",
        "| claim | by | verdict | closest comparison | Δ PSNR (dB) | 95 % interval | n |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(f"| {r['claim']} | {r['by']} | **{r['verdict']}** | " + " | ".join(_cells(r["closest"])) + " |")
    return "\n".join(lines) + "\n"


def _cells(c: dict | None) -> list[str]:
    """(comparison, difference, interval, n) of a claim's decisive comparison, or why there is none."""
    if c is None:
        return ["rows not in this run", "–", "–", "0"]
    if c["mean"] is None:
        return [f"{c['better']} vs {c['worse']}: too few paired units (< {MIN_UNITS})", "–", "–", str(c["n"])]
    return [f"{c['better']} vs {c['worse']}", f"{c['mean']:+.2f}", f"[{c['low']:+.2f}, {c['high']:+.2f}]", str(c["n"])]


def write_findings(metrics_files: list[str], stem: str | os.PathLike, nerf_variant: str) -> list[dict]:
    """``stem``.md, .json and .html from the metrics files (per-view scores)."""
    stem = Path(stem)
    results = evaluate_claims(per_view(metrics_files), nerf_variant) if metrics_files else []
    io.write_json(stem.with_suffix(".json"), {"metric": METRIC, "level": LEVEL, "n_boot": N_BOOT, "claims": results})
    md = markdown(results)
    io.write_text(stem.with_suffix(".md"), md)
    io.write_text(stem.with_suffix(".html"), _html(results))
    return results


def _html(results: list[dict]) -> str:
    rows = "".join(
        f"<tr><td>{r['claim']}</td><td>{r['by']}</td><td><b>{r['verdict']}</b></td>"
        + "".join(f"<td>{cell}</td>" for cell in _cells(r["closest"]))
        + "</tr>"
        for r in results
    )
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Findings</title><style>body{font-family:"
        "sans-serif;font-size:13px;margin:12px}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
        "padding:3px 6px}</style></head><body><h3>Findings: the claims, decided from the numbers</h3><table>"
        "<tr><th>claim</th><th>by</th><th>verdict</th><th>closest comparison</th><th>Δ PSNR (dB)</th>"
        f"<th>95 % interval</th><th>n</th></tr>{rows}</table><p>Paired over scenes × seeds × held-out views; "
        f"{N_BOOT:,} bootstrap resamples; rows of equal K only.</p></body></html>\n"
    )

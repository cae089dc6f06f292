"""The paper's claims and this project's, decided from the numbers: ``results/tables/findings.{md,json,html}``.

**The unit is the run.** A run is one (scene, seed). Each row of the tables is fitted once per run
and its held-out views are averaged inside the run (``metrics.json``'s ``mean``): the views of one
fit share its noise (the SPC draw, the translator, the fit's initialisation), so they are one piece
of evidence, not many. A claim compares two rows on the runs both have: one paired PSNR
difference (dB) per run.

**The test** is the exact sign-flip permutation test (Fisher 1935, Pitman 1937); its statistic is
the mean paired difference. If the two rows are exchangeable within a run (no method difference),
each paired difference is symmetric about 0 whatever its distribution, so the 2^n sign patterns are
equally likely and the two-sided p (the fraction of patterns whose |mean| reaches the observed one)
is exact: no normality, no large n. A t-interval is not used: at small n it is liberal for
light-tailed or lumpy differences (with ±1 differences at n = 3, t rejects 25 % of the time, the
same flaw as a percentile bootstrap over views). Up to 16 runs every pattern is enumerated; above,
2^16 random patterns (fixed seed) give p = (1 + count) / (1 + B). The 95 % interval is the test
inverted: the shifts δ whose test on d − δ is not rejected at 5 % (ends found by bisection).

**The price is discreteness.** The smallest two-sided p is 2 / 2^n: n = 5 gives 0.0625 (it can
never reject at 5 %), n = 6 gives 0.031, n = 9 gives 0.0039. Hence ``MIN_RUNS`` = 6, the smallest n
at which the test can reject at all; at n = 6 with every run agreeing in sign the interval is
exactly [min, max] of the run differences. With fewer paired runs a claim is DESCRIPTIVE ONLY: its
mean difference, the range [min, max] of its run differences (a range, not an interval) and n.

**A claim** has m comparisons (better row, worse row); their p-values are Holm-adjusted:

    HOLDS             every comparison has a positive mean and adjusted p ≤ 0.05
    DOES NOT HOLD     some comparison has a negative mean and adjusted p ≤ 0.05
    INCONCLUSIVE      otherwise
    DESCRIPTIVE ONLY  the claim's smallest paired n < MIN_RUNS

Holm's first step needs a p ≤ 0.05 / m, so m comparisons need n ≥ N runs with 2 / 2^N ≤ 0.05 / m
(:func:`needed_runs`); a claim short of that says so.

**Budgets.** A row's budget is (K binary frames per view, S sensor pixels per image pixel per axis),
read from its records. Comparisons are between rows of equal budget only, except in claims marked
cross-budget, whose text says what each side consumed. Rows on estimated poses ("@") enter no claim.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.names import STAGE1_METHODS, as_read

METRIC = "psnr"
ALPHA = 0.05  # two-sided level of every test (and 1 - the intervals' level)
MIN_RUNS = 6  # the smallest n whose smallest sign-flip p (2 / 2^n) is ≤ ALPHA
EXACT_UP_TO = 16  # enumerate the 2^n sign patterns up to this n, else Monte-Carlo
N_RANDOM = 2**16  # random sign patterns above EXACT_UP_TO
RANDOM_SEED = 0
TIE_RTOL = 1e-9  # |pattern mean| within this fraction of mean |d| of the observed counts as a tie
BISECT_RTOL = 1e-7  # interval ends to this fraction of the differences' range
PRESET = "workflow/presets/findings.yaml"
TRANSLATORS = tuple(m for m in STAGE1_METHODS if m != "prior" and not m.endswith("-pub"))  # the default networks
PUBLISHED = tuple(f"{m}-pub" for m in TRANSLATORS)
BLOCKS = ((TRANSLATORS, "residual networks"), (PUBLISHED, "published networks"))
DESCRIPTIVE = "DESCRIPTIVE ONLY"
NOT_RUN = "NOT RUN"


# --- runs ------------------------------------------------------------------------------------------


@dataclass
class Row:
    """One table row: its budget (K, S) and its PSNR per run (scene, seed); NaN: not reconstructed."""

    budget: tuple[int | None, int]
    runs: dict[tuple, float] = field(default_factory=dict)

    @property
    def scored(self) -> bool:
        return any(math.isfinite(v) for v in self.runs.values())


def _add(rows: dict[str, Row], name: str, run: tuple, budget: tuple, value, where) -> None:
    """Record ``name``'s value on ``run``: one budget per row, one record per row and run."""
    row = rows.setdefault(name, Row(budget))
    if row.budget != budget:
        raise ValueError(
            f"{where}: row {name!r} has budget (K, S) = {budget} but its other runs {row.budget}: "
            "a row must consume one budget in every run"
        )
    if run in row.runs:
        raise ValueError(f"{where}: a second record of row {name!r} for scene {run[0]!r}, seed {run[1]!r}")
    row.runs[run] = math.nan if value is None else float(value)


def read_rows(metrics_files: list[str | os.PathLike]) -> dict[str, Row]:
    """The rows of the metrics records, one value per run (``mean``, the views already averaged).
    Captures without reference views and rows on estimated poses ("@") are left out."""
    rows: dict[str, Row] = {}
    for path in metrics_files:
        rec = io.read_json(path)
        if rec.get("reference") is False or "@" in rec["combination"]:
            continue
        budget = (rec.get("frames"), rec.get("capture_factor") or 1)
        value = (rec.get("mean") or {}).get(METRIC)
        _add(
            rows,
            as_read(rec["combination"], budget[0], rec.get("capture_factor")),
            (rec["scene"], rec.get("seed")),
            budget,
            value,
            path,
        )
    return rows


def read_stage1(stage1_files: list[str | os.PathLike]) -> dict[str, Row]:
    """Stage-1 rows by source, one value per run. The untrained ``prior`` comes from its own records
    or, when it has none for a run, from the ``prior`` scores a translator's record carries."""
    rows: dict[str, Row] = {}
    carried = {}
    for path in stage1_files:
        rec = io.read_json(path)
        run, budget = (rec["scene"], rec.get("seed")), (rec.get("frames"), 1)
        _add(rows, rec["source"], run, budget, (rec.get("mean") or {}).get(METRIC), path)
        if (rec.get("prior") or {}).get("mean"):  # the translators share one prior per run
            carried.setdefault(run, (budget, rec["prior"]["mean"].get(METRIC), path))
    for run, (budget, value, path) in carried.items():
        if run not in rows.get("prior", Row(budget)).runs:
            _add(rows, "prior", run, budget, value, path)
    return rows


def paired(a: Row, b: Row) -> np.ndarray:
    """Row ``a`` minus row ``b`` on the runs both scored, in run order."""
    both = sorted((r for r in a.runs.keys() & b.runs.keys()), key=str)
    d = np.array([a.runs[r] - b.runs[r] for r in both], dtype=np.float64)
    return d[np.isfinite(d)]


# --- the test ----------------------------------------------------------------------------------------


@functools.cache
def _patterns(n: int) -> np.ndarray:
    """Sign patterns (P, n): for n ≤ EXACT_UP_TO the 2^(n-1) with a first sign + (the other half
    mirrors them, same |mean|), else N_RANDOM random ones (fixed seed)."""
    if n <= EXACT_UP_TO:
        bits = (np.arange(2 ** (n - 1))[:, None] >> np.arange(n - 1)) & 1  # (P, n-1)
        signs = np.hstack([np.ones((len(bits), 1)), 1.0 - 2.0 * bits])
    else:
        signs = np.random.default_rng(RANDOM_SEED).choice([-1.0, 1.0], size=(N_RANDOM, n))
    signs.setflags(write=False)
    return signs


def sign_flip_p(d) -> np.ndarray | float:
    """Two-sided sign-flip p of the mean of ``d`` (..., n) against 0, over the last axis."""
    d = np.asarray(d, dtype=np.float64)
    if d.ndim == 0 or d.shape[-1] == 0 or not np.isfinite(d).all():
        raise ValueError(f"sign_flip_p: need ≥ 1 finite paired difference per test, got shape {d.shape}")
    n, flat = d.shape[-1], d.reshape(-1, d.shape[-1])
    signs = _patterns(n)
    tol = TIE_RTOL * np.abs(flat).mean(axis=1, keepdims=True)
    observed = np.abs(flat.mean(axis=1, keepdims=True)) - tol
    count = np.empty(len(flat))
    step = max(1, 2**22 // len(signs))  # (step, P) pattern means at a time
    for i in range(0, len(flat), step):
        means = np.abs(flat[i : i + step] @ signs.T) / n  # (step, P)
        count[i : i + step] = (means >= observed[i : i + step]).sum(axis=1)
    p = count / len(signs) if n <= EXACT_UP_TO else (1 + count) / (1 + len(signs))
    return float(p[0]) if d.ndim == 1 else p.reshape(d.shape[:-1])


def smallest_p(n: int) -> float:
    """The smallest two-sided p the test can give with n runs: 2 / 2^n (Monte-Carlo: 1 / (1 + B))."""
    return 2.0 / 2.0**n if n <= EXACT_UP_TO else 1.0 / (1 + N_RANDOM)


def needed_runs(m: int, alpha: float = ALPHA) -> int:
    """The fewest paired runs with which a claim of m comparisons can reach a verdict (Holm's
    first step needs p ≤ alpha / m): the smallest N with 2 / 2^N ≤ alpha / m."""
    n = 1
    while smallest_p(n) > alpha / m:
        n += 1
    return n


def interval(d, alpha: float = ALPHA) -> tuple[float, float]:
    """The 1 − alpha interval of the mean difference: the shifts δ whose test on d − δ is not
    rejected at alpha. Unbounded when no test can reject (n < MIN_RUNS at 5 %); else within [min, max]."""
    d = np.asarray(d, dtype=np.float64)
    if smallest_p(d.size) > alpha:
        return -math.inf, math.inf
    centre = float(d.mean())  # d − mean has mean 0: p = 1, accepted
    return _end(d, float(d.min()), centre, alpha), _end(d, float(d.max()), centre, alpha)


def _end(d: np.ndarray, outer: float, inner: float, alpha: float) -> float:
    """The accepted shift nearest ``outer`` (beyond it every difference has one sign: rejected),
    by bisection towards ``inner`` (accepted)."""
    if sign_flip_p(d - outer) > alpha:
        return outer
    resolution = BISECT_RTOL * (float(d.max() - d.min()) or 1.0)
    while abs(outer - inner) > resolution:
        mid = (outer + inner) / 2
        if sign_flip_p(d - mid) > alpha:
            inner = mid
        else:
            outer = mid
    return inner


def holm(p) -> np.ndarray:
    """Holm's step-down adjusted p-values over the last axis (monotone, at most 1)."""
    p = np.asarray(p, dtype=np.float64)
    m = p.shape[-1]
    order = np.argsort(p, axis=-1, kind="stable")
    steps = np.take_along_axis(p, order, axis=-1) * (m - np.arange(m))
    steps = np.minimum(np.maximum.accumulate(steps, axis=-1), 1.0)
    out = np.empty_like(p)
    np.put_along_axis(out, order, steps, axis=-1)
    return out


def verdict(means, adjusted, n: int, alpha: float = ALPHA) -> np.ndarray:
    """The verdict of claims (...) from their comparisons' means and Holm-adjusted p (..., m) and
    the claims' smallest paired n."""
    means, adjusted = np.asarray(means, dtype=np.float64), np.asarray(adjusted, dtype=np.float64)
    if n < MIN_RUNS:
        return np.full(means.shape[:-1], DESCRIPTIVE)
    rejected = adjusted <= alpha
    fails = ((means < 0) & rejected).any(axis=-1)
    holds = ((means > 0) & rejected).all(axis=-1)
    return np.select([fails, holds], ["DOES NOT HOLD", "HOLDS"], "INCONCLUSIVE")


# --- claims ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Claim:
    id: str
    by: str  # "paper" or "ours"
    text: str
    pairs: tuple[tuple[str, str], ...]  # (better row, worse row)
    cross_budget: bool = False  # compare rows of unequal budget (the text says what each consumed)


def spend(budget: tuple) -> str:
    """What a budget (K, S) consumed, in words."""
    k, s = budget
    frames = f"{k} frame{'' if k == 1 else 's'}"
    return f"{frames} at {s}×{s} sensor pixels per image pixel" if s > 1 else f"{frames} at 1×"


def consumed(rows: dict[str, Row], better: str, worse: str) -> str:
    """What each side of a cross-budget claim consumed, e.g. "cross-budget: none: 1 frame at 4×4 sensor
    pixels per image pixel vs 1 frame at 1×"."""
    if better not in rows or worse not in rows:
        return "cross-budget"
    source = worse.partition("+")[0]
    return f"cross-budget: {source}: {spend(rows[worse].budget)} vs {spend(rows[better].budget)}"


def translator_block(rows) -> tuple[tuple[str, ...], str]:
    """Block T: the published networks when any ran, else the residual (default) networks."""
    for block, label in reversed(BLOCKS):
        if any(r.partition("+")[0] in block for r in rows):
            return block, label
    return BLOCKS[0]


def mle_rows(rows: dict[str, Row], like: str) -> list[str]:
    """The MLE-image 3DGS rows (``mle``, ``mle-x1``, ``mle-x1-mse``, ``mle-k16``...) of ``like``'s budget."""
    budget = rows[like].budget if like in rows else None
    names = (r for r in rows if r.endswith("+3dgs") and r.partition("+")[0].partition("-")[0] == "mle")
    return sorted(r for r in names if rows[r].budget == budget)


def claims(rows: dict[str, Row], nerf: str) -> list[Claim]:
    """The claims, for the rows of this run (a row that did not run is skipped by the comparisons)."""
    block, label = translator_block(rows)
    p = block[TRANSLATORS.index("pix2pixhd")]
    p_nerf, p_3dgs, models = f"{p}+{nerf}", f"{p}+3dgs", (nerf, "3dgs")
    two_stage = [f"{t}+{m}" for t in block for m in models]
    # The strongest two-stage rows: the residual networks (the project's default) and their untrained
    # start; the published ones are compared in Δ over the prior. Fewer comparisons also keep the claim
    # decidable at the findings preset's 9 runs (Holm over 10: 2/2^9 <= 0.05/10).
    strongest = [f"{t}+{m}" for t in (*TRANSLATORS, "prior") for m in models]
    denoisers = [block[TRANSLATORS.index(d)] for d in ("restormer", "diffusion")]
    mle = mle_rows(rows, "bernoulli+3dgs")
    vs_mle = ", ".join(mle) or "no MLE row of its budget"
    two_vs_one = f"Two-stage beats single-stage with {{}}: Pix2PixHD ({label}) vs"
    x1 = "one binary frame at the working resolution (equal budget)"
    return [
        Claim("best-nerf", "paper", f"Pix2PixHD + NeRF [{nerf}] is the best two-stage combination ({label})",
              tuple((p_nerf, r) for r in two_stage if r != p_nerf)),
        Claim("best-3dgs", "paper",
              f"Pix2PixHD + 3DGS beats every two-stage combination with another translator ({label})",
              tuple((p_3dgs, r) for r in two_stage if not r.startswith(f"{p}+"))),
        Claim("two-stage-nerf-faithful", "paper",
              f"{two_vs_one.format(f'NeRF [{nerf}]')} the paper-faithful single stage "
              f"({consumed(rows, p_nerf, f'none+{nerf}')})", ((p_nerf, f"none+{nerf}"),), cross_budget=True),
        Claim("two-stage-nerf", "paper", f"{two_vs_one.format(f'NeRF [{nerf}]')} {x1}", ((p_nerf, f"none-x1+{nerf}"),)),
        Claim("two-stage-3dgs-faithful", "paper",
              f"{two_vs_one.format('3DGS')} the paper-faithful single stage ({consumed(rows, p_3dgs, 'none+3dgs')})",
              ((p_3dgs, "none+3dgs"),), cross_budget=True),
        Claim("two-stage-3dgs", "paper",
              f"{two_vs_one.format('3DGS')} 3DGS fitted with MSE (the mean-fitting loss) to {x1}",
              ((p_3dgs, "none-x1-mse+3dgs"),)),
        Claim("denoisers", "paper",
              f"Denoise-then-reconstruct (Restormer, diffusion as DiffBIR stand-in) is worse than Pix2PixHD ({label})",
              tuple((f"{p}+{m}", f"{d}+{m}") for d in denoisers for m in models)),
        Claim("spad-two-stage", "ours",
              "The SPAD likelihood (bernoulli + 3DGS) beats every two-stage row at equal budget "
              "(the residual networks and their untrained prior)",
              tuple(("bernoulli+3dgs", r) for r in strongest)),
        Claim("spad-mle", "ours",
              f"The SPAD likelihood beats the MLE image at equal budget (vs {vs_mle})",
              tuple(("bernoulli+3dgs", r) for r in mle)),
    ]  # fmt: skip


# --- deciding ----------------------------------------------------------------------------------------


@dataclass
class Comparison:
    better: str
    worse: str
    n: int  # paired runs
    mean: float | None = None  # mean paired difference (dB)
    low: float | None = None  # interval (n ≥ MIN_RUNS) or range [min, max] of the run differences
    high: float | None = None
    bounds: str = "range"  # "interval" or "range"
    p: float = 1.0  # sign-flip p; 1 without paired runs
    adjusted: float = 1.0  # Holm-adjusted over the claim's comparisons


def compare(rows: dict[str, Row], better: str, worse: str) -> Comparison:
    """The paired runs of two rows: mean difference, its interval (or range below MIN_RUNS), p."""
    d = paired(rows[better], rows[worse])
    if d.size == 0:
        return Comparison(better, worse, 0)
    if d.size < MIN_RUNS:
        low, high, bounds = float(d.min()), float(d.max()), "range"
    else:
        (low, high), bounds = interval(d), "interval"
    return Comparison(better, worse, int(d.size), float(d.mean()), low, high, bounds, sign_flip_p(d))


def decisive(comps: list[Comparison], outcome: str) -> Comparison:
    """The comparison that decides: the failing one for DOES NOT HOLD, the closest one (smallest
    mean) when descriptive, else the one with the largest adjusted p."""
    scored = [c for c in comps if c.mean is not None] or comps
    if outcome == "DOES NOT HOLD":
        return min((c for c in scored if c.mean < 0 and c.adjusted <= ALPHA), key=lambda c: (c.adjusted, c.mean))
    if outcome == DESCRIPTIVE:
        return min(scored, key=lambda c: (c.mean is not None, c.mean or 0.0))
    return max(scored, key=lambda c: (c.adjusted, -c.mean))


def evaluate(claim: Claim, rows: dict[str, Row]) -> dict:
    """A claim decided: its comparisons (rows of equal budget unless cross-budget), Holm, verdict."""
    present = [(a, b) for a, b in claim.pairs if a in rows and b in rows and rows[a].scored and rows[b].scored]
    equal = [(a, b) for a, b in present if claim.cross_budget or rows[a].budget == rows[b].budget]
    out = {"id": claim.id, "claim": claim.text, "by": claim.by, "cross_budget": claim.cross_budget, "m": len(equal)}
    out["unequal_budget"] = [[a, b] for a, b in present if (a, b) not in equal]
    if not equal:
        why = "no row of equal budget in this run" if present else "rows not in this run"
        return out | {"verdict": NOT_RUN, "note": why, "n": 0, "decisive": None, "comparisons": []}
    comps = [compare(rows, a, b) for a, b in equal]
    for c, adj in zip(comps, holm([c.p for c in comps])):
        c.adjusted = float(adj)
    n = min(c.n for c in comps)
    outcome = str(verdict([c.mean or 0.0 for c in comps], [c.adjusted for c in comps], n))
    need = needed_runs(len(comps))
    note = f"needs n ≥ {need} for {len(comps)} comparisons" if n < need and need > MIN_RUNS else ""
    return out | {
        "verdict": outcome,
        "note": note,
        "n": n,
        "decisive": decisive(comps, outcome).__dict__,
        "comparisons": [c.__dict__ for c in comps],
    }


def over_prior(rows: dict[str, Row], stage1: dict[str, Row], nerf: str) -> list[dict]:
    """Δ PSNR of every translator that ran over the untrained prior, at stage 1 and in each model;
    each is its own one-comparison claim."""
    out = []
    for t, label in ((t, label) for block, label in BLOCKS for t in block):
        for stage, table, better, worse in (
            ("stage 1", stage1, t, "prior"),
            ("3dgs", rows, f"{t}+3dgs", "prior+3dgs"),
            (nerf, rows, f"{t}+{nerf}", f"prior+{nerf}"),
        ):
            if better in table and worse in table:
                claim = Claim(f"over-prior:{t}:{stage}", "ours", f"{t} over the prior ({stage})", ((better, worse),))
                out.append(evaluate(claim, table) | {"translator": t, "block": label, "stage": stage})
    return out


# --- the base of the findings ------------------------------------------------------------------------


def base(rows: dict[str, Row]) -> str:
    """The scored runs of every row, e.g. "6 runs (courtyard, tabletop × seeds 0, 1, 2)"."""
    runs = {r for row in rows.values() for r, v in row.runs.items() if math.isfinite(v)}
    seeds: dict[str, set] = {}
    for scene, seed in runs:
        seeds.setdefault(scene, set()).add(seed)

    def listed(s: set) -> str:
        return f"seed{'s' if len(s) > 1 else ''} {', '.join(map(str, sorted(s, key=str)))}"

    if len({frozenset(s) for s in seeds.values()}) <= 1:
        where = f"{', '.join(sorted(seeds))} × {listed(next(iter(seeds.values())))}" if seeds else "none"
    else:
        where = "; ".join(f"{scene} × {listed(s)}" for scene, s in sorted(seeds.items()))
    return f"{len(runs)} run{'' if len(runs) == 1 else 's'} ({where})"


def header(rows: dict[str, Row], results: list[dict]) -> str:
    """The opening line: the base (runs, scenes × seeds), the test, MIN_RUNS; and whether only descriptive."""
    line = (
        f"Base: {base(rows)}; one PSNR per row and run (its held-out views averaged), claims pair the runs "
        f"two rows share. Test: exact sign-flip permutation test of the mean paired difference, Holm over a "
        f"claim's comparisons at 5 %, interval = the test inverted; a verdict needs ≥ MIN_RUNS = {MIN_RUNS} "
        "paired runs."
    )
    if not any(r["verdict"] in ("HOLDS", "DOES NOT HOLD", "INCONCLUSIVE") for r in results):
        line += f" This run is descriptive only: n = {base(rows)}; a verdict needs ≥ {MIN_RUNS} paired runs ({PRESET})."
    return line


# --- writing -----------------------------------------------------------------------------------------

LEGEND = (
    "HOLDS: every comparison favours the claim with Holm p ≤ 0.05; DOES NOT HOLD: one goes against it "
    "with Holm p ≤ 0.05; INCONCLUSIVE: otherwise; DESCRIPTIVE ONLY: fewer than "
    f"{MIN_RUNS} paired runs (the smallest exact p, 2/2^n, cannot reach 0.05), shown with the range of the run "
    "differences instead of an interval. The decisive comparison is the one with the largest Holm p (for DOES "
    "NOT HOLD the failing one; when descriptive the closest). Rows of equal budget (K frames, S× capture) only, "
    "except cross-budget claims; rows on estimated poses enter no claim."
)
CLAIM_COLUMNS = ["claim", "by", "verdict", "decisive comparison", "Δ PSNR (dB)", "95 % interval (or range)",
                 "Holm p", "n (runs)", "m"]  # fmt: skip
PRIOR_COLUMNS = ["translator", "block", "stage", "verdict", "Δ PSNR (dB)", "95 % interval (or range)", "p", "n (runs)"]


def p_text(p: float) -> str:
    return f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def _cells(r: dict) -> list[str]:
    """(verdict, decisive comparison, Δ, interval or range, Holm p, n) of a decided claim."""
    c, note = r["decisive"], f" ({r['note']})" if r["note"] else ""
    if c is None:
        return [f"**{r['verdict']}**", r["note"], "–", "–", "–", "0"]
    if c["mean"] is None:
        return [f"**{r['verdict']}**{note}", f"{c['better']} vs {c['worse']}: no paired runs", "–", "–", "–", "0"]
    bounds = f"[{c['low']:+.2f}, {c['high']:+.2f}]"
    p = "–" if r["verdict"] == DESCRIPTIVE else p_text(c["adjusted"])
    return [
        f"**{r['verdict']}**{note}",
        f"{c['better']} vs {c['worse']}",
        f"{c['mean']:+.2f}",
        bounds if c["bounds"] == "interval" else f"range {bounds}",
        p,
        str(r["n"]),
    ]


def claim_cells(r: dict) -> list[str]:
    verdict_, comp, *rest = _cells(r)
    return [r["claim"], r["by"], verdict_, comp, *rest, str(r["m"])]


def prior_cells(r: dict) -> list[str]:
    verdict_, _, *rest = _cells(r)
    return [r["translator"], r["block"], r["stage"], verdict_, *rest]


def md_table(columns: list[str], cells: list[list[str]]) -> list[str]:
    return [f"| {' | '.join(columns)} |", "|" + "---|" * len(columns), *(f"| {' | '.join(c)} |" for c in cells)]


def markdown(first_line: str, results: list[dict], prior: list[dict]) -> str:
    lines = ["# Findings", "", first_line, "", *md_table(CLAIM_COLUMNS, [claim_cells(r) for r in results])]
    lines += ["", LEGEND, "", "## Δ over the untrained prior", ""]
    if prior:
        lines += md_table(PRIOR_COLUMNS, [prior_cells(r) for r in prior])
    else:
        lines.append("No translator ran beside the untrained prior (`prior` rows) in this run.")
    return "\n".join(lines) + "\n"


def _html_table(columns: list[str], cells: list[list[str]]) -> str:
    head = "".join(f"<th>{c}</th>" for c in columns)
    body = "".join("<tr>" + "".join(f"<td>{_bold(c)}</td>" for c in row) + "</tr>" for row in cells)
    return f"<table><tr>{head}</tr>{body}</table>"


def _bold(cell: str) -> str:
    return f"<b>{cell[2:].replace('**', '</b>', 1)}" if cell.startswith("**") else cell


def html(first_line: str, results: list[dict], prior: list[dict]) -> str:
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Findings</title><style>body{font-family:"
        "sans-serif;font-size:13px;margin:12px}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
        "padding:3px 6px}</style></head><body><h3>Findings: the claims, decided from the numbers</h3>"
        f"<p>{first_line}</p>{_html_table(CLAIM_COLUMNS, [claim_cells(r) for r in results])}<p>{LEGEND}</p>"
        f"<h3>Δ over the untrained prior</h3>{_html_table(PRIOR_COLUMNS, [prior_cells(r) for r in prior])}"
        "</body></html>\n"
    )


def write_findings(
    metrics_files: list[str | os.PathLike],
    stem: str | os.PathLike,
    nerf_variant: str,
    stage1_files: list[str | os.PathLike] | tuple = (),
) -> dict:
    """``stem``.md, .json and .html: every claim decided on paired runs, and the Δ-over-prior table.
    Returns what the JSON holds."""
    stem = Path(stem)
    rows = read_rows(metrics_files)
    results = [evaluate(c, rows) for c in claims(rows, nerf_variant)]
    prior = over_prior(rows, read_stage1(stage1_files), nerf_variant)
    first_line = header(rows, results + prior)
    out = {
        "metric": METRIC,
        "alpha": ALPHA,
        "min_runs": MIN_RUNS,
        "test": "exact sign-flip permutation test of the mean paired run difference (Monte-Carlo above "
        f"{EXACT_UP_TO} runs); Holm over a claim's comparisons; interval = the test inverted",
        "base": first_line,
        "claims": results,
        "over_prior": prior,
    }
    io.write_json(stem.with_suffix(".json"), out)
    io.write_text(stem.with_suffix(".md"), markdown(first_line, results, prior))
    io.write_text(stem.with_suffix(".html"), html(first_line, results, prior))
    return out

"""The paper's claims and this project's, decided from the numbers: ``results/tables/findings.{md,json,html}``.

**The unit is the scene.** A run is one (scene, seed). Each row of the tables is fitted once per run
and its held-out views are averaged inside the run (``metrics.json``'s ``mean``): the views of one
fit share its noise (the SPC draw, the translator, the fit's initialisation), so they are one piece
of evidence, not many. Nor are the seeds of one scene independent evidence about imaging: they
share the scene's content, and paired differences cluster by scene (on the real scenes, seeds of
one scene differed by a median 0.17 dB where scenes differed by up to 2.8 dB), so a test that flips
each (scene, seed) on its own treats clustered runs as independent and holds too often. A claim
compares two rows on the scenes both have: one paired PSNR difference (dB) per scene, the mean over
the seeds both rows scored on it (:func:`paired`); n counts scenes.

**The test** is the exact sign-flip permutation test (Fisher 1935, Pitman 1937); its statistic is
the mean paired difference. If the scenes' paired differences are independent and symmetric about a
shift s (for s = 0: the two rows are exchangeable within a scene), the differences minus s have 2^n
equally likely sign patterns whatever their distribution, so the p-values below are exact: no
normality, no large n.
A t-interval is not used: at small n it is liberal for light-tailed or lumpy differences (with ±1
differences at n = 3, t rejects 25 % of the time, the same flaw as a percentile bootstrap over
views). Up to 16 scenes every pattern is enumerated; above, B = 2^16 random patterns (fixed seed)
give p = (1 + count) / (1 + B) two-sided and (1 + count) / (2 + 2B) one-sided, counting each
pattern and its mirror. The 95 % interval is the two-sided test inverted: the shifts whose test on
d − shift is not rejected at 5 % (ends found by bisection).

**Effects that matter.** A claim "A beats B" means "A beats B by at least δ", the smallest effect
of interest (``SMALLEST_EFFECT`` = 0.25 dB PSNR by default; config ``findings.smallest_effect_db``):
a gain below δ is not one a reader would act on, and with enough runs any nonzero gain becomes
"significant". Each comparison gets three one-sided p-values (:func:`effect_p`), each tested at
α / 2 = 0.025, so that a rejection is exactly the 95 % interval clearing the bound:

    p_holds   H0 Δ ≤ δ    rejected: Δ > δ   (the interval's lower end is above +δ)
    p_short   H0 Δ ≥ δ    rejected: Δ < δ   (the claimed effect is excluded)
    p_low     H0 Δ ≤ −δ   rejected: Δ > −δ

A comparison is equivalent when p_short and p_low both reject (two one-sided tests, TOST): the
rows differ by less than δ either way. With δ = 0 a one-comparison claim gets the two-sided 5 %
test's verdict (HOLDS or DOES NOT HOLD by the sign of the difference) and equivalence is impossible.

**The price is discreteness.** The smallest one-sided p is 1 / 2^n: n = 5 gives 0.031 (it can
never reject at 0.025), n = 6 gives 0.016, n = 9 gives 0.002. Hence ``MIN_SCENES`` = 6, the smallest
n at which a test can reject at all; at n = 6 with every scene agreeing in sign the interval is
exactly [min, max] of the scene differences. With fewer paired scenes a claim is DESCRIPTIVE ONLY:
its mean difference, the range [min, max] of its scene differences (a range, not an interval) and n.
More seeds of the same scenes never make a claim decidable.

**A claim** has m comparisons (better row, worse row), and claims that *every* one of them
clears δ ("A beats every other two-stage row"). Its rivals are listed, not inferred from what ran
(``findings.rivals`` in the configuration: the two-stage rows and the MLE rows a claim over "every"
such row compares with): a listed rival that did not run makes the claim NOT RUN, naming it, so a
claim never silently shrinks to the rivals that happened to run. Its p-values are adjusted for the claim's
comparisons (:func:`claim_families`) according to what each verdict asserts:

    HOLDS             every comparison's p_holds ≤ 0.025, unadjusted: the claim is the intersection
                      of its comparisons, so it is wrongly held only if every one of them is, and
                      testing each at 0.025 keeps that ≤ 0.025 (the intersection-union test,
                      Berger 1982); Holm here would only cost power
    EQUIVALENT        else some comparison's Holm-adjusted p_short ≤ 0.025 (asserting that *some*
                      comparison fails is a union over them: Holm keeps it ≤ 0.025), and every such
                      comparison is equivalent (Holm-adjusted max(p_short, p_low) ≤ 0.025): the
                      claimed advantage over that row is smaller than δ either way
    DOES NOT HOLD     else some comparison's Holm-adjusted p_short ≤ 0.025 (one not equivalent)
    INCONCLUSIVE      otherwise
    DESCRIPTIVE ONLY  the claim's smallest paired n < MIN_SCENES

A claim wrongly held or wrongly failed is then at most 5 % together. Holm's first step needs a
p ≤ 0.025 / m, so showing a failure among m comparisons needs n ≥ N scenes with 1 / 2^N ≤ 0.025 / m
(:func:`needed_scenes`); a claim short of that says so. HOLDS needs only MIN_SCENES whatever m.

**Baselines.** Every translator's Δ over the two non-learned stage-1 methods, the untrained
``prior`` and ``classical`` (and ``classical`` over ``prior``), at stage 1 and through each 3D
model, is a one-comparison claim of its own (:func:`over_baseline`): a method that does not beat
them learnt nothing the physics did not give.

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
from spc3d.evaluation.record import RunRecord
from spc3d.names import STAGE1_METHODS, parse_combination, parse_source, reads_capture_frame, source_frames

METRIC = "psnr"
ALPHA = 0.05  # 1 - the intervals' level; the two-sided level of sign_flip_p
LEVEL = ALPHA / 2  # the level of every one-sided test: a rejection is the 95 % interval clearing its bound
SMALLEST_EFFECT = 0.25  # δ (dB PSNR): a claim "A beats B" means by at least δ (config findings.smallest_effect_db)
MIN_SCENES = 6  # the smallest n (scenes) whose smallest one-sided sign-flip p (1 / 2^n) is ≤ LEVEL
EXACT_UP_TO = 16  # enumerate the 2^n sign patterns up to this n, else Monte-Carlo
N_RANDOM = 2**16  # random sign patterns above EXACT_UP_TO
RANDOM_SEED = 0
TIE_RTOL = 1e-9  # |pattern mean| within this fraction of mean |d| of the observed counts as a tie
BISECT_RTOL = 1e-7  # interval ends to this fraction of the differences' range
PRESET = "workflow/presets/findings.yaml"
BASELINES = {"prior": "the prior", "classical": "the classical method"}  # the non-learned stage-1 methods
NETWORKS = tuple(m for m in STAGE1_METHODS if m not in BASELINES and not m.endswith("-pub"))  # default translators
PUBLISHED = tuple(f"{m}-pub" for m in NETWORKS)
BLOCKS = ((NETWORKS, "residual networks"), (PUBLISHED, "published networks"))
DESCRIPTIVE = "DESCRIPTIVE ONLY"
NOT_RUN = "NOT RUN"
DECIDED = ("HOLDS", "EQUIVALENT", "DOES NOT HOLD", "INCONCLUSIVE")  # the verdicts of n ≥ MIN_SCENES
# The Holm family whose p a verdict shows, and its null hypothesis in the tables.
FAMILY = {"HOLDS": "holds", "INCONCLUSIVE": "holds", "DOES NOT HOLD": "short", "EQUIVALENT": "equivalent"}
NULLS = {"holds": "Δ ≤ δ", "short": "Δ ≥ δ", "equivalent": "Δ ∉ (−δ, δ)"}  # no "|": cells of Markdown tables


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
        rec = RunRecord.read(path)
        if not rec.reference or "@" in rec.combination:
            continue
        _add(rows, rec.row, (rec.scene, rec.seed), rec.budget, rec.score(METRIC), path)
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
    """Row ``a`` minus row ``b``, one difference per scene both scored (in scene order): the mean over
    the seeds of that scene both rows scored. The scene is the unit: its seeds share its content, so
    they average into one value instead of counting as independent runs."""
    per_scene: dict = {}
    for run in a.runs.keys() & b.runs.keys():
        d = a.runs[run] - b.runs[run]
        if math.isfinite(d):
            per_scene.setdefault(run[0], []).append(d)
    return np.array([np.mean(per_scene[s]) for s in sorted(per_scene, key=str)], dtype=np.float64)


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


def _flat(d, who: str) -> np.ndarray:
    """``d`` (..., n) as rows (R, n) of finite paired differences."""
    d = np.asarray(d, dtype=np.float64)
    if d.ndim == 0 or d.shape[-1] == 0 or not np.isfinite(d).all():
        raise ValueError(f"{who}: need ≥ 1 finite paired difference per test, got shape {d.shape}")
    return d.reshape(-1, d.shape[-1])


def sign_flip_p(d) -> np.ndarray | float:
    """Two-sided sign-flip p of the mean of ``d`` (..., n) against 0, over the last axis."""
    d = np.asarray(d, dtype=np.float64)
    flat = _flat(d, "sign_flip_p")
    n = flat.shape[1]
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


def _tails(x) -> tuple[np.ndarray, np.ndarray]:
    """One-sided sign-flip p of the mean of ``x`` (..., n) over the last axis, both ways: (p of
    H0 mean ≤ 0, p of H0 mean ≥ 0), over every sign pattern and its mirror. Where the observed mean
    is beyond the tie tolerance, the p in its direction is exactly half :func:`sign_flip_p`'s."""
    x = np.asarray(x, dtype=np.float64)
    flat = _flat(x, "one-sided sign-flip p")
    n = flat.shape[1]
    signs = _patterns(n)
    tol = TIE_RTOL * np.abs(flat).mean(axis=1, keepdims=True)
    observed = flat.mean(axis=1, keepdims=True)
    above, below = np.empty(len(flat)), np.empty(len(flat))
    step = max(1, 2**22 // len(signs))  # (step, P) pattern means at a time
    for i in range(0, len(flat), step):
        means = flat[i : i + step] @ signs.T / n  # (step, P); the mirrors' are -means
        high, low = observed[i : i + step] - tol[i : i + step], observed[i : i + step] + tol[i : i + step]
        above[i : i + step] = (means >= high).sum(axis=1) + (means <= -high).sum(axis=1)
        below[i : i + step] = (means <= low).sum(axis=1) + (means >= -low).sum(axis=1)
    patterns = 2 * len(signs)
    if n <= EXACT_UP_TO:
        above, below = above / patterns, below / patterns
    else:
        above, below = (1 + above) / (2 + patterns), (1 + below) / (2 + patterns)
    if x.ndim == 1:
        return float(above[0]), float(below[0])
    return above.reshape(x.shape[:-1]), below.reshape(x.shape[:-1])


def one_sided_p(d, shift: float = 0.0, greater: bool = True) -> np.ndarray | float:
    """One-sided sign-flip p of the mean Δ of ``d`` (..., n) over the last axis: of H0 Δ ≤ ``shift``
    (``greater``: rejecting shows Δ > shift) or of H0 Δ ≥ ``shift``. Rejecting at ALPHA / 2 is the
    same as ``shift`` lying outside :func:`interval` on that side."""
    above, below = _tails(np.asarray(d, dtype=np.float64) - shift)
    return above if greater else below


def effect_p(d, smallest_effect: float = SMALLEST_EFFECT) -> tuple:
    """(p_holds, p_short, p_low) of the mean Δ of ``d`` (..., n) against δ = ``smallest_effect``:
    the one-sided sign-flip p of H0 Δ ≤ δ, of H0 Δ ≥ δ and of H0 Δ ≤ −δ."""
    if not (math.isfinite(smallest_effect) and smallest_effect >= 0):
        raise ValueError(f"effect_p: the smallest effect of interest must be finite and ≥ 0, got {smallest_effect}")
    d = np.asarray(d, dtype=np.float64)
    p_holds, p_short = _tails(d - smallest_effect)
    p_low = _tails(d + smallest_effect)[0] if smallest_effect else p_holds
    return p_holds, p_short, p_low


def smallest_p(n: int, one_sided: bool = False) -> float:
    """The smallest p the test can give with n scenes: 2 / 2^n two-sided, 1 / 2^n one-sided
    (Monte-Carlo: 1 / (1 + B), 1 / (2 + 2B))."""
    if n <= EXACT_UP_TO:
        return (1.0 if one_sided else 2.0) / 2.0**n
    return 1.0 / (2 + 2 * N_RANDOM) if one_sided else 1.0 / (1 + N_RANDOM)


def needed_scenes(m: int, alpha: float = ALPHA) -> int:
    """The fewest paired scenes with which a failure among m comparisons can be shown (DOES NOT HOLD,
    EQUIVALENT): Holm's first step needs a one-sided p ≤ (alpha / 2) / m, so the smallest N with
    1 / 2^N ≤ (alpha / 2) / m. HOLDS, an intersection-union test, needs MIN_SCENES whatever m."""
    n = 1
    while smallest_p(n, one_sided=True) > alpha / 2 / m:
        n += 1
    return n


def interval(d, alpha: float = ALPHA) -> tuple[float, float]:
    """The 1 − alpha interval of the mean difference: the shifts δ whose test on d − δ is not
    rejected at alpha. Unbounded when no test can reject (n < MIN_SCENES at 5 %); else within [min, max]."""
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


def claim_families(p_holds, p_short, p_low) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The comparisons' (..., m) p-values adjusted for the claim over the last axis, family by
    family: p_holds as it is (the claim holds only if every comparison does: an intersection-union
    test needs no adjustment), p_short and the equivalence p max(p_short, p_low) (two one-sided
    tests) Holm-adjusted (a failure is asserted of some comparison: a union over them)."""
    p_holds, p_short = (np.asarray(p, dtype=np.float64) for p in (p_holds, p_short))
    return p_holds.copy(), holm(p_short), holm(np.maximum(p_short, p_low))


def verdict(holds, short, equivalent, n: int, alpha: float = ALPHA) -> np.ndarray:
    """The verdict of claims (...) from their comparisons' adjusted p (..., m) of each family
    (:func:`claim_families`), each tested at alpha / 2, and the claims' smallest paired n (scenes): HOLDS when
    every comparison clears δ; else, where some comparison falls short of δ, EQUIVALENT when each
    that does is within ±δ, else DOES NOT HOLD; else INCONCLUSIVE."""
    holds, short, equivalent = (np.asarray(p, dtype=np.float64) for p in (holds, short, equivalent))
    if n < MIN_SCENES:
        return np.full(holds.shape[:-1], DESCRIPTIVE)
    level = alpha / 2
    failing = short <= level
    fails = failing.any(axis=-1)
    equal = fails & (~failing | (equivalent <= level)).all(axis=-1)
    held = (holds <= level).all(axis=-1)
    return np.select([held, equal, fails], ["HOLDS", "EQUIVALENT", "DOES NOT HOLD"], "INCONCLUSIVE")


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


def default_rivals(nerf: str) -> dict[str, list[str]]:
    """The rivals of the claims over "every" row when the configuration lists none
    (``findings.rivals``): every residual translator and the untrained prior under both models, and
    the two MLE-image rows at K = 1 and 1× (one per loss)."""
    two_stage = [f"{t}+{m}" for t in (*NETWORKS, "prior") for m in (nerf, "3dgs")]
    return {"two_stage": two_stage, "mle": ["mle-x1+3dgs", "mle-x1-mse+3dgs"]}


def claims(rows: dict[str, Row], nerf: str, rivals: dict[str, list[str]] | None = None) -> list[Claim]:
    """The claims. Their rivals are listed (``rivals``: ``two_stage``, the two-stage rows a claim over
    "every two-stage row" compares with, and ``mle``, the MLE-image rows of the likelihood's claim;
    :func:`default_rivals` when None), not inferred from the rows that ran: :func:`decide` makes a
    claim with a rival that did not run NOT RUN, naming it. The paper's claims over translators take
    the listed two-stage rows of the translator block that ran (:func:`translator_block`)."""
    rivals = default_rivals(nerf) | (rivals or {})
    block, label = translator_block(rows)
    p = block[NETWORKS.index("pix2pixhd")]
    p_nerf, p_3dgs, models = f"{p}+{nerf}", f"{p}+3dgs", (nerf, "3dgs")
    every = list(rivals["two_stage"])
    two_stage = [r for r in every if r.partition("+")[0] in block]
    denoisers = [block[NETWORKS.index(d)] for d in ("restormer", "diffusion")]
    mle = list(rivals["mle"])
    vs_mle = ", ".join(mle) or "no MLE row listed"
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
              f"The SPAD likelihood (bernoulli + 3DGS) beats every two-stage row at equal budget ({len(every)} listed)",
              tuple(("bernoulli+3dgs", r) for r in every)),
        Claim("spad-mle", "ours",
              f"The SPAD likelihood beats the MLE image at equal budget (vs {vs_mle})",
              tuple(("bernoulli+3dgs", r) for r in mle)),
        *(claim for row in joint_rows(rows) for claim in joint_claims(rows, row, every)),
    ]  # fmt: skip


def joint_rows(rows) -> list[str]:
    """The joint rows that ran on the scene's cameras (``joint-<method>+model``), in name order."""

    def on_scene_poses_joint(row: str) -> bool:
        source, _, poses = parse_combination(row)
        return parse_source(source).joint and poses is None

    return sorted(filter(on_scene_poses_joint, rows))


def joint_claims(rows, joint: str, two_stage: list[str]) -> list[Claim]:
    """A joint row beats its model's likelihood row and every two-stage row at equal budget; and,
    across budgets, the 16-frame MLE row of its model."""
    model = joint.partition("+")[2]
    reference = f"mle-k16+{model}"
    return [
        Claim(f"joint-likelihood:{joint}", "ours",
              f"The joint fit {joint} beats the SPAD likelihood alone (bernoulli+{model}) at equal budget",
              ((joint, f"bernoulli+{model}"),)),
        Claim(f"joint-two-stage:{joint}", "ours",
              f"The joint fit {joint} beats every two-stage row at equal budget ({len(two_stage)} listed)",
              tuple((joint, r) for r in two_stage)),
        Claim(f"joint-mle16:{joint}", "ours",
              f"The joint fit {joint} beats the 16-frame MLE image + {model} ({consumed(rows, joint, reference)})",
              ((joint, reference),), cross_budget=True),
    ]  # fmt: skip


# --- deciding ----------------------------------------------------------------------------------------


@dataclass
class Comparison:
    better: str
    worse: str
    n: int  # paired scenes
    mean: float | None = None  # mean paired difference (dB)
    low: float | None = None  # interval (n ≥ MIN_SCENES) or range [min, max] of the scene differences
    high: float | None = None
    bounds: str = "range"  # "interval" or "range"
    p: float = 1.0  # two-sided sign-flip p against no difference; 1 without paired scenes
    p_holds: float = 1.0  # one-sided p of H0 Δ ≤ δ (rejected: the claim's margin is shown)
    p_short: float = 1.0  # of H0 Δ ≥ δ (rejected: the claimed effect is excluded)
    p_low: float = 1.0  # of H0 Δ ≤ −δ (rejected with p_short: equivalent, |Δ| < δ)
    adj_holds: float = 1.0  # adjusted for the claim (claim_families): p_holds as it is (intersection-union)
    adj_short: float = 1.0  # Holm over the claim's comparisons
    adj_equivalent: float = 1.0  # Holm, of max(p_short, p_low)


def compare(rows: dict[str, Row], better: str, worse: str, smallest_effect: float = SMALLEST_EFFECT) -> Comparison:
    """The paired scenes of two rows: mean difference, its interval (or range below MIN_SCENES), the
    two-sided p against 0 and the one-sided p against δ = ``smallest_effect`` (:func:`effect_p`)."""
    d = paired(rows[better], rows[worse])
    if d.size == 0:
        return Comparison(better, worse, 0)
    if d.size < MIN_SCENES:
        low, high, bounds = float(d.min()), float(d.max()), "range"
    else:
        (low, high), bounds = interval(d), "interval"
    p_holds, p_short, p_low = effect_p(d, smallest_effect)
    return Comparison(
        better, worse, int(d.size), float(d.mean()), low, high, bounds, sign_flip_p(d), p_holds, p_short, p_low
    )


def decisive(comps: list[Comparison], outcome: str, alpha: float = ALPHA) -> Comparison:
    """The comparison that decides: for DOES NOT HOLD and EQUIVALENT the failing one with the
    strongest evidence (smallest adjusted p_short; for DOES NOT HOLD among those not equivalent), the
    closest one (smallest mean) when descriptive, else the one with the largest p_holds."""
    scored = [c for c in comps if c.mean is not None] or comps
    if outcome in ("DOES NOT HOLD", "EQUIVALENT"):
        failing = [c for c in scored if c.adj_short <= alpha / 2]
        if outcome == "DOES NOT HOLD":
            failing = [c for c in failing if c.adj_equivalent > alpha / 2]
        return min(failing, key=lambda c: (c.adj_short, c.mean))
    if outcome == DESCRIPTIVE:
        return min(scored, key=lambda c: (c.mean is not None, c.mean or 0.0))
    return max(scored, key=lambda c: (c.adj_holds, -c.mean))


def decide(claim: Claim, rows: dict[str, Row], smallest_effect: float = SMALLEST_EFFECT) -> dict:
    """A claim decided: its comparisons (rows of equal budget unless cross-budget), their p adjusted
    per family, the verdict against δ = ``smallest_effect``; ``family`` names the p the tables show.
    NOT RUN, naming them, when any row it lists did not run (``not_run``)."""
    ran = {r for r in rows if rows[r].scored}
    missing = sorted({r for pair in claim.pairs for r in pair} - ran)
    present = [(a, b) for a, b in claim.pairs if a in ran and b in ran]
    equal = [(a, b) for a, b in present if claim.cross_budget or rows[a].budget == rows[b].budget]
    out = {"id": claim.id, "claim": claim.text, "by": claim.by, "cross_budget": claim.cross_budget, "m": len(equal)}
    out["unequal_budget"] = [[a, b] for a, b in present if (a, b) not in equal]
    out["not_run"] = missing
    if missing or not equal:  # a listed row that did not run: the claim is not decided on the others
        why = f"not run: {', '.join(missing)}" if missing else "no row of equal budget in this run"
        return out | {"verdict": NOT_RUN, "note": why, "n": 0, "family": None, "decisive": None, "comparisons": []}
    comps = [compare(rows, a, b, smallest_effect) for a, b in equal]
    families = claim_families(*([getattr(c, f) for c in comps] for f in ("p_holds", "p_short", "p_low")))
    for c, (h, s, e) in zip(comps, zip(*families)):
        c.adj_holds, c.adj_short, c.adj_equivalent = float(h), float(s), float(e)
    n = min(c.n for c in comps)
    outcome = str(verdict(*families, n))
    need = needed_scenes(len(comps))
    short = outcome == "INCONCLUSIVE" and n < need
    note = f"a failure among {len(comps)} comparisons needs n ≥ {need} scenes" if short and need > MIN_SCENES else ""
    return out | {
        "verdict": outcome,
        "note": note,
        "n": n,
        "family": FAMILY.get(outcome),
        "decisive": decisive(comps, outcome).__dict__,
        "comparisons": [c.__dict__ for c in comps],
    }


def over_baseline(
    rows: dict[str, Row],
    stage1: dict[str, Row],
    nerf: str,
    baseline: str = "prior",
    smallest_effect: float = SMALLEST_EFFECT,
) -> list[dict]:
    """Δ PSNR of every translator that ran over a non-learned ``baseline`` (a key of BASELINES), and
    of the baselines listed after it (``classical`` over ``prior``), at stage 1 and in each model;
    each is its own one-comparison claim against δ = ``smallest_effect``."""
    later = list(BASELINES)[list(BASELINES).index(baseline) + 1 :]
    methods = [(t, label) for block, label in BLOCKS for t in block] + [(b, "non-learned") for b in later]
    out = []
    for t, label in methods:
        for stage, table, better, worse in (
            ("stage 1", stage1, t, baseline),
            ("3dgs", rows, f"{t}+3dgs", f"{baseline}+3dgs"),
            (nerf, rows, f"{t}+{nerf}", f"{baseline}+{nerf}"),
        ):
            if better in table and worse in table:
                text = f"{t} over {BASELINES[baseline]} ({stage})"
                claim = Claim(f"over-{baseline}:{t}:{stage}", "ours", text, ((better, worse),))
                entry = decide(claim, table, smallest_effect)
                out.append(entry | {"translator": t, "block": label, "baseline": baseline, "stage": stage})
    return out


def over_prior(
    rows: dict[str, Row], stage1: dict[str, Row], nerf: str, smallest_effect: float = SMALLEST_EFFECT
) -> list[dict]:
    """:func:`over_baseline` for the untrained ``prior``."""
    return over_baseline(rows, stage1, nerf, "prior", smallest_effect)


# --- the plan: the claims a configuration will decide, before it runs ---------------------------------


def planned_rows(combinations: list[str], budgets: dict[str, tuple]) -> dict[str, Row]:
    """Rows as a run of ``combinations`` will record them, each with its budget (K, S) from ``budgets``
    and one nominal scored run, so that :func:`claims` and the equal-budget rule see them as run."""
    return {c: Row(tuple(budgets[c]), {("planned", 0): 0.0}) for c in combinations if "@" not in c}


def planned_budgets(combinations: list[str], stage1_frames: int, stage2_frames: int, capture_factor: int) -> dict:
    """(K, S) each row of ``combinations`` will record (spc3d.names: frames per view, sensor pixels per
    image pixel per axis), as the workflow's jobs write them into metrics.json."""
    budgets = {}
    for combo in combinations:
        source = parse_combination(combo)[0]
        k = source_frames(source, stage1_frames, stage2_frames)
        budgets[combo] = (k, capture_factor if reads_capture_frame(source, stage2_frames) else 1)
    return budgets


def claim_plan(rows: dict[str, Row], nerf: str, rivals: dict[str, list[str]] | None = None) -> list[dict]:
    """Each claim of a planned run (:func:`planned_rows`): its comparisons at equal budget (or
    cross-budget), the listed rows the configuration does not run (the claim would be NOT RUN), and
    the fewest scenes that can decide it: HOLDS needs MIN_SCENES whatever m; a failure among m
    comparisons needs :func:`needed_scenes`."""
    out = []
    for claim in claims(rows, nerf, rivals):
        listed = {r for pair in claim.pairs for r in pair}
        pairs = [(a, b) for a, b in claim.pairs if a in rows and b in rows]
        equal = [(a, b) for a, b in pairs if claim.cross_budget or rows[a].budget == rows[b].budget]
        out.append(
            {
                "id": claim.id,
                "by": claim.by,
                "claim": claim.text,
                "comparisons": [f"{a} vs {b}" for a, b in equal],
                "m": len(equal),
                "not_run": sorted(listed - set(rows)),
                "cross_budget": claim.cross_budget,
                "holds_needs": MIN_SCENES,
                "fails_needs": needed_scenes(len(equal)) if equal else None,
            }
        )
    return out


def plan_markdown(plan: list[dict]) -> str:
    """The claims of a plan as a Markdown table (docs/protocol.md quotes it, tests/test_protocol_plan.py
    checks the quote)."""
    cells = []
    for c in plan:
        pairs = [x.split(" vs ") for x in c["comparisons"]]
        if len({a for a, _ in pairs}) == 1:  # one row against its rivals: name it once
            versus = f"{pairs[0][0]} vs {', '.join(b for _, b in pairs)}"
        else:
            versus = "; ".join(c["comparisons"]) or "–"
        missing = f" **NOT RUN: {', '.join(c['not_run'])}**" if c["not_run"] else ""
        fails = c["fails_needs"] if c["fails_needs"] is not None else "–"
        budget = "cross-budget" if c["cross_budget"] else "equal"
        cells.append([f"`{c['id']}`", c["by"], c["claim"] + missing, versus, str(c["m"]), budget, str(fails)])
    columns = ["id", "by", "claim", "comparisons (better vs worse)", "m", "budgets", "scenes a failure needs"]
    return "\n".join(md_table(columns, cells)) + "\n"


# --- the base of the findings ------------------------------------------------------------------------


def base(rows: dict[str, Row]) -> str:
    """The scored scenes and runs of every row, e.g. "2 scenes, 6 runs (courtyard, tabletop × seeds 0, 1, 2)"."""
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
    plural = {n: "" if n == 1 else "s" for n in (len(seeds), len(runs))}
    return f"{len(seeds)} scene{plural[len(seeds)]}, {len(runs)} run{plural[len(runs)]} ({where})"


def header(rows: dict[str, Row], results: list[dict], smallest_effect: float = SMALLEST_EFFECT) -> str:
    """The opening line: the base (scenes × seeds), δ, the test, MIN_SCENES; and whether only descriptive."""
    line = (
        f"Base: {base(rows)}; one PSNR per row and run (its held-out views averaged), one per row and scene "
        "(its seeds averaged: the scene is the unit), claims pair the scenes two rows share. Smallest effect of "
        f'interest δ = {smallest_effect:g} dB: "A beats B" means by more '
        "than δ. Test: exact sign-flip permutation test of the mean paired difference, one-sided at 2.5 % "
        "against ±δ (a claim holds when each of its comparisons does; a failure is Holm-adjusted over them), "
        "interval = the two-sided test inverted (95 %); a verdict "
        f"needs ≥ MIN_SCENES = {MIN_SCENES} paired scenes."
    )
    if not any(r["verdict"] in DECIDED for r in results):
        line += (
            f" This run is descriptive only: n = {base(rows)}; a verdict needs ≥ {MIN_SCENES} paired scenes, "
            f"whatever the seeds ({PRESET})."
        )
    return line


# --- writing -----------------------------------------------------------------------------------------


def legend(smallest_effect: float = SMALLEST_EFFECT) -> str:
    """What the verdicts and columns mean, with δ."""
    return (
        f"δ = {smallest_effect:g} dB, the smallest effect of interest. HOLDS: every comparison beats its row by "
        "more than δ (each p of H0: Δ ≤ δ at most 0.025: its 95 % interval lies above +δ; unadjusted, as the "
        "claim needs every one of them, an intersection-union test); DOES NOT HOLD: some comparison falls short "
        "of δ (Holm p of H0: Δ ≥ δ at most 0.025) and is not within ±δ; EQUIVALENT: every comparison that falls "
        "short of δ is within ±δ (two one-sided tests, Holm p of H0: Δ ∉ (−δ, δ) at most 0.025): the claimed "
        "advantage is smaller than δ either way; INCONCLUSIVE: otherwise; DESCRIPTIVE ONLY: fewer than "
        f"{MIN_SCENES} paired scenes (the smallest exact one-sided p, 1/2^n, cannot reach 0.025), shown with the "
        "range of the scene differences instead of an interval. The adjusted p shown is the decisive comparison's, "
        "of the null hypothesis named beside it. The decisive comparison is the one with the largest p of "
        "H0: Δ ≤ δ (for DOES NOT HOLD and EQUIVALENT the failing one with the strongest evidence; when "
        "descriptive the closest). Rows of equal budget (K frames, S× capture) only, except cross-budget "
        "claims; rows on estimated poses enter no claim."
    )


LEGEND = legend()
CLAIM_COLUMNS = ["claim", "by", "verdict", "decisive comparison", "Δ PSNR (dB)", "95 % interval (or range)",
                 "adjusted p", "n (scenes)", "m"]  # fmt: skip
PRIOR_COLUMNS = ["translator", "block", "stage", "verdict", "Δ PSNR (dB)", "95 % interval (or range)", "p",
                 "n (scenes)"]  # fmt: skip
BASELINE_TITLES = {
    "prior": "Δ over the untrained prior (`prior`)",
    "classical": "Δ over the classical method (`classical`)",
}


def p_text(p: float) -> str:
    return f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def _cells(r: dict) -> list[str]:
    """(verdict, decisive comparison, Δ, interval or range, adjusted p, n) of a decided claim."""
    c, note = r["decisive"], f" ({r['note']})" if r["note"] else ""
    if c is None:
        return [f"**{r['verdict']}**", r["note"], "–", "–", "–", "0"]
    if c["mean"] is None:
        return [f"**{r['verdict']}**{note}", f"{c['better']} vs {c['worse']}: no paired scenes", "–", "–", "–", "0"]
    bounds = f"[{c['low']:+.2f}, {c['high']:+.2f}]"
    family = r.get("family")
    p = f"{p_text(c[f'adj_{family}'])} (H0: {NULLS[family]})" if family else "–"
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


def _baselines(prior: list[dict], classical: list[dict]) -> list[tuple[str, str, list[dict]]]:
    """(baseline, title, entries) of the Δ-over-baselines tables."""
    return [(b, BASELINE_TITLES[b], entries) for b, entries in (("prior", prior), ("classical", classical))]


def markdown(
    first_line: str,
    results: list[dict],
    prior: list[dict],
    classical: list[dict] | tuple = (),
    smallest_effect: float = SMALLEST_EFFECT,
) -> str:
    lines = ["# Findings", "", first_line, "", *md_table(CLAIM_COLUMNS, [claim_cells(r) for r in results])]
    lines += ["", legend(smallest_effect), "", "## Δ over the baselines"]
    for baseline, title, entries in _baselines(prior, list(classical)):
        lines += ["", f"### {title}", ""]
        if entries:
            lines += md_table(PRIOR_COLUMNS, [prior_cells(r) for r in entries])
        else:
            lines.append(f"No other stage-1 method ran beside the `{baseline}` rows in this run.")
    return "\n".join(lines) + "\n"


def _html_table(columns: list[str], cells: list[list[str]]) -> str:
    head = "".join(f"<th>{c}</th>" for c in columns)
    body = "".join("<tr>" + "".join(f"<td>{_bold(c)}</td>" for c in row) + "</tr>" for row in cells)
    return f"<table><tr>{head}</tr>{body}</table>"


def _bold(cell: str) -> str:
    return f"<b>{cell[2:].replace('**', '</b>', 1)}" if cell.startswith("**") else cell


def html(
    first_line: str,
    results: list[dict],
    prior: list[dict],
    classical: list[dict] | tuple = (),
    smallest_effect: float = SMALLEST_EFFECT,
) -> str:
    tables = "".join(
        f"<h4>{title.replace('`', '')}</h4>{_html_table(PRIOR_COLUMNS, [prior_cells(r) for r in entries])}"
        for _, title, entries in _baselines(prior, list(classical))
    )
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Findings</title><style>body{font-family:"
        "sans-serif;font-size:13px;margin:12px}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
        "padding:3px 6px}</style></head><body><h3>Findings: the claims, decided from the numbers</h3>"
        f"<p>{first_line}</p>{_html_table(CLAIM_COLUMNS, [claim_cells(r) for r in results])}"
        f"<p>{legend(smallest_effect)}</p><h3>Δ over the baselines</h3>{tables}</body></html>\n"
    )


def write_findings(
    metrics_files: list[str | os.PathLike],
    stem: str | os.PathLike,
    nerf_variant: str,
    stage1_files: list[str | os.PathLike] | tuple = (),
    smallest_effect: float = SMALLEST_EFFECT,
    rivals: dict[str, list[str]] | None = None,
) -> dict:
    """``stem``.md, .json and .html: every claim decided on paired scenes against the smallest effect
    of interest δ = ``smallest_effect`` (dB PSNR), with the listed ``rivals`` (:func:`claims`), and the
    Δ-over-baselines tables (``over_prior``, ``over_classical``). Returns what the JSON holds."""
    stem, delta = Path(stem), float(smallest_effect)
    if not (math.isfinite(delta) and delta >= 0):
        raise ValueError(f"write_findings: smallest_effect (dB) must be finite and ≥ 0, got {smallest_effect!r}")
    rows, stage1 = read_rows(metrics_files), read_stage1(stage1_files)
    results = [decide(c, rows, delta) for c in claims(rows, nerf_variant, rivals)]
    prior = over_baseline(rows, stage1, nerf_variant, "prior", delta)
    classical = over_baseline(rows, stage1, nerf_variant, "classical", delta)
    first_line = header(rows, results + prior + classical, delta)
    out = {
        "metric": METRIC,
        "alpha": ALPHA,
        "level": LEVEL,
        "smallest_effect_db": delta,
        "min_scenes": MIN_SCENES,
        "unit": "scene (a row's value for a scene is the mean over its seeds)",
        "test": "exact sign-flip permutation test of the mean paired scene difference (Monte-Carlo above "
        f"{EXACT_UP_TO} scenes), one-sided at alpha / 2 against ±smallest_effect_db; Holm over a claim's "
        "comparisons, family by family; equivalence by two one-sided tests; interval = the two-sided test inverted",
        "base": first_line,
        "claims": results,
        "over_prior": prior,
        "over_classical": classical,
    }
    io.write_json(stem.with_suffix(".json"), out)
    io.write_text(stem.with_suffix(".md"), markdown(first_line, results, prior, classical, delta))
    io.write_text(stem.with_suffix(".html"), html(first_line, results, prior, classical, delta))
    return out

"""The findings: claims decided on paired scenes by the exact sign-flip test against the smallest
effect of interest δ (one-sided at 2.5 %, equivalence by two one-sided tests), Holm over a claim's
comparisons per family, DESCRIPTIVE ONLY below MIN_SCENES, equal budgets only (cross-budget claims
labelled)."""

import json
import math

import numpy as np
import pytest

from spc3d import io
from spc3d.evaluation.findings import (
    MIN_SCENES,
    N_RANDOM,
    Row,
    claim_families,
    effect_p,
    holm,
    interval,
    needed_scenes,
    one_sided_p,
    paired,
    sign_flip_p,
    smallest_p,
    verdict,
    write_findings,
)

NERF = "nerf-grid"
# 6 scenes x 2 seeds: 6 paired scenes, the smallest n that can reach a verdict (the seeds of a scene average)
SCENES, SEEDS = ("courtyard", "tabletop", "orchard", "gallery", "harbour", "observatory"), (0, 1)


# --- the test on known answers -------------------------------------------------------------------


def test_exact_p_on_small_known_cases():
    assert sign_flip_p([1.0, 2.0, 3.0]) == 0.25  # all positive: 2 of 8 patterns reach the observed |mean|
    assert sign_flip_p(np.arange(1.0, 7.0)) == 2 / 64
    assert sign_flip_p([3.0, 1.0, -1.0]) == 0.75  # |sums| 3, 5, 1, 3 (and mirrored): 3 of 4 reach 3
    assert sign_flip_p([0.7]) == 1.0 and sign_flip_p([1.0, -1.0]) == 1.0
    assert sign_flip_p(np.zeros(8)) == 1.0  # ties count
    batch = np.array([[1.0, 2.0, 3.0], [3.0, 1.0, -1.0]])
    assert np.array_equal(sign_flip_p(batch), [0.25, 0.75])  # vectorised over leading axes
    assert sign_flip_p(np.arange(1.0, 21.0)) <= 3 / (1 + N_RANDOM)  # n > 16: Monte-Carlo, (1 + count) / (1 + B)
    with pytest.raises(ValueError, match="finite paired difference"):
        sign_flip_p([1.0, math.inf])


def test_interval_is_the_inverted_test():
    assert interval(np.full(8, 1.5)) == (1.5, 1.5)
    six = np.array([0.4, 1.9, 0.7, 2.5, 1.1, 0.2])
    assert interval(six) == (0.2, 2.5)  # n = 6, all one sign: exactly [min, max]
    assert interval(six[:5]) == (-math.inf, math.inf)  # no test can reject at n = 5
    rng = np.random.default_rng(1)
    for n, draws in ((7, 5), (9, 5), (12, 5), (18, 1)):  # 18: Monte-Carlo patterns
        for _ in range(draws):
            d = rng.normal(0.6, 1.0, n)
            lo, hi = interval(d)
            assert d.min() <= lo <= d.mean() <= hi <= d.max()
            assert (lo > 0 or hi < 0) == (sign_flip_p(d) <= 0.05), (n, d)  # 0 outside iff rejected
            eps = 1e-5 * np.ptp(d)
            assert sign_flip_p(d - lo) > 0.05 and sign_flip_p(d - hi) > 0.05  # the ends are accepted
            assert sign_flip_p(d - (lo - eps)) <= 0.05 and sign_flip_p(d - (hi + eps)) <= 0.05  # just outside: not


def test_one_sided_p_on_small_known_cases():
    assert one_sided_p([1.0, 2.0, 3.0]) == 1 / 8  # only the observed pattern reaches mean 2: half the two-sided 0.25
    assert one_sided_p([1.0, 2.0, 3.0], greater=False) == 1.0
    assert one_sided_p(np.arange(1.0, 7.0)) == 1 / 64 == smallest_p(6, one_sided=True)
    assert one_sided_p([0.5, 1.0, 1.5], shift=1.0) == 0.75  # d - 1 = (-0.5, 0, 0.5): sums 0, 1, -1, 0 (twice)
    assert one_sided_p(np.zeros(8)) == one_sided_p(np.zeros(8), greater=False) == 1.0  # ties count
    batch = np.array([[1.0, 2.0, 3.0], [-1.0, -2.0, -3.0]])
    assert np.array_equal(one_sided_p(batch), [1 / 8, 1.0])  # vectorised over leading axes
    many = np.arange(1.0, 21.0)  # n > 16: Monte-Carlo, (1 + count) / (2 + 2B) over the patterns and their mirrors
    assert one_sided_p(many) == pytest.approx(sign_flip_p(many) / 2) and one_sided_p(many) <= 3 / (2 + 2 * N_RANDOM)
    # δ = 0.25 against runs 0.1 dB apart: short of δ (1/64), above -δ (1/64), not above δ (1)
    assert effect_p(np.full(6, 0.1), 0.25) == (1.0, 1 / 64, 1 / 64)
    p_holds, p_short, p_low = effect_p(batch, 0.5)
    assert p_holds.shape == p_short.shape == p_low.shape == (2,)
    with pytest.raises(ValueError, match="must be finite and ≥ 0"):
        effect_p([1.0, 2.0], -0.1)
    with pytest.raises(ValueError, match="finite paired difference"):
        one_sided_p([1.0, math.nan])


def test_one_sided_tests_agree_with_the_interval():
    """Rejecting at 2.5 % one-sided is the two-sided 95 % interval clearing the bound."""
    rng = np.random.default_rng(3)
    for n, draws in ((6, 4), (9, 4), (12, 4), (18, 1)):  # 18: Monte-Carlo patterns
        for _ in range(draws):
            d = rng.normal(0.3, 0.5, n)
            lo, hi = interval(d)
            towards = one_sided_p(d, greater=bool(d.mean() > 0))
            assert towards == pytest.approx(sign_flip_p(d) / 2, rel=1e-12)
            for delta in rng.uniform(0.0, 0.8, 4):
                p_holds, p_short, p_low = effect_p(d, delta)
                assert (lo > delta) == (p_holds <= 0.025), (n, d, delta)
                assert (hi < delta) == (p_short <= 0.025), (n, d, delta)
                assert (lo > -delta) == (p_low <= 0.025), (n, d, delta)


def test_holm_against_a_hand_computation():
    p = [0.01, 0.04, 0.03, 0.005]
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 = 0.02, 0.03, 0.06, 0.04; made monotone: 0.06 for the last
    assert holm(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm([[0.5, 0.6], [0.01, 0.02]]), [[1.0, 1.0], [0.02, 0.02]])  # capped at 1, per row
    assert [needed_scenes(m) for m in (1, 2, 4, 8)] == [6, 7, 8, 9]  # 1 / 2^N ≤ 0.025 / m
    holds, short, equivalent = claim_families([[0.01, 0.5]], [[0.9, 0.004]], [[0.001, 0.02]])
    np.testing.assert_allclose(holds, [[0.01, 0.5]])  # as they are: HOLDS is an intersection-union test
    np.testing.assert_allclose(short, [[0.9, 0.008]])
    np.testing.assert_allclose(equivalent, [[0.9, 0.04]])  # Holm of max(p_short, p_low) = (0.9, 0.02)


def test_verdict_rules():
    # adjusted p per comparison of each family (holds: H0 Δ ≤ δ, as it is; short: H0 Δ ≥ δ and
    # equivalent: H0 |Δ| ≥ δ, Holm-adjusted), each tested at 0.025
    assert verdict([0.005, 0.015], [1.0, 1.0], [1.0, 1.0], 6) == "HOLDS"
    assert verdict([0.005, 0.15], [1.0, 0.9], [1.0, 0.9], 6) == "INCONCLUSIVE"
    assert verdict([0.03], [0.97], [0.97], 6) == "INCONCLUSIVE"  # 0.03 > 0.025
    assert verdict([0.15, 1.0], [0.9, 0.015], [0.9, 0.3], 6) == "DOES NOT HOLD"  # short of δ, not within ±δ
    assert verdict([0.15, 1.0], [0.9, 0.015], [0.9, 0.02], 6) == "EQUIVALENT"  # short of δ, within ±δ
    assert verdict([1.0, 1.0], [0.01, 0.02], [0.01, 0.3], 6) == "DOES NOT HOLD"  # one failing is not equivalent
    assert verdict([1.0, 1.0], [0.3, 0.5], [0.01, 0.02], 6) == "INCONCLUSIVE"  # equivalence alone does not fail
    assert verdict([0.005], [1.0], [1.0], MIN_SCENES - 1) == "DESCRIPTIVE ONLY"
    batch = verdict([[0.005], [1.0], [1.0]], [[1.0], [0.01], [0.01]], [[1.0], [0.5], [0.01]], 6)
    assert list(batch) == ["HOLDS", "DOES NOT HOLD", "EQUIVALENT"]  # vectorised over claims


def _decide(diffs: list, smallest_effect: float) -> str:
    """The verdict of one claim whose comparisons have these paired run differences."""
    families = claim_families(*zip(*(effect_p(d, smallest_effect) for d in diffs)))
    return str(verdict(*families, min(len(d) for d in diffs)))


def test_equivalence_and_the_margin_on_known_effects():
    rng = np.random.default_rng(5)

    def runs(mean, sd):
        return rng.normal(mean, sd, 12)

    assert _decide([runs(0.0, 0.05)], 0.25) == "EQUIVALENT"  # no effect: the rows differ by less than δ
    assert _decide([runs(1.0, 0.1)], 0.25) == "HOLDS"
    small = runs(0.15, 0.02)  # a real effect, smaller than δ
    assert _decide([small], 0.25) == "EQUIVALENT" and _decide([small], 0.0) == "HOLDS"
    assert _decide([runs(-1.0, 0.1)], 0.25) == "DOES NOT HOLD"
    assert _decide([runs(0.25, 0.5)], 0.25) == "INCONCLUSIVE"
    # two comparisons: one clears δ and the other is equivalent, or one falls below -δ
    assert _decide([runs(1.0, 0.1), runs(0.0, 0.05)], 0.25) == "EQUIVALENT"
    assert _decide([runs(0.0, 0.05), runs(-1.0, 0.1)], 0.25) == "DOES NOT HOLD"
    assert _decide([runs(1.0, 0.1), runs(2.0, 0.1)], 0.25) == "HOLDS"


def test_a_claim_over_many_comparisons_is_wrongly_held_at_most_at_the_level():
    """The intersection-union test: five comparisons, four far beyond δ and one exactly at δ (the
    least favourable configuration): HOLDS at most 2.5 % of the time, at n = 8 as at n = 12, where
    Holm over the five would need n = 8 just to reach the level."""
    rng = np.random.default_rng(11)
    for n in (8, 12):
        d = rng.normal(0.25, 0.3, (4000, 5, n))
        d[:, 1:] += 2.0  # far beyond δ: these always hold
        p_holds, p_short, p_low = effect_p(d, 0.25)
        rate = float((verdict(*claim_families(p_holds, p_short, p_low), n) == "HOLDS").mean())
        assert rate <= 0.025 + 3 * math.sqrt(0.025 * 0.975 / 4000), (n, rate)
    clear = rng.normal(1.5, 0.2, (10, 8))  # ten rivals each beaten by far more than δ, on 8 runs
    assert _decide(list(clear), 0.25) == "HOLDS"  # Holm over ten would need n = 9


def test_without_a_margin_the_two_sided_rule_and_never_equivalent():
    """δ = 0: a one-comparison claim HOLDS (DOES NOT HOLD) exactly when the two-sided test rejects at
    5 % with a positive (negative) mean, and EQUIVALENT cannot happen."""
    rng = np.random.default_rng(2)
    for n in (6, 8, 11):
        d = rng.normal(rng.uniform(-1.5, 1.5, (1500, 1)), 1.0, (1500, n))
        p_holds, p_short, p_low = effect_p(d, 0.0)
        holds, short, equivalent = claim_families(p_holds[:, None], p_short[:, None], p_low[:, None])
        v = verdict(holds, short, equivalent, n)
        p, mean = sign_flip_p(d), d.mean(axis=1)
        old = np.select(
            [(mean > 0) & (p <= 0.05), (mean < 0) & (p <= 0.05)], ["HOLDS", "DOES NOT HOLD"], "INCONCLUSIVE"
        )
        assert np.array_equal(v, old), n
        assert (equivalent >= 0.5).all() and "EQUIVALENT" not in v


# --- coverage and power under simulation ---------------------------------------------------------

RUNS, REPS, SHIFTS = (3, 5, 6, 9, 10), 4000, (0.0, 0.5, 1.0, 1.5, 2.0)
# Null paired run differences (symmetric about 0) and their standard deviation; the mixture's
# runs alternate between two scenes: normal with sd 0.3 and a lumpy ±2.
NULLS = {
    "normal": (lambda rng, size: rng.normal(size=size), 1.0),
    "student t3": (lambda rng, size: rng.standard_t(3, size=size), math.sqrt(3)),
    "uniform": (lambda rng, size: rng.uniform(-1, 1, size), 1 / math.sqrt(3)),
    "two-point ±1": (lambda rng, size: rng.choice([-1.0, 1.0], size), 1.0),
    "two-scene mix": (
        lambda rng, size: np.where(np.arange(size[-1]) % 2, rng.choice([-2.0, 2.0], size), rng.normal(0, 0.3, size)),
        math.sqrt((0.3**2 + 2**2) / 2),
    ),
}


def _verdicts(d: np.ndarray, smallest_effect: float = 0.0) -> np.ndarray:
    """The verdicts of one-comparison claims, one per replicate (row of paired run differences)."""
    p_holds, p_short, p_low = effect_p(d, smallest_effect)
    return verdict(*claim_families(p_holds[:, None], p_short[:, None], p_low[:, None]), d.shape[1])


def _rejection_rate(d: np.ndarray) -> float:
    """Fraction of replicates (rows) whose one-comparison claim gets a verdict (HOLDS or DOES NOT HOLD)
    with δ = 0: the two one-sided tests at 2.5 % together, the two-sided test at 5 %."""
    return float(np.isin(_verdicts(d), ["HOLDS", "DOES NOT HOLD"]).mean())


def test_coverage_false_positives_and_power_by_run_count():
    rng = np.random.default_rng(7)
    rate = {}  # (distribution, n, shift in sd) -> rejection rate
    for name, (draw, sd) in NULLS.items():
        base = draw(rng, (REPS, max(RUNS)))  # common draws: the first n runs of each replicate
        for n in RUNS:
            for shift in SHIFTS:
                rate[name, n, shift] = _rejection_rate(base[:, :n] + shift * sd)
    print(f"\n{'null':<14} {'n':>3} {'FPR':>6} " + " ".join(f"pow {s:g}σ".rjust(8) for s in SHIFTS[1:]))
    for name in NULLS:
        for n in RUNS:
            print(
                f"{name:<14} {n:>3} {rate[name, n, 0.0]:6.3f} "
                + " ".join(f"{rate[name, n, s]:8.3f}" for s in SHIFTS[1:])
            )
    slack = 3 * math.sqrt(0.05 * 0.95 / REPS)
    for name in NULLS:
        for n in RUNS:
            assert rate[name, n, 0.0] <= 0.05 + slack, (name, n)  # false positives: at most 5 %
            if n < MIN_SCENES:
                assert all(rate[name, n, s] == 0.0 for s in SHIFTS), (name, n)  # descriptive: never a verdict
        assert rate[name, 10, 0.5] <= rate[name, 10, 1.0] + 0.02 <= rate[name, 10, 2.0] + 0.04, name
        assert rate[name, 10, 2.0] > rate[name, 10, 0.5], name  # power rises with the shift
        assert rate[name, 10, 1.0] > rate[name, 6, 1.0], name  # and with the runs
    assert rate["normal", 10, 1.5] > 0.5


def test_false_positives_at_the_margin():
    """True effect exactly δ: HOLDS at most 2.5 % of the time, and so is the claimed effect wrongly
    excluded (DOES NOT HOLD or EQUIVALENT); true effect exactly -δ: EQUIVALENT at most 2.5 %. Under
    every null (symmetric about the true effect), at n = 6 (the smallest p is 1/64) and 10."""
    delta, reps, scale = 0.25, 4000, 0.4  # run differences of sd 0.4 dB x the null's
    rng = np.random.default_rng(11)
    slack = 3 * math.sqrt(0.025 * 0.975 / reps)
    for name, (draw, sd) in NULLS.items():
        noise = draw(rng, (reps, 10)) * scale / sd
        for n in (6, 10):
            at_delta = _verdicts(delta + noise[:, :n], delta)
            assert np.mean(at_delta == "HOLDS") <= 0.025 + slack, (name, n)
            assert np.isin(at_delta, ["DOES NOT HOLD", "EQUIVALENT"]).mean() <= 0.025 + slack, (name, n)
            assert np.mean(_verdicts(-delta + noise[:, :n], delta) == "EQUIVALENT") <= 0.025 + slack, (name, n)
        inside = _verdicts(0.1 * noise, delta)  # no effect, small noise: equivalence has power
        assert np.mean(inside == "EQUIVALENT") > 0.9, name


# Clustered nulls: the paired difference of a run is δ + the scene's effect + the seed's noise, the
# scene's effect (symmetric about 0) much larger than the seed noise, as on the real scenes (per-scene
# Δ from −0.22 to +2.57 dB, seeds of one scene a median 0.17 dB apart).
SCENE_EFFECTS = {
    "normal": lambda rng, size: rng.normal(0.0, 1.0, size),
    "two-point ±1": lambda rng, size: rng.choice([-1.0, 1.0], size),
    "student t3": lambda rng, size: rng.standard_t(3, size) / math.sqrt(3),
}


def _clustered(rng, effect, reps: int, scenes: int, seeds: int, shift: float) -> list[np.ndarray]:
    """Per replicate, the paired scene differences :func:`paired` makes of two rows whose run
    differences are shift + scene effect + seed noise (sd 0.1 dB)."""
    u = effect(rng, (reps, scenes, 1))
    d = shift + u + rng.normal(0.0, 0.1, (reps, scenes, seeds))
    out = []
    for rep in d:
        a = Row((1, 1), {(f"s{i}", k): float(rep[i, k]) for i in range(scenes) for k in range(seeds)})
        b = Row((1, 1), {run: 0.0 for run in a.runs})
        out.append(paired(a, b))
    return out


def test_clustered_nulls_keep_every_verdict_at_its_level():
    """Scene effects ≫ seed noise, true Δ exactly δ (or −δ): with the scene as the unit, a wrong HOLDS,
    a wrong exclusion of the effect (DOES NOT HOLD or EQUIVALENT) and a wrong EQUIVALENT at −δ each
    happen at most 2.5 % of the time; fewer than six scenes never decide, however many seeds. Treating
    each (scene, seed) as independent would not keep the level: shown on the same draws."""
    delta, reps = 0.25, 2000
    rng = np.random.default_rng(5)
    slack = 3 * math.sqrt(0.025 * 0.975 / reps)
    for name, effect in SCENE_EFFECTS.items():
        for scenes, seeds in ((4, 2), (6, 2), (6, 3), (8, 2)):
            at = np.stack(_clustered(rng, effect, reps, scenes, seeds, delta))
            assert at.shape == (reps, scenes)  # one value per scene: the seeds averaged
            v = _verdicts(at, delta)
            below = np.stack(_clustered(rng, effect, reps, scenes, seeds, -delta))
            if scenes < MIN_SCENES:
                assert (v == "DESCRIPTIVE ONLY").all() and (_verdicts(below, delta) == "DESCRIPTIVE ONLY").all()
                continue
            assert np.mean(v == "HOLDS") <= 0.025 + slack, (name, scenes, seeds)
            assert np.isin(v, ["DOES NOT HOLD", "EQUIVALENT"]).mean() <= 0.025 + slack, (name, scenes, seeds)
            assert np.mean(_verdicts(below, delta) == "EQUIVALENT") <= 0.025 + slack, (name, scenes, seeds)
    # the same clustered draws flipped run by run: 8 "runs" of 4 scenes hold far above the level
    u = rng.normal(0.0, 1.0, (reps, 4, 1))
    runs = (delta + u + rng.normal(0.0, 0.1, (reps, 4, 2))).reshape(reps, 8)
    assert np.mean(_verdicts(runs, delta) == "HOLDS") > 0.05


# --- the findings files --------------------------------------------------------------------------


def _record(folder, combo, scene, seed, psnr, frames=1, capture_factor=None, **extra):
    """A metrics.json record of one run; ``psnr`` None: not reconstructed."""
    path = folder / f"{combo}-{scene}-{seed}.json".replace("+", "_").replace("@", "_at_")
    rec = {"combination": combo, "scene": scene, "seed": seed, "frames": frames, **extra}
    rec["mean"] = None if psnr is None else {"psnr": float(psnr), "ssim": 0.5}
    rec["per_view"] = [] if psnr is None else [{"view": "v0", "psnr": float(psnr)}]
    if capture_factor is not None:
        rec["capture_factor"] = capture_factor
    io.write_json(path, rec)
    return str(path)


def _rows(folder, offsets: dict[str, float], budgets: dict[str, dict] | None = None) -> list[str]:
    """Records of every row on the 6 runs: a per-run base PSNR plus the row's offset and a little
    per-run noise (all rows of one run share its base: the runs pair)."""
    rng = np.random.default_rng(0)
    runs = [(s, k) for s in SCENES for k in SEEDS]
    base = dict(zip(runs, rng.uniform(18, 24, len(runs))))
    files = []
    for combo, offset in offsets.items():
        for run in runs:
            psnr = base[run] + offset + rng.uniform(-0.05, 0.05)
            files.append(_record(folder, combo, *run, psnr, **(budgets or {}).get(combo, {})))
    return files


def _listed(*two_stage: str, mle: tuple = ("mle-x1+3dgs", "mle-x1-mse+3dgs")) -> dict:
    """The claims' listed rivals (``findings.rivals``): these two-stage rows and MLE rows."""
    return {"two_stage": list(two_stage), "mle": list(mle)}


def _by_id(results: dict) -> dict:
    return {r["id"]: r for r in results["claims"]}


def _two_sided_verdict(entry: dict) -> str:
    """A claim's verdict by the rule without δ, from its comparisons' two-sided p at 5 %: HOLDS when
    every one is rejected with a positive mean (unadjusted: the claim needs all of them), DOES NOT
    HOLD when one is, Holm-adjusted over them, with a negative mean."""
    if entry["verdict"] == "NOT RUN" or entry["n"] < MIN_SCENES:
        return entry["verdict"] if entry["verdict"] == "NOT RUN" else "DESCRIPTIVE ONLY"
    means, p = [c["mean"] for c in entry["comparisons"]], [c["p"] for c in entry["comparisons"]]
    if all(m > 0 and q <= 0.05 for m, q in zip(means, p)):
        return "HOLDS"
    return "DOES NOT HOLD" if any(m < 0 and a <= 0.05 for m, a in zip(means, holm(p))) else "INCONCLUSIVE"


def _at_zero_margin(files, stem, **kwargs) -> dict:
    """The findings with δ = 0: every claim and Δ-over-baseline entry gets the two-sided rule's verdict."""
    out = write_findings(files, stem, NERF, smallest_effect=0.0, **kwargs)
    entries = out["claims"] + out["over_prior"] + out["over_classical"]
    assert [e["verdict"] for e in entries] == [_two_sided_verdict(e) for e in entries]
    assert all(e["verdict"] != "EQUIVALENT" for e in entries) and out["smallest_effect_db"] == 0.0
    return out


def test_one_run_is_descriptive_only(tmp_path):
    files = [
        _record(tmp_path, f"pix2pixhd+{NERF}", "courtyard", 0, 22.0),
        _record(tmp_path, "pix2pixhd+3dgs", "courtyard", 0, 21.0),
        _record(tmp_path, f"none-x1+{NERF}", "courtyard", 0, 15.0),
    ]
    listed = _listed(f"pix2pixhd+{NERF}", "pix2pixhd+3dgs")
    out = write_findings(files, tmp_path / "findings", NERF, rivals=listed)
    claims = _by_id(out)
    assert claims["best-nerf"]["verdict"] == "DESCRIPTIVE ONLY" and claims["best-nerf"]["n"] == 1
    assert claims["two-stage-nerf"]["decisive"]["low"] == claims["two-stage-nerf"]["decisive"]["high"] == 7.0
    assert claims["denoisers"]["verdict"] == "NOT RUN"  # every listed row that did not run is named
    assert claims["denoisers"]["note"] == f"not run: diffusion+3dgs, diffusion+{NERF}, restormer+3dgs, restormer+{NERF}"
    md = (tmp_path / "findings.md").read_text()
    line = md.splitlines()[2]
    assert line.startswith("Base: 1 scene, 1 run (courtyard × seed 0)") and "sign-flip" in line
    assert "MIN_SCENES = 6" in line and "the scene is the unit" in line
    assert line.endswith(
        "This run is descriptive only: n = 1 scene, 1 run (courtyard × seed 0); a verdict needs ≥ 6 paired "
        "scenes, whatever the seeds (workflow/presets/findings.yaml)."
    )
    assert (
        "| **DESCRIPTIVE ONLY** | pix2pixhd+nerf-grid vs pix2pixhd+3dgs | +1.00 | range [+1.00, +1.00] | – | 1 | 1 |"
        in md
    )
    _at_zero_margin(files, tmp_path / "zero", rivals=listed)


def test_verdicts_on_six_paired_scenes(tmp_path):
    offsets = {f"pix2pixhd+{NERF}": 3.0, "pix2pixhd+3dgs": 2.0, f"none-x1+{NERF}": -4.0, "restormer+3dgs": 2.5}
    offsets |= {"bernoulli+3dgs": 1.0, "gt+3dgs": 10.0}
    files, listed = _rows(tmp_path, offsets), _listed(f"pix2pixhd+{NERF}", "pix2pixhd+3dgs", "restormer+3dgs")
    claims = _by_id(write_findings(files, tmp_path / "findings", NERF, rivals=listed))
    assert claims["two-stage-nerf"]["verdict"] == "HOLDS" and claims["two-stage-nerf"]["n"] == 6
    # one-sided against δ: the smallest p at n = 6, 1/64 (half the two-sided 2/64), from the "holds" family
    assert claims["two-stage-nerf"]["decisive"]["adj_holds"] == 1 / 64
    assert claims["two-stage-nerf"]["family"] == "holds"
    assert claims["two-stage-nerf"]["decisive"]["low"] == pytest.approx(7.0, abs=0.1)  # [min, max] of the runs
    best = claims["best-nerf"]  # m = 2 at n = 6: each comparison clears δ, which is all HOLDS needs (no Holm)
    assert best["m"] == 2 and best["verdict"] == "HOLDS" and best["note"] == ""
    assert claims["best-3dgs"]["verdict"] == "DOES NOT HOLD"  # restormer + 3DGS is better
    assert claims["best-3dgs"]["decisive"]["worse"] == "restormer+3dgs"
    assert claims["best-3dgs"]["family"] == "short"  # the Holm p of H0 Δ ≥ δ is shown
    assert "gt+3dgs" not in str(claims)
    assert "residual networks" in claims["best-nerf"]["claim"]
    zero = _by_id(_at_zero_margin(files, tmp_path / "zero", rivals=listed))
    assert [zero[k]["verdict"] for k in ("two-stage-nerf", "best-nerf", "best-3dgs")] == [
        "HOLDS",
        "HOLDS",
        "DOES NOT HOLD",
    ]


def test_equal_budgets_only_and_cross_budget_claims_labelled(tmp_path):
    offsets = {"bernoulli+3dgs": 1.0, "mle-x1+3dgs": 0.0, "mle-x1-mse+3dgs": -0.5, "mle+3dgs": 3.0}
    offsets |= {"mle-k16+3dgs": 9.0, "pix2pixhd+3dgs": 2.0, "none+3dgs": -1.0, "none-x1-mse+3dgs": -6.0}
    offsets |= {"prior+3dgs": 0.5, "bernoulli+3dgs@mle-k16": 5.0}
    budgets = {"mle+3dgs": {"capture_factor": 4}, "none+3dgs": {"capture_factor": 4}, "mle-k16+3dgs": {"frames": 16}}
    files, listed = _rows(tmp_path, offsets, budgets), _listed("pix2pixhd+3dgs", "prior+3dgs")
    claims = _by_id(write_findings(files, tmp_path / "findings", NERF, rivals=listed))
    spad_mle = claims["spad-mle"]
    assert [c["worse"] for c in spad_mle["comparisons"]] == ["mle-x1+3dgs", "mle-x1-mse+3dgs"]
    assert "(vs mle-x1+3dgs, mle-x1-mse+3dgs)" in spad_mle["claim"]
    assert spad_mle["verdict"] == "HOLDS" and spad_mle["note"] == ""  # +1.0 and +1.5 dB on each of 6 runs
    assert "mle-k16" not in str(claims) and "mle+3dgs" not in str(claims) and "@" not in str(claims)
    faithful = claims["two-stage-3dgs-faithful"]
    assert faithful["cross_budget"] and faithful["m"] == 1 and faithful["verdict"] == "HOLDS"
    assert "cross-budget: none: 1 frame at 4×4 sensor pixels per image pixel vs 1 frame at 1×" in faithful["claim"]
    assert claims["two-stage-3dgs"]["decisive"]["worse"] == "none-x1-mse+3dgs"
    spad = claims["spad-two-stage"]  # pix2pixhd is better than the SPAD likelihood here; the prior is not
    assert {c["worse"] for c in spad["comparisons"]} == {"pix2pixhd+3dgs", "prior+3dgs"}
    # a failure among 2 comparisons needs Holm p ≤ 0.0125; the smallest one-sided p at n = 6 is 0.016
    assert spad["verdict"] == "INCONCLUSIVE" and spad["note"] == "a failure among 2 comparisons needs n ≥ 7 scenes"
    _at_zero_margin(files, tmp_path / "zero", rivals=listed)


def test_joint_rows_get_their_claims_at_equal_and_across_budgets(tmp_path):
    offsets = {"joint-restormer+3dgs": 2.0, "bernoulli+3dgs": 1.0, "restormer+3dgs": 0.5, "prior+3dgs": 0.4}
    offsets |= {f"restormer+{NERF}": 1.9, "mle-k16+3dgs": 3.0}
    files = _rows(tmp_path, offsets, {"mle-k16+3dgs": {"frames": 16}})
    listed = _listed("restormer+3dgs", "prior+3dgs", f"restormer+{NERF}")
    claims = _by_id(write_findings(files, tmp_path / "findings", NERF, rivals=listed))
    likelihood = claims["joint-likelihood:joint-restormer+3dgs"]
    assert likelihood["verdict"] == "HOLDS" and likelihood["decisive"]["worse"] == "bernoulli+3dgs"
    two_stage = claims["joint-two-stage:joint-restormer+3dgs"]  # +0.1 dB over restormer + NeRF: not by δ
    assert {c["worse"] for c in two_stage["comparisons"]} == {"restormer+3dgs", "prior+3dgs", f"restormer+{NERF}"}
    # equivalence to one of 3 rows needs Holm p <= 0.025 / 3: n >= 7 (1/128), not 6 (1/64)
    assert two_stage["verdict"] == "INCONCLUSIVE"
    assert two_stage["note"] == "a failure among 3 comparisons needs n ≥ 7 scenes"
    reference = claims["joint-mle16:joint-restormer+3dgs"]
    assert reference["cross_budget"] and reference["verdict"] == "DOES NOT HOLD"
    assert "cross-budget: mle-k16: 16 frames at 1× vs 1 frame at 1×" in reference["claim"]
    assert not any(k.startswith("joint-") and "nerf" in k for k in claims)  # no joint NeRF row ran


def test_unequal_budget_pairs_are_set_aside_and_mixed_budgets_refused(tmp_path):
    offsets = {"bernoulli+3dgs": 1.0, "pix2pixhd+3dgs": 2.0}
    files = _rows(tmp_path, offsets, {"pix2pixhd+3dgs": {"frames": 16}})
    out = write_findings(files, tmp_path / "findings", NERF, rivals=_listed("pix2pixhd+3dgs"))
    spad = _by_id(out)["spad-two-stage"]
    assert spad["verdict"] == "NOT RUN" and spad["note"] == "no row of equal budget in this run"
    assert spad["unequal_budget"] == [["bernoulli+3dgs", "pix2pixhd+3dgs"]]
    files.append(_record(tmp_path, "bernoulli+3dgs", "extra", 0, 20.0, frames=4))
    with pytest.raises(ValueError, match=r"'bernoulli\+3dgs' has budget \(K, S\) = \(4, 1\)"):
        write_findings(files, tmp_path / "again", NERF)


def test_published_block_and_the_prior_table(tmp_path):
    offsets = {f"pix2pixhd-pub+{NERF}": 2.0, "pix2pixhd-pub+3dgs": 1.0, "diffusion-pub+3dgs": 0.0}
    offsets |= {"pix2pixhd+3dgs": 1.5, "prior+3dgs": 1.0, f"prior+{NERF}": 0.5}
    files = _rows(tmp_path, offsets)
    stage1 = []
    for i, (scene, seed) in enumerate((s, k) for s in SCENES for k in SEEDS):
        for source, psnr in (("pix2pixhd", 21.0 + 0.1 * i), ("pix2pixhd-pub", 19.0)):
            rec = {"scene": scene, "source": source, "seed": seed, "frames": 1, "mean": {"psnr": psnr}}
            if source == "pix2pixhd":  # the prior travels with the residual translator's record
                rec["prior"] = {"sigma": 1.0, "mean": {"psnr": 20.0}}
            stage1.append(str(tmp_path / f"s1-{source}-{scene}-{seed}.json"))
            io.write_json(stage1[-1], rec)
    out = write_findings(files, tmp_path / "findings", NERF, stage1_files=stage1)
    claims = _by_id(out)
    assert "published networks" in claims["best-nerf"]["claim"]
    denoisers = claims["denoisers"]  # its listed rows that did not run are named, none silently dropped
    assert denoisers["verdict"] == "NOT RUN" and denoisers["comparisons"] == []
    assert denoisers["not_run"] == [f"diffusion-pub+{NERF}", "restormer-pub+3dgs", f"restormer-pub+{NERF}"]
    prior = {(r["translator"], r["stage"]): r for r in out["over_prior"]}
    assert set(prior) == {
        ("pix2pixhd", "stage 1"),
        ("pix2pixhd", "3dgs"),
        ("pix2pixhd-pub", "stage 1"),
        ("pix2pixhd-pub", "3dgs"),
        ("pix2pixhd-pub", NERF),
        ("diffusion-pub", "3dgs"),
    }
    assert prior["pix2pixhd-pub", "stage 1"]["decisive"]["mean"] == pytest.approx(-1.0)
    assert prior["pix2pixhd-pub", "stage 1"]["verdict"] == "DOES NOT HOLD"
    assert prior["pix2pixhd", "stage 1"]["verdict"] == "HOLDS" and prior["pix2pixhd", "3dgs"]["m"] == 1
    # ±0.05 dB of noise around 0: within ±δ (EQUIVALENT); without δ nothing can be said (INCONCLUSIVE)
    assert prior["pix2pixhd-pub", "3dgs"]["verdict"] == "EQUIVALENT"
    assert prior["pix2pixhd-pub", "3dgs"]["family"] == "equivalent"
    zero = _at_zero_margin(files, tmp_path / "zero", stage1_files=stage1)
    assert {r["id"]: r["verdict"] for r in zero["over_prior"]}["over-prior:pix2pixhd-pub:3dgs"] == "INCONCLUSIVE"
    md = (tmp_path / "findings.md").read_text()
    assert "## Δ over the baselines\n\n### Δ over the untrained prior (`prior`)" in md
    assert "| pix2pixhd-pub | published networks | stage 1 | **DOES NOT HOLD** | -1.00 |" in md
    assert "No other stage-1 method ran beside the `classical` rows in this run." in md
    assert out["over_classical"] == []


def test_the_classical_baseline(tmp_path):
    """Every translator over ``classical`` and ``classical`` over ``prior``, at stage 1 and per model;
    ``classical`` is a baseline, not a translator of the claims."""
    offsets = {"pix2pixhd+3dgs": 2.0, "classical+3dgs": 1.0, "prior+3dgs": 0.0, f"classical+{NERF}": 0.5}
    offsets |= {f"prior+{NERF}": 0.4, "restormer+3dgs": 1.05}
    files = _rows(tmp_path, offsets)
    stage1 = []
    for scene, seed in ((s, k) for s in SCENES for k in SEEDS):
        for source, psnr in (("pix2pixhd", 22.0), ("classical", 21.0), ("prior", 20.0)):
            stage1.append(str(tmp_path / f"s1-{source}-{scene}-{seed}.json"))
            io.write_json(
                stage1[-1], {"scene": scene, "source": source, "seed": seed, "frames": 1, "mean": {"psnr": psnr}}
            )
    out = write_findings(files, tmp_path / "findings", NERF, stage1_files=stage1)
    over = {(r["baseline"], r["translator"], r["stage"]): r for r in out["over_prior"] + out["over_classical"]}
    assert set(over) == {
        ("prior", "pix2pixhd", "stage 1"),
        ("prior", "pix2pixhd", "3dgs"),
        ("prior", "restormer", "3dgs"),
        ("prior", "classical", "stage 1"),
        ("prior", "classical", "3dgs"),
        ("prior", "classical", NERF),
        ("classical", "pix2pixhd", "stage 1"),
        ("classical", "pix2pixhd", "3dgs"),
        ("classical", "restormer", "3dgs"),
    }
    assert all(r["baseline"] == "prior" for r in out["over_prior"])  # tools read over_prior as before
    assert over["prior", "classical", "3dgs"]["block"] == "non-learned"
    assert over["prior", "classical", "3dgs"]["id"] == "over-prior:classical:3dgs"
    assert over["classical", "pix2pixhd", "3dgs"]["verdict"] == "HOLDS"  # +1 dB
    assert over["classical", "restormer", "3dgs"]["verdict"] == "EQUIVALENT"  # +0.05 dB
    assert over["prior", "classical", NERF]["verdict"] == "EQUIVALENT"  # +0.1 dB: under δ
    assert over["prior", "classical", "stage 1"]["verdict"] == "HOLDS"
    claims = _by_id(out)
    assert "classical" not in str(claims["best-3dgs"]) and "classical" not in str(claims["spad-two-stage"])
    md = (tmp_path / "findings.md").read_text()
    assert "### Δ over the classical method (`classical`)" in md
    assert (
        "| classical | non-learned | nerf-grid | **EQUIVALENT** | +0.10 | [+0.04, +0.14] | 0.016 (H0: Δ ∉ (−δ, δ)) |"
        in md
    )
    html = (tmp_path / "findings.html").read_text()
    assert "<h4>Δ over the classical method (classical)</h4>" in html


def test_the_three_files_are_written(tmp_path):
    files = _rows(tmp_path, {"bernoulli+3dgs": 1.0, "mle-x1+3dgs": 0.0})
    files.append(_record(tmp_path, "bernoulli+3dgs", "capture", 0, None, reference=False))
    out = write_findings(files, tmp_path / "findings", NERF, rivals=_listed(mle=("mle-x1+3dgs",)))
    assert io.read_json(tmp_path / "findings.json") == json.loads(json.dumps(out))
    assert out["min_scenes"] == 6 and out["unit"].startswith("scene")
    md = (tmp_path / "findings.md").read_text()
    assert md.startswith(
        "# Findings\n\nBase: 6 scenes, 12 runs "
        "(courtyard, gallery, harbour, observatory, orchard, tabletop × seeds 0, 1);"
    )
    assert "descriptive only" not in md.splitlines()[2]
    assert "| claim | by | verdict | decisive comparison | Δ PSNR (dB) | 95 % interval (or range) | adjusted p |" in md
    html = (tmp_path / "findings.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "<b>HOLDS</b>" in html and "Δ over the untrained prior" in html


def test_the_smallest_effect_is_stated_everywhere(tmp_path):
    files, listed = _rows(tmp_path, {"bernoulli+3dgs": 1.0, "mle-x1+3dgs": 0.0}), _listed(mle=("mle-x1+3dgs",))
    out = write_findings(files, tmp_path / "findings", NERF, rivals=listed)
    assert out["smallest_effect_db"] == 0.25 and io.read_json(tmp_path / "findings.json")["smallest_effect_db"] == 0.25
    md = (tmp_path / "findings.md").read_text()
    first, legend = md.splitlines()[2], md.split("\n\n")[3]
    assert "δ = 0.25 dB" in first and legend.startswith("δ = 0.25 dB, the smallest effect of interest.")
    assert "| **HOLDS** | bernoulli+3dgs vs mle-x1+3dgs | +0.99 | [+0.95, +1.02] | 0.016 (H0: Δ ≤ δ) | 6 | 1 |" in md
    html = (tmp_path / "findings.html").read_text()
    assert html.count("δ = 0.25 dB") == 2  # the opening line and the legend
    out = write_findings(files, tmp_path / "wide", NERF, smallest_effect=1.5, rivals=listed)  # +1 dB: within ±1.5
    assert "δ = 1.5 dB" in (tmp_path / "wide.md").read_text() and out["smallest_effect_db"] == 1.5
    assert _by_id(out)["spad-mle"]["verdict"] == "EQUIVALENT"
    with pytest.raises(ValueError, match="smallest_effect"):
        write_findings(files, tmp_path / "bad", NERF, smallest_effect=-0.25)


# --- two findings runs compared (spc3d.evaluation.shift) ------------------------------------------


def _findings_run(folder, offsets: dict[str, float], seed_noise: int = 0):
    """A results/ folder as the findings preset leaves it: eval/{scene}/{row}{-seedK}/metrics.json
    on the 12 runs of 6 scenes (one base PSNR per run, shared by both compared runs) and tables/findings.json."""
    runs = [(s, k) for s in SCENES for k in SEEDS]
    base = dict(zip(runs, np.random.default_rng(0).uniform(18, 24, len(runs))))
    rng, files = np.random.default_rng(seed_noise), []
    for combo, offset in offsets.items():
        for (scene, seed), b in base.items():
            rep = f"-seed{seed}" if seed else ""
            path = folder / "eval" / scene / f"{combo}{rep}" / "metrics.json"
            psnr = b + offset + rng.uniform(-0.05, 0.05)
            io.write_json(
                path, {"combination": combo, "scene": scene, "seed": seed, "frames": 1, "mean": {"psnr": psnr}}
            )
            files.append(str(path))
    write_findings(files, folder / "tables" / "findings", NERF)
    return folder


def test_shift_of_a_run_against_itself_is_nil(tmp_path):
    from spc3d.evaluation.shift import write_shift

    run = _findings_run(tmp_path / "a", {f"pix2pixhd+{NERF}": 3.0, f"none-x1+{NERF}": -4.0})
    text = write_shift(run, run, names=("x", "x"))
    assert "Old: x; new: x. Of 9 claims and Δ-over-baseline entries, 0 changed verdict and 0 moved" in text
    assert "| two-stage-nerf" not in text and f"pix2pixhd+{NERF} vs none-x1+{NERF} | HOLDS | HOLDS |" in text
    assert f"| pix2pixhd+{NERF} | 6 | +0.00 | [+0.00, +0.00] | 1.000 |" in text
    assert (run / "tables" / "findings_shift.md").read_text() == text


def test_shift_finds_a_moved_row_and_a_flipped_claim(tmp_path):
    from spc3d.evaluation.shift import claim_shifts, read_run, row_shifts

    old = _findings_run(tmp_path / "old", {f"pix2pixhd+{NERF}": 3.0, f"none-x1+{NERF}": -4.0, "prior+3dgs": 0.0})
    new = _findings_run(tmp_path / "new", {f"pix2pixhd+{NERF}": -5.0, f"none-x1+{NERF}": -4.0, "prior+3dgs": 0.0}, 1)
    (old_rows, old_f), (new_rows, new_f) = read_run(old), read_run(new)
    rows = {r["row"]: r for r in row_shifts(old_rows, new_rows)}
    moved, still = rows[f"pix2pixhd+{NERF}"], rows[f"none-x1+{NERF}"]
    assert moved["n"] == 6 and moved["mean"] == pytest.approx(-8.0, abs=0.1) and moved["high"] < -7.8
    assert moved["p"] == 2 / 64 and still["low"] < 0 < still["high"] and still["p"] > 0.05
    shifts = {c["id"]: c for c in claim_shifts(old_f, new_f)}
    claim = shifts["two-stage-nerf"]
    assert shifts["denoisers"]["new"] == "NOT RUN" and shifts["denoisers"]["beyond"] is None
    assert (claim["old"], claim["new"]) == ("HOLDS", "DOES NOT HOLD")
    assert claim["beyond"] is True and claim["old_d"]["mean"] == pytest.approx(7.0, abs=0.1)
    assert claim["new_d"]["mean"] == pytest.approx(-1.0, abs=0.1)


def test_shift_names_a_folder_without_findings(tmp_path):
    from spc3d.evaluation.shift import read_run

    with pytest.raises(FileNotFoundError, match=r"tables/findings.json: no findings table; pass the results/"):
        read_run(tmp_path)


# --- the test's machinery, for its mutants -------------------------------------------------------


def test_rows_pair_on_the_scenes_both_scored_only():
    a = Row((1, 1), {("s1", 0): 20.0, ("s2", 0): 21.0, ("s3", 0): 22.0})
    b = Row((1, 1), {("s2", 0): 20.0, ("s3", 0): 20.5, ("s4", 0): 19.0})
    assert paired(a, b).tolist() == [1.0, 1.5]


def test_the_exact_test_enumerates_up_to_sixteen_scenes():
    """At n = 16, the largest exact n, p is a count over the 2^15 patterns with a first sign +,
    computed here by brute force; at n = 17 the Monte-Carlo p is (1 + count) / (1 + N_RANDOM)."""
    d = np.array([0.9, -0.3, 1.1, 0.4, -0.8, 0.6, 0.2, 1.3, -0.1, 0.7, 0.5, -0.4, 0.8, 0.3, -0.6, 1.0])
    bits = (np.arange(2**15)[:, None] >> np.arange(15)) & 1
    signs = np.hstack([np.ones((2**15, 1)), 1.0 - 2.0 * bits])
    observed = abs(d.mean()) - 1e-9 * np.abs(d).mean()
    expected = float((np.abs(signs @ d) / 16 >= observed).sum()) / 2**15
    assert sign_flip_p(d) == expected
    p17 = sign_flip_p(np.append(d, 0.5))
    assert (p17 * (1 + N_RANDOM) - 1) == pytest.approx(round(p17 * (1 + N_RANDOM) - 1), abs=1e-6)


def test_tests_take_any_batch_shape_and_refuse_empty_or_scalar_input_by_name():
    rng = np.random.default_rng(0)
    d = rng.normal(0.3, 1.0, (2, 3, 7))
    p = sign_flip_p(d)
    assert p.shape == (2, 3) and p[1, 2] == sign_flip_p(d[1, 2])
    above, below = one_sided_p(d), one_sided_p(d, greater=False)
    assert above.shape == below.shape == (2, 3) and above[0, 1] == one_sided_p(d[0, 1])
    for bad, shape in ((np.array([]), r"\(0,\)"), (3.0, r"\(\)")):
        message = rf"^sign_flip_p: need ≥ 1 finite paired difference per test, got shape {shape}$"
        with pytest.raises(ValueError, match=message):
            sign_flip_p(bad)
        with pytest.raises(ValueError, match=r"^one-sided sign-flip p: need ≥ 1 finite paired difference"):
            one_sided_p(bad)


def test_the_cached_sign_patterns_cannot_be_changed_by_a_caller():
    from spc3d.evaluation.findings import _patterns

    with pytest.raises(ValueError, match="read-only"):
        _patterns(5)[0, 0] = -1.0


def test_the_smallest_p_is_one_pattern_of_all_exact_or_of_the_monte_carlo_draws():
    assert smallest_p(16) == 2 / 2**16 and smallest_p(16, one_sided=True) == 1 / 2**16  # exact up to 16
    assert smallest_p(17) == 1 / (1 + N_RANDOM) and smallest_p(17, one_sided=True) == 1 / (2 + 2 * N_RANDOM)


def test_needed_scenes_is_the_fewest_that_can_reach_the_level():
    assert needed_scenes(1, alpha=1.0) == 1  # one scene: one-sided p 1/2 <= 1/2
    assert needed_scenes(1, alpha=2 / 64) == 6  # 1/2^6 reaches (alpha / 2) / m exactly: enough
    assert needed_scenes(4) == 8 and needed_scenes(1) == MIN_SCENES


@pytest.mark.parametrize("n", [16, 17])
def test_one_sided_p_counts_patterns_and_mirrors_exactly_or_by_monte_carlo(n):
    """Both one-sided p of a mixed-sign sample against a brute-force count over the test's own sign
    patterns and their mirrors: a fraction at n = 16, (1 + count) / (2 + 2B) above it."""
    from spc3d.evaluation.findings import _patterns

    d = np.resize([0.9, -0.3, 1.1, 0.4, -0.8, 0.6, 0.2, 1.3, -0.1, 0.7, 0.5, -0.4, 0.8, 0.3, -0.6, 1.0, 0.45], n)
    signs = _patterns(n)
    means = signs @ d / n
    obs, tol = d.mean(), 1e-9 * np.abs(d).mean()
    above = (means >= obs - tol).sum() + (means <= -(obs - tol)).sum()
    below = (means <= obs + tol).sum() + (means >= -(obs + tol)).sum()
    total = 2 * len(signs)
    if n <= 16:
        expected = above / total, below / total
    else:
        expected = (1 + above) / (2 + total), (1 + below) / (2 + total)
    assert (one_sided_p(d), one_sided_p(d, greater=False)) == pytest.approx(expected, rel=1e-12)


def test_effect_p_refuses_a_negative_or_infinite_smallest_effect_by_name():
    for bad in (-0.1, math.inf):
        with pytest.raises(ValueError, match=r"^effect_p: the smallest effect of interest must be finite and ≥ 0"):
            effect_p(np.ones(6), bad)


# --- boundaries, precision and the decisive comparison ------------------------------------------------


def test_interval_ends_lie_at_the_inverted_test_boundary_to_the_bisection_tolerance_at_any_scale():
    """An end is accepted (p > alpha) and a shift beyond it by twice the stated resolution
    (BISECT_RTOL x the range) is rejected; the ends scale with the differences."""
    from spc3d.evaluation.findings import ALPHA, BISECT_RTOL

    d = np.array([0.9, -0.2, 1.4, 0.3, 0.8, -0.5, 1.1, 0.6, 0.2])
    base = np.array(interval(d))
    for scale in (1e-3, 1.0, 1e3):
        x = d * scale
        lo, hi = interval(x)
        step = 2 * BISECT_RTOL * (x.max() - x.min())
        assert sign_flip_p(x - lo) > ALPHA and sign_flip_p(x - (lo - step)) <= ALPHA
        assert sign_flip_p(x - hi) > ALPHA and sign_flip_p(x - (hi + step)) <= ALPHA
        np.testing.assert_allclose((lo, hi), base * scale, atol=step)


def test_at_an_alpha_the_test_can_reach_exactly_an_end_is_still_found():
    """alpha = 1/32, the smallest two-sided p of six scenes: the interval is bounded and its ends
    are the inverted test's (p exactly alpha rejects)."""
    alpha = 2 / 2**6
    six = np.array([0.4, 1.9, 0.7, 2.5, 1.1, 0.2])
    lo, hi = interval(six, alpha=alpha)
    assert math.isfinite(lo) and math.isfinite(hi)
    assert sign_flip_p(six - lo) > alpha and sign_flip_p(six - hi) > alpha
    mixed = np.array([0.4, 1.9, -0.7, 2.5, 1.1, 0.2])
    lo, hi = interval(mixed, alpha=alpha)
    assert sign_flip_p(mixed - lo) > alpha and sign_flip_p(mixed - hi) > alpha


def test_holm_never_exceeds_one_and_a_verdict_at_exactly_the_level_rejects():
    assert holm([0.7, 0.9]).tolist() == [1.0, 1.0]
    assert verdict([0.025], [1.0], [1.0], 6) == "HOLDS"  # p ≤ alpha / 2 rejects
    assert verdict([1.0], [0.025], [0.3], 6) == "DOES NOT HOLD"
    assert verdict([1.0], [0.025], [0.025], 6) == "EQUIVALENT"
    assert (
        verdict([[0.005], [1.0], [0.5]], [[1.0]] * 3, [[1.0]] * 3, MIN_SCENES - 1).tolist() == ["DESCRIPTIVE ONLY"] * 3
    )


def test_a_comparison_without_paired_scenes_is_empty_and_one_below_six_shows_its_range():
    from dataclasses import asdict

    from spc3d.evaluation.findings import compare

    rows = {"a": Row((1, 1), {("s1", 0): 21.0}), "b": Row((1, 1), {("s2", 0): 20.0})}
    ones = dict.fromkeys(("p", "p_holds", "p_short", "p_low", "adj_holds", "adj_short", "adj_equivalent"), 1.0)
    assert asdict(compare(rows, "a", "b")) == {
        "better": "a", "worse": "b", "n": 0, "mean": None, "low": None, "high": None, "bounds": "range"
    } | ones  # fmt: skip
    rows = {
        "a": Row((1, 1), {(s, 0): 21.0 + i for i, s in enumerate("xyz")}),
        "b": Row((1, 1), {(s, 0): 20.0 for s in "xyz"}),
    }
    three = compare(rows, "a", "b")
    assert (three.n, three.low, three.high, three.bounds) == (3, 1.0, 3.0, "range")


def _comparison(name: str, mean, adj_holds=1.0, adj_short=1.0, adj_equivalent=1.0):
    from spc3d.evaluation.findings import Comparison

    n = 0 if mean is None else 6
    return Comparison(name, "base", n, mean, adj_holds=adj_holds, adj_short=adj_short, adj_equivalent=adj_equivalent)


def test_the_decisive_comparison_of_a_failure_is_the_strongest_failing_one():
    from spc3d.evaluation.findings import decisive

    not_equal = _comparison("not-equal", 0.1, adj_short=0.02, adj_equivalent=0.5)
    equal = _comparison("equal", 0.0, adj_short=0.005, adj_equivalent=0.025)  # within ±δ at exactly the level
    edge = _comparison("edge", 0.05, adj_short=0.025, adj_equivalent=0.9)  # fails at exactly the level
    passing = _comparison("passing", -1.0, adj_short=0.03)
    unscored = _comparison("unscored", None, adj_short=0.0)
    comps = [passing, not_equal, unscored, equal, edge]
    assert decisive(comps, "EQUIVALENT").better == "equal"  # smallest adjusted p_short
    assert decisive(comps, "DOES NOT HOLD").better == "not-equal"  # among those not equivalent
    tied = [_comparison("later", 0.3, adj_short=0.01), _comparison("closer", 0.1, adj_short=0.01)]
    assert decisive(tied, "EQUIVALENT").better == "closer"  # a tie: the smaller mean


def test_the_decisive_comparison_of_a_descriptive_or_undecided_claim():
    from spc3d.evaluation.findings import DESCRIPTIVE, decisive

    comps = [_comparison("far", 0.5), _comparison("zero", 0.0), _comparison("unscored", None)]
    assert decisive(comps, DESCRIPTIVE).better == "zero"  # the closest of the scored
    assert decisive([_comparison("none", None), _comparison("also", None)], DESCRIPTIVE).better == "none"
    held = [_comparison("clear", 2.0, adj_holds=0.001), _comparison("weakest", 0.4, adj_holds=0.02)]
    assert decisive(held, "HOLDS").better == "weakest"  # the largest adjusted p_holds
    tied = [_comparison("larger", 0.9, adj_holds=0.2), _comparison("smaller", 0.3, adj_holds=0.2)]
    assert decisive(tied, "INCONCLUSIVE").better == "smaller"  # a tie: the smaller mean


def _claim_rows(scenes: int, offsets: dict[str, list[float]]) -> dict:
    names = [f"s{i}" for i in range(scenes)]
    rows = {"base": Row((1, 1), {(s, 0): 20.0 for s in names})}
    for name, values in offsets.items():
        rows[name] = Row((1, 1), {(s, 0): 20.0 + v for s, v in zip(names, values)})
    return rows


def test_a_claim_with_a_row_not_run_is_recorded_as_such():
    from spc3d.evaluation.findings import NOT_RUN, Claim, decide

    claim = Claim("c", "ours", "a beats base", (("a", "base"), ("missing", "base")))
    out = decide(claim, _claim_rows(6, {"a": [1.0] * 6}))
    assert (out["verdict"], out["n"], out["family"], out["decisive"], out["comparisons"]) == (
        NOT_RUN,
        0,
        None,
        None,
        [],
    )
    assert out["note"] == "not run: missing" and out["not_run"] == ["missing"]


def test_an_undecided_claim_names_the_scenes_a_failure_would_need_only_below_them():
    """Two comparisons: a failure needs n ≥ 7 (Holm at 0.025 / 2); at n = 7 nothing is missing."""
    from spc3d.evaluation.findings import Claim, decide

    noisy = [0.9, -0.6, 0.4, 1.2, -0.3, 0.5, 0.1]
    claim = Claim("c", "ours", "a and b beat base", (("a", "base"), ("b", "base")))
    six = decide(claim, _claim_rows(6, {"a": noisy[:6], "b": noisy[:6]}))
    assert six["verdict"] == "INCONCLUSIVE" and six["note"] == "a failure among 2 comparisons needs n ≥ 7 scenes"
    seven = decide(claim, _claim_rows(7, {"a": noisy, "b": noisy}))
    assert seven["verdict"] == "INCONCLUSIVE" and seven["note"] == ""


def test_a_shift_whose_p_is_exactly_alpha_is_rejected_at_an_interval_end():
    """alpha = 1/16: at the minimum of six positive differences p is exactly 2 of 32 patterns, so
    the minimum is rejected and the end lies inside it, where p > alpha."""
    alpha = 4 / 2**6
    six = np.array([0.4, 1.9, 0.7, 2.5, 1.1, 0.2])
    assert sign_flip_p(six - six.min()) == alpha
    lo, hi = interval(six, alpha=alpha)
    assert six.min() < lo and sign_flip_p(six - lo) > alpha
    assert hi < six.max() and sign_flip_p(six - hi) > alpha


def test_the_decisive_failure_may_fail_at_exactly_the_level_or_be_far_from_equivalent():
    from spc3d.evaluation.findings import decisive

    edge = _comparison("edge", 0.05, adj_short=0.025, adj_equivalent=0.9)
    assert decisive([edge, _comparison("passing", -1.0, adj_short=0.3)], "DOES NOT HOLD").better == "edge"
    unequal = _comparison("unequal", 0.1, adj_short=0.01, adj_equivalent=0.05)
    assert decisive([unequal], "DOES NOT HOLD").better == "unequal"

"""The findings: claims decided on paired runs by the exact sign-flip test, Holm over a claim's
comparisons, DESCRIPTIVE ONLY below MIN_RUNS, equal budgets only (cross-budget claims labelled)."""

import json
import math

import numpy as np
import pytest

from spc3d import io
from spc3d.evaluation.findings import (
    MIN_RUNS,
    N_RANDOM,
    holm,
    interval,
    needed_runs,
    sign_flip_p,
    verdict,
    write_findings,
)

NERF = "nerf-grid"
SCENES, SEEDS = ("courtyard", "tabletop"), (0, 1, 2)  # 6 runs: the smallest n that can reach a verdict


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


def test_holm_against_a_hand_computation():
    p = [0.01, 0.04, 0.03, 0.005]
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 = 0.02, 0.03, 0.06, 0.04; made monotone: 0.06 for the last
    assert holm(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm([[0.5, 0.6], [0.01, 0.02]]), [[1.0, 1.0], [0.02, 0.02]])  # capped at 1, per row
    assert [needed_runs(m) for m in (1, 2, 4, 8)] == [6, 7, 8, 9]  # 2 / 2^N ≤ 0.05 / m


def test_verdict_rules():
    assert verdict([1.0, 2.0], [0.01, 0.03], 6) == "HOLDS"
    assert verdict([1.0, 2.0], [0.01, 0.3], 6) == "INCONCLUSIVE"
    assert verdict([1.0, -2.0], [0.3, 0.03], 6) == "DOES NOT HOLD"
    assert verdict([1.0], [0.01], MIN_RUNS - 1) == "DESCRIPTIVE ONLY"


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


def _rejection_rate(d: np.ndarray) -> float:
    """Fraction of replicates (rows) whose one-comparison claim gets a verdict (HOLDS or DOES NOT HOLD)."""
    p = sign_flip_p(d)[:, None]
    v = verdict(d.mean(axis=1)[:, None], holm(p), d.shape[1])
    return float(np.isin(v, ["HOLDS", "DOES NOT HOLD"]).mean())


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
            if n < MIN_RUNS:
                assert all(rate[name, n, s] == 0.0 for s in SHIFTS), (name, n)  # descriptive: never a verdict
        assert rate[name, 10, 0.5] <= rate[name, 10, 1.0] + 0.02 <= rate[name, 10, 2.0] + 0.04, name
        assert rate[name, 10, 2.0] > rate[name, 10, 0.5], name  # power rises with the shift
        assert rate[name, 10, 1.0] > rate[name, 6, 1.0], name  # and with the runs
    assert rate["normal", 10, 1.5] > 0.5


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


def _by_id(results: dict) -> dict:
    return {r["id"]: r for r in results["claims"]}


def test_one_run_is_descriptive_only(tmp_path):
    files = [
        _record(tmp_path, f"pix2pixhd+{NERF}", "courtyard", 0, 22.0),
        _record(tmp_path, "pix2pixhd+3dgs", "courtyard", 0, 21.0),
        _record(tmp_path, f"none-x1+{NERF}", "courtyard", 0, 15.0),
    ]
    out = write_findings(files, tmp_path / "findings", NERF)
    claims = _by_id(out)
    assert claims["best-nerf"]["verdict"] == "DESCRIPTIVE ONLY" and claims["best-nerf"]["n"] == 1
    assert claims["two-stage-nerf"]["decisive"]["low"] == claims["two-stage-nerf"]["decisive"]["high"] == 7.0
    assert claims["denoisers"]["verdict"] == "NOT RUN" and claims["denoisers"]["note"] == "rows not in this run"
    md = (tmp_path / "findings.md").read_text()
    line = md.splitlines()[2]
    assert line.startswith("Base: 1 run (courtyard × seed 0)") and "sign-flip" in line and "MIN_RUNS = 6" in line
    assert line.endswith(
        "This run is descriptive only: n = 1 run (courtyard × seed 0); a verdict needs ≥ 6 paired runs "
        "(workflow/presets/findings.yaml)."
    )
    assert (
        "| **DESCRIPTIVE ONLY** | pix2pixhd+nerf-grid vs pix2pixhd+3dgs | +1.00 | range [+1.00, +1.00] | – | 1 | 1 |"
        in md
    )


def test_verdicts_on_six_paired_runs_with_holm(tmp_path):
    offsets = {f"pix2pixhd+{NERF}": 3.0, "pix2pixhd+3dgs": 2.0, f"none-x1+{NERF}": -4.0, "restormer+3dgs": 2.5}
    offsets |= {"bernoulli+3dgs": 1.0, "gt+3dgs": 10.0}
    claims = _by_id(write_findings(_rows(tmp_path, offsets), tmp_path / "findings", NERF))
    assert claims["two-stage-nerf"]["verdict"] == "HOLDS" and claims["two-stage-nerf"]["n"] == 6
    assert claims["two-stage-nerf"]["decisive"]["adjusted"] == 2 / 64
    assert claims["two-stage-nerf"]["decisive"]["low"] == pytest.approx(7.0, abs=0.1)  # [min, max] of the runs
    best = claims["best-nerf"]  # m = 2 at n = 6: Holm needs p ≤ 0.025, the smallest p is 0.031
    assert best["m"] == 2 and best["verdict"] == "INCONCLUSIVE" and best["note"] == "needs n ≥ 7 for 2 comparisons"
    assert claims["best-3dgs"]["verdict"] == "DOES NOT HOLD"  # restormer + 3DGS is better
    assert claims["best-3dgs"]["decisive"]["worse"] == "restormer+3dgs"
    assert "gt+3dgs" not in str(claims)
    assert "residual networks" in claims["best-nerf"]["claim"]


def test_equal_budgets_only_and_cross_budget_claims_labelled(tmp_path):
    offsets = {"bernoulli+3dgs": 1.0, "mle-x1+3dgs": 0.0, "mle-x1-mse+3dgs": -0.5, "mle+3dgs": 3.0}
    offsets |= {"mle-k16+3dgs": 9.0, "pix2pixhd+3dgs": 2.0, "none+3dgs": -1.0, "none-x1-mse+3dgs": -6.0}
    offsets |= {"prior+3dgs": 0.5, "bernoulli+3dgs@mle-k16": 5.0}
    budgets = {"mle+3dgs": {"capture_factor": 4}, "none+3dgs": {"capture_factor": 4}, "mle-k16+3dgs": {"frames": 16}}
    claims = _by_id(write_findings(_rows(tmp_path, offsets, budgets), tmp_path / "findings", NERF))
    spad_mle = claims["spad-mle"]
    assert [c["worse"] for c in spad_mle["comparisons"]] == ["mle-x1+3dgs", "mle-x1-mse+3dgs"]
    assert "(vs mle-x1+3dgs, mle-x1-mse+3dgs)" in spad_mle["claim"]
    assert spad_mle["verdict"] == "INCONCLUSIVE" and spad_mle["note"] == "needs n ≥ 7 for 2 comparisons"
    assert "mle-k16" not in str(claims) and "mle+3dgs" not in str(claims) and "@" not in str(claims)
    faithful = claims["two-stage-3dgs-faithful"]
    assert faithful["cross_budget"] and faithful["m"] == 1 and faithful["verdict"] == "HOLDS"
    assert "cross-budget: none: 1 frame at 4×4 sensor pixels per image pixel vs 1 frame at 1×" in faithful["claim"]
    assert claims["two-stage-3dgs"]["decisive"]["worse"] == "none-x1-mse+3dgs"
    spad = claims["spad-two-stage"]  # pix2pixhd is better than the SPAD likelihood here; the prior is not
    assert {c["worse"] for c in spad["comparisons"]} == {"pix2pixhd+3dgs", "prior+3dgs"}
    assert spad["verdict"] == "INCONCLUSIVE" and spad["note"] == "needs n ≥ 7 for 2 comparisons"


def test_unequal_budget_pairs_are_set_aside_and_mixed_budgets_refused(tmp_path):
    offsets = {"bernoulli+3dgs": 1.0, "pix2pixhd+3dgs": 2.0}
    files = _rows(tmp_path, offsets, {"pix2pixhd+3dgs": {"frames": 16}})
    spad = _by_id(write_findings(files, tmp_path / "findings", NERF))["spad-two-stage"]
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
    assert [c["worse"] for c in claims["denoisers"]["comparisons"]] == ["diffusion-pub+3dgs"]
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
    assert prior["pix2pixhd-pub", "3dgs"]["verdict"] == "INCONCLUSIVE"  # ±0.05 dB of noise around 0
    md = (tmp_path / "findings.md").read_text()
    assert "## Δ over the untrained prior" in md
    assert "| pix2pixhd-pub | published networks | stage 1 | **DOES NOT HOLD** | -1.00 |" in md


def test_the_three_files_are_written(tmp_path):
    files = _rows(tmp_path, {"bernoulli+3dgs": 1.0, "mle-x1+3dgs": 0.0})
    files.append(_record(tmp_path, "bernoulli+3dgs", "capture", 0, None, reference=False))
    out = write_findings(files, tmp_path / "findings", NERF)
    assert io.read_json(tmp_path / "findings.json") == json.loads(json.dumps(out))
    md = (tmp_path / "findings.md").read_text()
    assert md.startswith("# Findings\n\nBase: 6 runs (courtyard, tabletop × seeds 0, 1, 2);")
    assert "descriptive only" not in md.splitlines()[2]
    assert "| claim | by | verdict | decisive comparison | Δ PSNR (dB) | 95 % interval (or range) | Holm p |" in md
    html = (tmp_path / "findings.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "<b>HOLDS</b>" in html and "Δ over the untrained prior" in html


# --- two findings runs compared (spc3d.evaluation.shift) ------------------------------------------


def _findings_run(folder, offsets: dict[str, float], seed_noise: int = 0):
    """A results/ folder as the findings preset leaves it: eval/{scene}/{row}{-seedK}/metrics.json
    on the 6 runs (one base PSNR per run, shared by both compared runs) and tables/findings.json."""
    base = dict(zip([(s, k) for s in SCENES for k in SEEDS], np.random.default_rng(0).uniform(18, 24, 6)))
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
    assert "Old: x; new: x. Of 9 claims and Δ-over-prior entries, 0 changed verdict and 0 moved" in text
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

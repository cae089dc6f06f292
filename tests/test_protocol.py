"""The evaluation protocol: no row but the oracle reads the evaluation scene's ground truth, the
physics rows' display gain is metered from their own frames, and claims carry bootstrap intervals."""

import numpy as np
import pytest

from spc3d import exposure, io, spc
from spc3d.augment import AugmentSettings, augment_scene
from spc3d.findings import Comparison, bootstrap, evaluate_claims, per_view, verdict, write_findings
from spc3d.scenes import write_builtin_scene
from spc3d.inputs import simulate_scene
from spc3d.stage2 import reconstruct
from spc3d.translate.apply import translate_scene
from spc3d.translate.train import train_translator

TINY_3DGS = {"iterations": 8, "densify_from": 4, "densify_until": 6, "densify_every": 2, "init_points": 200}
TINY_PIX2PIX = {"ngf": 8, "ndf": 8, "num_downs": 3, "n_layers_D": 2}


# --- the metered display --------------------------------------------------------------------------


def test_metered_display_is_exposure_invariant_and_the_fit_finds_the_known_level():
    rng = np.random.default_rng(0)
    linear = [rng.uniform(0.0, 0.5, (2, 6, 8, 3)), rng.uniform(0.0, 0.5, (2, 6, 8, 3))]
    linear[1] *= linear[0].mean() / linear[1].mean()  # both scenes: the same mean linear level
    gts = [spc.linear_to_srgb(x) for x in linear]
    phis = [3e4 * linear[0], 7e5 * linear[1]]  # two exposures, unknown to the rule
    level, per_scene = exposure.fit_level(phis, gts)
    assert level == pytest.approx(linear[0].mean(), rel=1e-5)
    assert per_scene == pytest.approx([linear[0].mean()] * 2, rel=1e-5)
    shown = exposure.display_srgb(phis[1], exposure.metered_gain(phis[1], level))
    assert np.abs(shown - gts[1]).max() < 1e-5  # the exact image back, without knowing 7e5
    brighter = 10 * phis[1]
    assert np.array_equal(exposure.display_srgb(brighter, exposure.metered_gain(brighter, level)), shown)
    assert exposure.metered_gain(np.zeros((2, 2)), level) == 1.0  # no detection at all: finite, no NaN
    # Metering on a biased estimate (half the flux) while showing the true flux: the level absorbs the bias.
    biased, _ = exposure.fit_level([0.5 * p for p in phis], gts, shown=phis)
    assert biased == pytest.approx(linear[0].mean() / 2, rel=1e-5)


# --- no oracle information outside oracle rows ----------------------------------------------------


def _products(root, out):
    """Every non-oracle product of the evaluation scene: metered MLE images, translated images (and
    the translator's physics prior alone) and the stage-2 renders of none / mle / bernoulli / a
    translator (one thread: bit-reproducible)."""
    scene, frames = root / "scenes" / "courtyard", root / "spc" / "courtyard"
    exposure.write_display(frames, root / "display-k2.json", 2, out / "mle")
    translate_scene(root / "model", frames, scene, out / "translate", frames=1, threads=1)
    runs = {
        "none": {},
        "mle-k2": {"display_dir": out / "mle", "frames": 2},
        "bernoulli-k2": {"display_dir": out / "mle", "frames": 2},
        "pix2pix": {"image_dir": out / "translate" / "images"},
    }
    for source, kw in runs.items():
        reconstruct(scene, out / source, source, "3dgs", TINY_3DGS, seed=1, spc_dir=frames, threads=1, **kw)
    return sorted(p for p in out.rglob("*.png"))


def test_replacing_the_ground_truth_changes_no_non_oracle_image_or_render(tmp_path):
    """The evaluation scene's ground-truth images are replaced (frames unchanged): every image and
    render of every non-oracle source stays byte-identical."""
    root = tmp_path
    for name in ("tabletop", "courtyard"):
        write_builtin_scene(name, root / "scenes" / name, height=32, width=40, views=9, supersample=1)
        simulate_scene(root / "scenes" / name, root / "spc" / name, spc.SPCParams(frames=2), seed=0)
    augment_scene(root / "scenes" / "tabletop", root / "spc" / "tabletop", root / "augment", 4, AugmentSettings())
    exposure.calibrate_display([root / "scenes" / "tabletop"], [root / "spc" / "tabletop"], 2, root / "display-k2.json")
    train_translator(
        "pix2pix",
        [root / "augment"],
        root / "model",
        TINY_PIX2PIX,
        {"iterations": 2, "batch_size": 2, "crop": 16},
        threads=1,
    )
    before = _products(root, root / "a")
    images = sorted((root / "scenes" / "courtyard" / "images").glob("*.png"))
    for i, path in enumerate(images):  # another picture entirely, same cameras
        io.write_image(path, np.random.default_rng(i).random(io.read_rgb(path).shape).astype(np.float32))
    after = _products(root, root / "b")
    assert [p.relative_to(root / "a") for p in before] == [p.relative_to(root / "b") for p in after]
    assert len(before) == 4 * 2 + 3 * 9  # renders of 4 rows (2 held-out views), MLE, translated and prior views
    for a, b in zip(before, after):
        assert a.read_bytes() == b.read_bytes(), a.relative_to(root / "a")
    oracle = reconstruct(root / "scenes" / "courtyard", root / "gt", "gt", "3dgs", TINY_3DGS, seed=1, threads=1)
    assert oracle["iterations"] == TINY_3DGS["iterations"]  # the oracle row does read the (new) ground truth
    assert not np.array_equal(
        io.read_rgb(root / "gt" / "renders" / "image000.png"),
        io.read_rgb(root / "a" / "none" / "renders" / "image000.png"),
    )


# --- claims with intervals ----------------------------------------------------------------------------


def test_bootstrap_interval_on_known_answers():
    const = np.full(20, 1.5)
    assert bootstrap(const) == pytest.approx((1.5, 1.5, 1.5))
    rng = np.random.default_rng(3)
    for n, trials in ((40, 200), (5, 400)):  # large and small samples: the interval keeps its coverage
        hits, widths = 0, []
        for trial in range(trials):
            x = rng.normal(0.7, 1.0, n)
            mean, lo, hi = bootstrap(x, n_boot=2000, seed=trial)
            hits += lo <= 0.7 <= hi
            widths.append(hi - lo)
        assert 0.9 <= hits / trials <= 0.99, (n, hits / trials)  # ~95 % of intervals cover the true mean
        t = {40: 2.023, 5: 2.776}[n]  # Student t quantiles: the normal-theory width
        assert np.mean(widths) == pytest.approx(2 * t / np.sqrt(n), rel=0.2), n
    with pytest.raises(ValueError, match="finite paired differences"):
        bootstrap(np.array([1.0, np.inf]))


def test_verdicts_follow_the_interval():
    assert Comparison("a", "b", 10, 1.0, 0.2, 1.8).verdict == "HOLDS"
    assert Comparison("a", "b", 10, -1.0, -1.8, -0.2).verdict == "DOES NOT HOLD"
    assert Comparison("a", "b", 10, 0.3, -0.2, 0.8).verdict == "INCONCLUSIVE"
    assert Comparison("a", "b", 2, 1.0, 0.5, 1.5).verdict == "INCONCLUSIVE"  # too few units
    holds, unclear = Comparison("a", "b", 9, 1, 0.5, 2), Comparison("a", "c", 9, 0.1, -0.2, 0.4)
    assert verdict([holds, holds]) == "HOLDS" and verdict([holds, unclear]) == "INCONCLUSIVE"
    assert verdict([holds, Comparison("a", "d", 9, -1, -2, -0.5)]) == "DOES NOT HOLD" and verdict([]) == "INCONCLUSIVE"


def _metrics(path, combo, K, psnrs, seed=0):
    io.write_json(
        path,
        {
            "scene": "s",
            "combination": combo,
            "seed": seed,
            "frames": K,
            "per_view": [{"view": f"v{i}", "psnr": p} for i, p in enumerate(psnrs)],
            "mean": {"psnr": float(np.mean(psnrs))},
        },
    )
    return str(path)


def test_findings_pair_views_and_compare_equal_budgets_only(tmp_path):
    base = np.array([20.0, 21.0, 19.5, 22.0, 20.5, 21.5])
    files = [
        _metrics(tmp_path / "1.json", "pix2pixhd+nerf-grid", 1, base + 2.0),
        _metrics(tmp_path / "2.json", "pix2pixhd+3dgs", 1, base + 1.0),
        _metrics(tmp_path / "3.json", "restormer+nerf-grid", 1, base + [0.5, -0.5, 0.4, -0.6, 0.3, 0.1]),
        _metrics(tmp_path / "4.json", "none+nerf-grid", 1, base - 3.0),
        _metrics(tmp_path / "5.json", "bernoulli+3dgs", 1, base + 0.1),
        _metrics(tmp_path / "6.json", "mle+3dgs", 1, base),
        _metrics(tmp_path / "7.json", "mle-k16+3dgs", 16, base + 9.0),  # more photons: never compared
        _metrics(tmp_path / "8.json", "gt+3dgs", None, base + 10.0),
    ]
    results = {r["claim"]: r for r in evaluate_claims(per_view(files), "nerf-grid")}
    best = results["Pix2PixHD + NeRF [nerf-grid] is the best two-stage combination"]
    assert best["verdict"] == "HOLDS" and best["n"] == 6
    assert best["closest"]["worse"] == "pix2pixhd+3dgs" and best["closest"]["mean"] == pytest.approx(1.0)
    assert (
        results["Two-stage beats single-stage with NeRF [nerf-grid] (Pix2PixHD + NeRF vs NeRF on binary)"]["verdict"]
        == "HOLDS"
    )
    spad = results["The SPAD likelihood on binary frames (3DGS) beats the best two-stage row at equal K"]
    assert spad["verdict"] == "DOES NOT HOLD" and "mle-k16+3dgs" not in str(spad)
    assert results["The SPAD likelihood beats the MLE image at equal K (both + 3DGS)"]["verdict"] == "HOLDS"
    assert results["Two-stage beats single-stage with 3DGS (Pix2PixHD + 3DGS vs 3DGS on binary)"]["closest"] is None
    write_findings(files, tmp_path / "findings", "nerf-grid")
    md = (tmp_path / "findings.md").read_text()
    assert "**HOLDS**" in md and "[+1.00, +1.00]" in md and "| 6 |" in md
    assert io.read_json(tmp_path / "findings.json")["claims"][0]["verdict"] == "HOLDS"

"""The evaluation protocol: no row but the oracle reads the evaluation scene's ground truth, the
physics rows' display gain is metered from their own frames."""

import numpy as np
import pytest

from spc3d import io
from spc3d.inputs import exposure
from spc3d.inputs.augment import AugmentSettings, augment_scene
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct
from spc3d.translate.apply import translate_scene
from spc3d.translate.train import TranslatorJob, train_translator, training_data

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


@pytest.mark.parametrize("kind", ["frames", "continuous", "constant", "dark"])
def test_scene_error_equals_the_per_pixel_mse(kind):
    """The grouped error (one sRGB encoding per distinct flux) is the per-pixel sRGB MSE at every level."""
    rng = np.random.default_rng(1)
    gt = rng.uniform(0.0, 1.0, (3, 5, 7, 3)).astype(np.float32)
    meter = {
        "frames": rng.integers(0, 5, gt.shape) * 1e3,  # an MLE of K = 4 frames: 5 values
        "continuous": rng.gamma(2.0, 1e3, gt.shape),  # every pixel distinct
        "constant": np.full(gt.shape, 42.0),
        "dark": np.zeros(gt.shape),  # no detection: the unit gain
    }[kind].astype(np.float32)
    shown = meter[::-1].copy()  # shown differs from what is metered
    error = exposure.scene_error(meter, gt, shown)
    for level in (1e-3, 0.05, 0.18, 0.7, 1.0):
        displayed = exposure.display_srgb(shown, exposure.metered_gain(meter, level))
        direct = np.mean((displayed - gt.astype(np.float64)) ** 2)
        assert error(level) == pytest.approx(direct, rel=1e-12, abs=1e-15), (kind, level)
    with pytest.raises(ValueError, match="shape"):
        exposure.scene_error(meter, gt[:2])


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
        reconstruct(
            ReconstructJob(scene, out / source, source, "3dgs", TINY_3DGS, seed=1, spc_dir=frames, threads=1, **kw)
        )
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
        TranslatorJob(
            "pix2pix",
            training_data("fixed", [root / "augment"]),
            root / "model",
            TINY_PIX2PIX,
            {"iterations": 2, "batch_size": 2, "crop": 16},
            threads=1,
        )
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
    oracle = reconstruct(
        ReconstructJob(root / "scenes" / "courtyard", root / "gt", "gt", "3dgs", TINY_3DGS, seed=1, threads=1)
    )
    assert oracle["iterations"] == TINY_3DGS["iterations"]  # the oracle row does read the (new) ground truth
    assert not np.array_equal(
        io.read_rgb(root / "gt" / "renders" / "image000.png"),
        io.read_rgb(root / "a" / "none" / "renders" / "image000.png"),
    )

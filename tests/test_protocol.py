"""The evaluation protocol: no row but the oracle reads the evaluation scene's ground truth; every
photon-fed row's display level follows the exposure the camera reports."""

import shutil

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


# --- the display follows the camera's reported exposure ------------------------------------------


def test_the_fit_finds_the_known_level_and_the_likelihood_needs_none():
    rng = np.random.default_rng(0)
    linear = [rng.uniform(0.0, 0.5, (2, 6, 8, 3)), rng.uniform(0.0, 0.2, (2, 6, 8, 3))]  # a bright and a dark scene
    gts = [spc.linear_to_srgb(x) for x in linear]
    fluxes = [3e4, 7e5]  # their exposures (flux at linear 1), as their cameras report them
    true = [f * x for f, x in zip(fluxes, linear)]
    level, per_scene = exposure.fit_level(true, gts, fluxes)
    assert level == pytest.approx(1.0, rel=1e-6) and per_scene == pytest.approx([1.0, 1.0], rel=1e-6)
    # The SPAD likelihood recovers the flux itself: k = 1, as calibrate_display writes it.
    # An estimator biased low by half: the level absorbs the bias, and the dark scene stays dark.
    biased, _ = exposure.fit_level([0.5 * t for t in true], gts, fluxes)
    assert biased == pytest.approx(0.5, rel=1e-6)
    shown = exposure.display_srgb(0.5 * true[1], biased * fluxes[1])
    assert np.abs(shown - gts[1]).max() < 1e-5
    assert spc.srgb_to_linear(shown).mean() < 0.5 * spc.srgb_to_linear(exposure.display_srgb(true[0], fluxes[0])).mean()
    assert exposure.metered_gain(np.zeros((2, 2)), 0.18) == 1.0  # a preview of no detection: finite, no NaN
    with pytest.raises(ValueError, match="flux per linear intensity"):
        exposure.scene_error(true[0], gts[0], 0.0)


@pytest.mark.parametrize("kind", ["frames", "continuous", "constant", "dark"])
def test_scene_error_equals_the_per_pixel_mse(kind):
    """The grouped error (one sRGB encoding per distinct flux) is the per-pixel sRGB MSE at every level."""
    rng = np.random.default_rng(1)
    gt = rng.uniform(0.0, 1.0, (3, 5, 7, 3)).astype(np.float32)
    shown = {
        "frames": rng.integers(0, 5, gt.shape) * 1e3,  # an MLE of K = 4 frames: 5 values
        "continuous": rng.gamma(2.0, 1e3, gt.shape),  # every pixel distinct
        "constant": np.full(gt.shape, 42.0),
        "dark": np.zeros(gt.shape),  # no detection: black
    }[kind].astype(np.float32)
    error = exposure.scene_error(shown, gt, 2.5e3)
    for level in (0.05, 0.3, 1.0, 4.0, 20.0):
        displayed = exposure.display_srgb(shown, level * 2.5e3)
        direct = np.mean((displayed - gt.astype(np.float64)) ** 2)
        assert error(level) == pytest.approx(direct, rel=1e-12, abs=1e-15), (kind, level)
    with pytest.raises(ValueError, match="shape"):
        exposure.scene_error(shown, gt[:2], 1.0)


def test_a_scene_four_times_darker_exposed_four_times_longer_displays_four_times_darker(tmp_path):
    """Same frames (the camera exposes the darker scene 4x longer), so only the reported exposure
    can tell them apart: the MLE display and a translator's display are 4x darker in linear light."""
    folders = {"bright": tmp_path / "bright", "dark": tmp_path / "dark"}
    write_builtin_scene("courtyard", folders["bright"] / "scenes" / "s", height=24, width=32, views=9)
    shutil.copytree(folders["bright"] / "scenes" / "s", folders["dark"] / "scenes" / "s")
    for path in sorted((folders["dark"] / "scenes" / "s" / "images").glob("*.png")):  # 4x darker, same cameras
        io.write_image(path, spc.linear_to_srgb(spc.srgb_to_linear(io.read_rgb(path)) / 4).astype(np.float32), bits=16)
    records = {
        name: simulate_scene(root / "scenes" / "s", root / "spc" / "s", spc.SPCParams(frames=8), seed=3)
        for name, root in folders.items()
    }
    ratio = records["dark"]["exposure"]["photons_per_frame"] / records["bright"]["exposure"]["photons_per_frame"]
    assert ratio == pytest.approx(4.0, rel=0.02)  # auto exposure: 4x longer (8-bit images: not exactly 4)
    cal = tmp_path / "display-k8.json"
    exposure.calibrate_display([folders["bright"] / "scenes" / "s"], [folders["bright"] / "spc" / "s"], 8, cal)
    train_translator(
        TranslatorJob(
            "prior", training_data("fixed", [_augmented(folders["bright"])]), tmp_path / "prior", {}, {"crop": 16}
        )
    )
    mle, prior = {}, {}
    for name, root in folders.items():
        exposure.write_display(root / "spc" / "s", cal, 8, root / "mle")
        translate_scene(tmp_path / "prior", root / "spc" / "s", root / "scenes" / "s", root / "prior", threads=1)
        mle[name], prior[name] = (_mean_linear(root / kind / "images") for kind in ("mle", "prior"))
    assert mle["dark"] / mle["bright"] == pytest.approx(1 / ratio, rel=0.03)
    assert prior["dark"] / prior["bright"] == pytest.approx(1 / ratio, rel=0.03)


def _mean_linear(folder) -> float:
    return float(np.mean([spc.srgb_to_linear(io.read_rgb(p)).mean() for p in sorted(folder.glob("*.png"))]))


def _augmented(root):
    out = root / "augment"
    augment_scene(root / "scenes" / "s", root / "spc" / "s", out, 4, AugmentSettings())
    return out


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

"""Joint reconstruction: the SPAD likelihood and a stage-1 prior term in one 3D fit."""

import numpy as np
import pytest
import torch

from spc3d import io
from spc3d.names import (
    ConfigError,
    check_source,
    display_budget,
    joint_settings,
    parse_source,
    source_frames,
    source_label,
)
from spc3d.pixels import linear_to_srgb
from spc3d.reconstruct.objectives import BernoulliObjective, JointConfig, JointObjective, RGBObjective, own_objective
from spc3d.reconstruct.sources import load_source
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct
from spc3d.specs.reconstructors import check_joint, config_joint

LIKELIHOOD = BernoulliObjective(flux_scale=2.0e4, q=0.4, exposure_s=1.0e-4, dark_count_rate=100.0)


def joint_target(shape=(6, 7), seed=0):
    """Bit fractions at K = 4 and a stage-1 image, stacked as a joint row's target (H, W, 6)."""
    g = torch.Generator().manual_seed(seed)
    fractions = torch.randint(0, 5, (*shape, 3), generator=g).double() / 4
    return torch.cat([fractions, torch.rand(*shape, 3, generator=g, dtype=torch.float64)], -1)


def test_schedule_falls_linearly_then_holds():
    cfg = JointConfig(weight=2.0, weight_final=0.5, decay_until=0.5)
    assert [cfg.weight_at(t) for t in (0.0, 0.25, 0.5, 0.9, 1.0)] == pytest.approx([2.0, 1.25, 0.5, 0.5, 0.5])
    assert JointConfig(weight=3.0, weight_final=0.2, decay_until=0.0).weight_at(0.0) == 0.2  # no decay phase
    objective = JointObjective(LIKELIHOOD, cfg)
    assert objective.weight == 2.0
    objective.at(0.25)
    assert objective.weight == pytest.approx(1.25)


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"penalty": "huber"}, r"stage2.joint.penalty = 'huber': use one of \['own', 'l1'\]"),
        ({"decay_until": 1.5}, r"stage2.joint.decay_until = 1.5: must be in \[0, 1\] \(a fraction of the run\)"),
        ({"weight": -1.0}, r"stage2.joint.weight = -1.0: must be >= 0"),
        ({"weigth": 1.0}, r"unknown setting\(s\) \['weigth'\]; did you mean 'weight'"),
    ],
)
def test_bad_settings_are_named(settings, message):
    with pytest.raises(ValueError, match=message):
        config_joint(settings)


def test_a_models_entry_overrides_the_common_settings_for_that_model_only():
    joint = {"weight": 0.1, "weight_final": 0.1, "models": {"nerf-grid": {"weight": 3.0, "weight_final": 3.0}}}
    assert joint_settings(joint, "nerf-grid") == {"weight": 3.0, "weight_final": 3.0}
    assert joint_settings(joint, "3dgs") == {"weight": 0.1, "weight_final": 0.1}
    check_joint(joint)
    with pytest.raises(ValueError, match=r"stage2.joint.models: unknown model\(s\) \['grid'\]"):
        check_joint({"models": {"grid": {"weight": 1.0}}})
    with pytest.raises(ValueError, match=r"stage2.joint.weight = -1.0"):
        check_joint({"models": {"3dgs": {"weight": -1.0}}})


def test_weight_zero_is_the_likelihood_row():
    target = joint_target()
    pred = torch.rand(6, 7, 3, dtype=torch.float64)
    joint = own_objective(JointObjective(LIKELIHOOD, JointConfig(weight=0.0, weight_final=0.0)), RGBObjective("l1"))
    assert torch.equal(joint.loss(pred, target), LIKELIHOOD.loss(pred, target[..., :3]))


def test_the_weight_scales_the_prior_term_in_the_loss():
    """The loss is the likelihood plus w times the two-stage image loss, at the weight the schedule set."""
    target = joint_target()
    pred = torch.rand(6, 7, 3, dtype=torch.float64) * 0.9 + 0.05
    own = RGBObjective("l1", 0.2)
    joint = own_objective(JointObjective(LIKELIHOOD, JointConfig(weight=2.0, weight_final=0.5, decay_until=0.5)), own)
    likelihood, prior = LIKELIHOOD.loss(pred, target[..., :3]), own.loss(linear_to_srgb(pred), target[..., 3:])
    assert float(prior) > 0.01  # else any weight would pass
    for t, w in ((0.0, 2.0), (0.25, 1.25), (0.9, 0.5)):
        joint.at(t)
        assert torch.allclose(joint.loss(pred, target), likelihood + w * prior, rtol=0, atol=1e-12)


def test_likelihood_off_is_the_two_stage_row_on_the_renders_srgb():
    target = joint_target()
    pred = torch.rand(6, 7, 3, dtype=torch.float64) * 0.9 + 0.05
    own = RGBObjective("l1", 0.2)  # 3DGS's 0.8 L1 + 0.2 D-SSIM
    joint = own_objective(JointObjective(LIKELIHOOD, JointConfig(likelihood=False)), own)
    expected = own.loss(linear_to_srgb(pred), target[..., 3:])
    assert torch.allclose(joint.loss(pred, target), expected, rtol=0, atol=1e-12)
    assert joint.to_srgb(pred).equal(linear_to_srgb(pred))


@pytest.mark.parametrize("own", [RGBObjective("mse"), RGBObjective("l1", 0.2)], ids=["nerf", "3dgs"])
def test_joint_gradient_matches_finite_differences(own):
    torch.manual_seed(0)
    target = joint_target((8, 8))
    joint = own_objective(JointObjective(LIKELIHOOD, JointConfig(weight=0.7, weight_final=0.7)), own)
    # Inside (0, 1) and away from sRGB's knee (0.0031308), where the loss is smooth.
    pred = (torch.rand(8, 8, 3, dtype=torch.float64) * 0.8 + 0.1).requires_grad_()
    joint.loss(pred, target).backward()
    eps = 1e-6
    for index in [(0, 0, 0), (3, 5, 1), (7, 2, 2), (4, 4, 0)]:
        plus, minus = pred.detach().clone(), pred.detach().clone()
        plus[index] += eps
        minus[index] -= eps
        numeric = (joint.loss(plus, target) - joint.loss(minus, target)) / (2 * eps)
        assert float(pred.grad[index]) == pytest.approx(float(numeric), rel=1e-4, abs=1e-9)


def test_joint_loss_is_finite_at_extreme_renders():
    target = joint_target()
    joint = own_objective(JointObjective(LIKELIHOOD), RGBObjective("l1", 0.2))
    for value in (0.0, 1e-9, 1.0, 1e6):
        pred = torch.full((6, 7, 3), value, dtype=torch.float64, requires_grad=True)
        loss = joint.loss(pred, target)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()


def test_joint_source_names():
    assert str(parse_source("joint-restormer")) == "joint-restormer" and parse_source("joint-prior").method == "prior"
    assert source_frames("joint-restormer", 4, 1) == 4 and display_budget("joint-restormer", 1, 4) == "k4"
    assert source_label("joint-restormer").startswith("Joint: SPAD likelihood + Restormer")
    for bad in ("joint-mle", "joint-restormer-mse", "joint-bernoulli"):
        with pytest.raises(ConfigError, match="takes a stage-1 method|applies to"):
            check_source(bad, f"{bad}+3dgs", "stage2.combinations")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A small evaluated scene with SPC frames, its metered display and a stand-in stage-1 output."""
    from spc3d.inputs.build import simulate_scene
    from spc3d.inputs.exposure import calibrate_display, write_display
    from spc3d.inputs.scenes import write_builtin_scene
    from spc3d.physics import spc

    root = tmp_path_factory.mktemp("joint")
    for name in ("gallery", "tabletop"):
        write_builtin_scene(name, root / "scenes" / name, height=24, width=32, views=10, supersample=1)
        simulate_scene(root / "scenes" / name, root / "spc" / name, spc.SPCParams(frames=2), seed=0)
    calibrate_display([root / "scenes" / "tabletop"], [root / "spc" / "tabletop"], 1, root / "display-k1.json")
    write_display(root / "spc" / "gallery", root / "display-k1.json", 1, root / "mle" / "k1")
    # The stage-1 images: the metered MLE stands in for a translator's output (any image folder will do).
    (root / "stage1").symlink_to(root / "mle" / "k1" / "images")
    return root


def test_joint_source_stacks_the_frames_and_the_stage1_image(scene):
    src = load_source(
        "joint-prior",
        scene / "scenes" / "gallery",
        scene / "spc" / "gallery",
        image_dir=scene / "stage1",
        display_dir=scene / "mle" / "k1",
        joint={"weight": 0.5},
    )
    assert src.views.targets.shape == (8, 24, 32, 6) and isinstance(src.objective, JointObjective)
    assert set(torch.unique(src.views.targets[..., :3]).tolist()) <= {0.0, 1.0}  # K = 1: the bits
    first = io.read_rgb(scene / "stage1" / f"{src.views.names[0]}.png")
    assert np.allclose(src.views.targets[0, ..., 3:].numpy(), first)
    assert src.objective.cfg.weight == 0.5 and src.objective.likelihood.flux_scale > 0
    with pytest.raises(ValueError, match="needs the folder of 'prior'"):
        load_source(
            "joint-prior", scene / "scenes" / "gallery", scene / "spc" / "gallery", display_dir=scene / "mle" / "k1"
        )


FITS = pytest.mark.parametrize(
    "model, settings",
    [
        ("3dgs", {"iterations": 8, "densify_from": 4, "densify_until": 6, "init_points": 200, "backend": "native"}),
        ("nerf-grid", {"n_iters": 6, "batch_rays": 256, "n_samples": 16, "res_schedule": [[0, 12]], "chunk": 1024}),
    ],
)


def fit_joint(scene, out, model, settings, joint):
    """One joint-prior fit of the gallery scene (seed 0); its record."""
    job = ReconstructJob(
        scene / "scenes" / "gallery",
        out,
        "joint-prior",
        model,
        settings,
        spc_dir=scene / "spc" / "gallery",
        image_dir=scene / "stage1",
        display_dir=scene / "mle" / "k1",
        joint=joint,
    )
    return reconstruct(job)


def renders(folder) -> np.ndarray:
    return np.stack([io.read_rgb(folder / "renders" / f"image00{i}.png") for i in (0, 8)])


@FITS
def test_joint_rows_reconstruct_and_record_their_schedule(scene, tmp_path, model, settings):
    rec = fit_joint(scene, tmp_path / "r", model, settings, {"weight_final": 0.2})
    train = io.read_json(tmp_path / "r" / "train.json")
    assert train["objective"] == "joint" and train["frames"] == 1 and train["joint"]["weight_final"] == 0.2
    assert train["job"]["joint"] == {"weight_final": 0.2} and np.isfinite(rec["final_loss"])
    assert io.read_rgb(tmp_path / "r" / "renders" / "image008.png").shape == (24, 32, 3)


@FITS
def test_both_trainers_apply_the_weight_schedule_at_every_step(scene, tmp_path, monkeypatch, model, settings):
    """The weight that multiplies the prior term in step t's loss is the schedule's w(t / steps),
    measured from the loss itself: (loss - likelihood) / prior term. Fails when a trainer does not
    call ``at`` (w would stay at w(0)) or the objective ignores its weight."""
    seen = []
    loss = JointObjective.loss

    def spy(self, pred, target):
        total = loss(self, pred, target)
        with torch.no_grad():
            likelihood = self.likelihood.loss(pred, target[..., :3])
            prior = self.image.loss(linear_to_srgb(pred), target[..., 3:])
            seen.append(float((total - likelihood) / prior))
        return total

    monkeypatch.setattr(JointObjective, "loss", spy)
    joint = {"weight": 1.0, "weight_final": 0.2, "decay_until": 0.5}
    fit_joint(scene, tmp_path / "r", model, settings, joint)
    steps = settings.get("iterations") or settings["n_iters"]
    expected = [JointConfig(**joint).weight_at(it / steps) for it in range(1, steps + 1)]
    assert len(set(expected)) > 2  # the schedule changes over these steps
    assert seen == pytest.approx(expected, rel=1e-3)


@FITS
def test_a_joint_fit_at_w_and_at_0_render_differently(scene, tmp_path, model, settings):
    """The prior term changes the fit: the same job at w = 1 renders other held-out views than at
    w = 0, which renders what the likelihood row (bernoulli source, same seed) renders."""
    fit_joint(scene, tmp_path / "w", model, settings, {"weight": 1.0, "weight_final": 1.0})
    fit_joint(scene, tmp_path / "0", model, settings, {"weight": 0.0, "weight_final": 0.0})
    likelihood = ReconstructJob(
        scene / "scenes" / "gallery",
        tmp_path / "b",
        "bernoulli",
        model,
        settings,
        spc_dir=scene / "spc" / "gallery",
        display_dir=scene / "mle" / "k1",
    )
    reconstruct(likelihood)
    with_prior, without = renders(tmp_path / "w"), renders(tmp_path / "0")
    assert np.array_equal(without, renders(tmp_path / "b"))  # w = 0 is the likelihood row, bit for bit
    # 8 (6) steps move 3DGS's held-out views little: a third of the values by about a grey level.
    assert (with_prior != without).mean() > 0.2 and np.abs(with_prior - without).mean() > 1e-3


def test_joint_rows_are_listed_in_both_paper_tables_under_their_own_name():
    import pandas as pd

    from spc3d.evaluation import tables

    summary = pd.DataFrame(index=["joint-restormer+3dgs", "bernoulli+3dgs", "restormer+3dgs"])
    for spec, unlisted in ((tables.SINGLE_STAGE, False), (tables.TWO_STAGE, True)):
        rows = {src: label for label, src, *_ in tables.extra_rows(summary, spec, "nerf-grid", unlisted)}
        assert rows["joint-restormer"] == "Joint: SPAD likelihood + Restormer (prior term) + 3DGS"

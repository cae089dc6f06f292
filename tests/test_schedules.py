"""The stage-2 fits' schedules: what each learning rate is at a step, that the trainers set it at
every step, and the rule that raises 3DGS's SH degree (spc3d.reconstruct.splatting, nerf,
nerf_grid, nerf_trainer)."""

from __future__ import annotations

import math

import pytest
import torch

from spc3d.evaluation.metrics import psnr
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct import RECONSTRUCTORS, nerf, nerf_grid
from spc3d.reconstruct.gaussians import GaussianConfig
from spc3d.reconstruct.splatting import log_linear, means_lr
from spc3d.reconstruct.views import Views


@pytest.fixture(scope="module")
def views() -> Views:
    s = render_scene("courtyard", height=12, width=16, views=6, supersample=1)
    return Views(torch.as_tensor(s.images, dtype=torch.float32), s.cameras, list(s.names))


def test_log_linear_falls_geometrically_between_its_ends_and_holds_outside():
    assert log_linear(100, 100, 300, 1e-2, 1e-4) == pytest.approx(1e-2)
    assert log_linear(200, 100, 300, 1e-2, 1e-4) == pytest.approx(1e-3)  # half way: the geometric mean
    assert log_linear(300, 100, 300, 1e-2, 1e-4) == pytest.approx(1e-4)
    assert log_linear(0, 100, 300, 1e-2, 1e-4) == pytest.approx(1e-2)
    assert log_linear(999, 100, 300, 1e-2, 1e-4) == pytest.approx(1e-4)
    assert log_linear(5, 10, 10, 1e-2, 1e-4) == pytest.approx(1e-2)  # an empty window: no division by 0
    assert log_linear(11, 10, 11, 1e-2, 1e-4) == pytest.approx(1e-4)  # a one-step window ends at its last value


def test_means_lr_is_the_reference_schedule_times_the_scene_extent():
    cfg = GaussianConfig(iterations=1000, lr_means=1.6e-4, lr_means_final=1.6e-6)
    assert means_lr(0, cfg, 2.5) == pytest.approx(2.5 * 1.6e-4)
    assert means_lr(500, cfg, 2.5) == pytest.approx(2.5 * 1.6e-5)
    assert means_lr(1000, cfg, 2.5) == pytest.approx(2.5 * 1.6e-6)


def test_the_3dgs_trainer_sets_the_means_lr_at_every_step_and_keeps_the_others(views):
    settings = {"iterations": 40, "init_points": 60, "densify_from": 100, "densify_until": 0, "sh_interval": 1000}
    trainer, iterations, cfg = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    for it in (1, 2, 20, 40):
        trainer.step(it)
        lrs = {g["name"]: g["lr"] for g in trainer.opt.param_groups}
        assert lrs["means"] == pytest.approx(means_lr(it, cfg, trainer.extent))
        assert lrs["sh_dc"] == cfg.lr_sh_dc and lrs["opacity_logits"] == cfg.lr_opacity


def test_the_sh_degree_rises_only_while_the_loss_still_falls_by_half_a_percent(views):
    settings = {"iterations": 40, "init_points": 60, "sh_interval": 4, "sh_degree": 2}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    trainer.losses, trainer.degree_loss = [1.0] * 4, math.inf
    trainer.maybe_raise_degree()
    assert trainer.model.active_degree == 1 and trainer.degree_loss == 1.0
    trainer.losses = [0.996] * 4  # 0.4 % better: not enough
    trainer.maybe_raise_degree()
    assert trainer.model.active_degree == 1 and trainer.degree_loss == pytest.approx(0.996)
    trainer.losses = [0.9] * 4
    trainer.maybe_raise_degree()
    assert trainer.model.active_degree == 2
    trainer.losses = [0.5] * 4
    trainer.maybe_raise_degree()
    assert trainer.model.active_degree == 2  # never past sh_degree


def test_nerf_learning_rates_decay_geometrically_per_group():
    ncfg = nerf.NerfConfig(lr=5e-4, lr_final=5e-6, n_iters=1000)
    assert nerf.lr_at(500, ncfg)["mlp"] == pytest.approx(5e-5)
    gcfg = nerf_grid.GridConfig(lr_grid=0.1, lr_mlp=1e-3, lr_decay=0.01, n_iters=600)
    half = nerf_grid.lr_at(300, gcfg)
    assert half == pytest.approx({"density": 0.01, "features": 0.01, "mlp": 1e-4})


@pytest.mark.parametrize("model", ["nerf-grid", "nerf-mlp"])
def test_the_ray_trainers_set_their_learning_rates_at_every_step(views, model):
    settings = {"n_iters": 10, "batch_rays": 32, "chunk": 512}
    if model == "nerf-grid":
        settings |= {"lr_decay": 0.1, "res_schedule": [[0, 16]], "occupancy_warmup": 100}
    else:
        settings |= {"preset": "cpu", "lr_final": 5e-5}
    trainer, _, cfg = RECONSTRUCTORS[model](views, None, settings, 0)
    lr_at = (nerf_grid if model == "nerf-grid" else nerf).lr_at
    for it in (1, 5, 10):
        trainer.step(it)
        got = {g["name"]: g["lr"] for g in trainer.opt.param_groups}
        assert got == pytest.approx(lr_at(it, cfg)), it


def test_3dgs_adam_has_the_reference_epsilon_so_a_vanishing_gradient_still_moves_a_gaussian(views):
    """3DGS's Adam uses eps = 1e-15 (Kerbl et al.): Gaussians far from every view get gradients of
    that order and must still move. A first Adam step moves a parameter by lr * g / (|g| + eps)."""
    from spc3d.reconstruct.splatting import make_optimizer

    settings = {"iterations": 40, "init_points": 60}
    trainer, _, cfg = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    model = trainer.model
    opt = make_optimizer(model, cfg, extent=1.0)
    before = model.opacity_logits.detach().clone()
    model.opacity_logits.grad = torch.full_like(model.opacity_logits, 1e-15)
    opt.step()
    moved = (before - model.opacity_logits.detach()).abs()
    assert torch.allclose(moved, torch.full_like(moved, cfg.lr_opacity * 0.5), rtol=1e-3)


def test_3dgs_density_control_of_a_step_runs_at_the_start_of_the_next(views):
    """Step k's density-control pass runs at the start of step k + 1 (a training stopped at k ends
    on a fitted model), so steps 1, 2, 3 run the passes of 1 and 2, never a pass 0 (which would
    reset every opacity before the first update)."""
    settings = {"iterations": 40, "init_points": 60}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    seen = []
    trainer.control.step = lambda it, model, opt: seen.append(it)
    for it in (1, 2, 3):
        trainer.step(it)
    assert seen == [1, 2]


def test_3dgs_cameras_are_refined_from_pose_from_on(views):
    """With camera refinement the corrections stay at zero before ``pose_from`` and move from it on."""
    settings = {"iterations": 40, "init_points": 60, "pose_refine": True, "pose_from": 3, "pose_lr": 1e-2}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    moved = []
    for it in (1, 2, 3, 4):
        trainer.step(it)
        moved.append(bool(trainer.poses.delta.detach().abs().sum() > 0))
    assert moved == [False, False, True, True]


def test_a_likelihood_fit_holds_no_view_out_even_with_plateau_views(views):
    """The SPAD likelihood never stops on a plateau (its loss floor is photon noise): it fits every
    training view whatever plateau_views says, and its record names no judging view."""
    from spc3d.reconstruct.objectives import BernoulliObjective
    from spc3d.reconstruct.splatting import SplatTrainer

    cfg = GaussianConfig(iterations=40, init_points=60, plateau_views=2, plateau_patience=2)
    trainer = SplatTrainer(views, BernoulliObjective(100.0, 0.4, 1e-3, 10.0), cfg, seed=0)
    assert len(trainer.views.names) == len(views.names) and trainer.check is None
    assert trainer.plateau.views == []


def test_a_non_finite_loss_stops_3dgs_naming_the_step_view_and_what_is_finite(views):
    """A NaN target makes the loss NaN: the fit stops at once, and the message counts the finite
    rendered pixels, says whether the target is finite, and counts the finite Gaussians."""
    settings = {"iterations": 40, "init_points": 60}
    nan = Views(torch.full_like(views.targets, float("nan")), views.cameras, views.names)
    trainer, _, _ = RECONSTRUCTORS["3dgs"](nan, None, settings, 0)
    h, w = views.targets.shape[1:3]
    n = len(trainer.model)
    pattern = (
        rf"^3DGS training stopped at iteration 1: the loss on training view \d+ is nan \({h * w} of {h * w} "
        rf"pixels rendered finite, target finite: False, {n} of {n} Gaussians finite\)$"
    )
    with pytest.raises(FloatingPointError, match=pattern):
        trainer.step(1)


def test_3dgs_stops_when_no_gaussian_is_finite_any_more_at_a_density_step(views):
    """Gaussians that turned non-finite render nothing (opacity 0), so the loss stays finite: the
    trainer checks at every density-control step that some Gaussian is still finite."""
    settings = {"iterations": 40, "init_points": 60, "densify_every": 2, "densify_from": 100}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    trainer.step(1)
    with torch.no_grad():
        trainer.model.means.fill_(float("nan"))
    with pytest.raises(FloatingPointError, match=r"^3DGS training stopped at iteration 2: none of the 60 Gaussians"):
        trainer.step(2)


def test_3dgs_keeps_one_interval_of_losses_and_judges_the_sh_degree_at_each_interval_end(views):
    """The SH-degree rule reads the mean loss of the last ``sh_interval`` steps, decided at every
    multiple of ``sh_interval``: the trainer keeps exactly that many losses and no more."""
    settings = {"iterations": 40, "init_points": 60, "sh_interval": 3}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    decided, values = [], []
    raise_degree = trainer.maybe_raise_degree
    trainer.maybe_raise_degree = lambda: (decided.append(len(values) + 1), raise_degree())  # inside step len + 1
    for it in range(1, 8):
        values.append(trainer.step(it)["loss"])
        assert trainer.losses == values[-3:]
    assert decided == [3, 6]


def test_3dgs_reports_training_psnr_for_image_targets_only(views):
    """The training PSNR of the step's view, its render clipped to [0, 1] as a viewer sees it (a
    sum of Gaussians can overshoot 1: here every render is tripled to make it)."""
    from spc3d.reconstruct.objectives import BernoulliObjective
    from spc3d.reconstruct.splatting import SplatTrainer

    trainer, _, cfg = RECONSTRUCTORS["3dgs"](views, None, {"iterations": 40, "init_points": 60}, 0)
    seen, render = [], trainer._render

    def overshooting(cams, i, motion=None):
        out = render(cams, i, motion)
        out["image"] = out["image"] * 3.0
        seen.append((i, out["image"].detach().clone()))
        return out

    trainer._render = overshooting
    psnr_db = trainer.step(1)["psnr"]
    ((i, image),) = seen
    assert image.max() > 1.0 and psnr_db == pytest.approx(psnr(image.clamp(0, 1), views.targets[i]), rel=1e-6)
    bits = SplatTrainer(views, BernoulliObjective(100.0, 0.4, 1e-3, 10.0), cfg, seed=0)
    assert math.isnan(bits.step(1)["psnr"])  # not against bit fractions


def test_3dgs_check_loss_is_the_objective_on_the_held_out_views(views):
    settings = {"iterations": 40, "init_points": 60, "plateau_views": 1, "plateau_patience": 2}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    trainer.step(1)
    cams, targets = trainer.check.cameras, trainer.check.targets
    with torch.no_grad():
        expected = [trainer.objective.loss(trainer.render(cams, j), targets[j]).item() for j in range(len(cams))]
    assert trainer.check_loss() == pytest.approx(float(sum(expected) / len(expected)), rel=1e-6)


def test_the_sh_degree_stays_when_the_loss_falls_by_exactly_half_a_percent(views):
    settings = {"iterations": 40, "init_points": 60, "sh_interval": 4, "sh_degree": 2}
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, None, settings, 0)
    trainer.model.active_degree, trainer.degree_loss = 1, 2.0
    trainer.losses = [0.995 * 2.0] * 4  # exactly 0.5 % better: not more
    trainer.maybe_raise_degree()
    assert trainer.model.active_degree == 1


def test_grid_config_takes_resolution_two_and_refuses_an_empty_or_smaller_schedule():
    assert nerf_grid.GridConfig(res_schedule=[[0, 2]]).res_schedule == [[0, 2]]
    for bad in ([], [[0, 1]]):
        with pytest.raises(ValueError, match=r"^res_schedule = .*: needs \(iteration, resolution >= 2\) pairs$"):
            nerf_grid.GridConfig(res_schedule=bad)


def test_the_grid_switches_resolution_at_the_scheduled_step_and_reports_its_capacity():
    cfg = nerf_grid.GridConfig(res_schedule=[[0, 8], [5, 12]])
    model = nerf_grid.GridNeRF(cfg)
    assert [model.res_for_step(s) for s in (0, 4, 5, 6)] == [8, 8, 12, 12]
    cap = model.capacity()
    assert cap["cells"] == (model.res - 1) ** 3 and cap["parameters"] == sum(p.numel() for p in model.parameters())


def test_a_one_iteration_grid_decays_its_lr_over_that_iteration():
    cfg = nerf_grid.GridConfig(n_iters=1, lr_decay=0.1)
    assert nerf_grid.lr_at(1, cfg)["density"] == pytest.approx(cfg.lr_grid * 0.1)


def test_a_one_iteration_nerf_reaches_its_final_lr_and_its_optimiser_starts_at_lr():
    cfg = nerf.nerf_preset("cpu")
    one = type(cfg)(**{**cfg.__dict__, "n_iters": 1})
    assert nerf.lr_at(1, one)["mlp"] == pytest.approx(cfg.lr_final, rel=1e-12)
    (group,) = nerf.make_optimizer(nerf.NeRF(cfg), cfg).param_groups
    assert group["name"] == "mlp" and group["lr"] == cfg.lr == nerf.lr_at(0, cfg)["mlp"]


@pytest.mark.parametrize("samples", [16, 48])
def test_a_fresh_grid_gives_each_sample_of_the_axial_ray_its_initial_alpha(samples):
    """step_ref is the NDC spacing of the samples on the ray along the z axis (z spans 2): a fresh
    grid's α there is alpha_init per sample, so the ray's opacity is 1 − (1 − alpha_init)^n."""
    cfg = nerf_grid.GridConfig(n_samples=samples, res_schedule=[[0, 8]])
    model = nerf_grid.GridNeRF(cfg)
    axial = torch.tensor([[0.0, 0.0, -1.0]]), torch.tensor([[0.0, 0.0, 2.0]])
    with torch.no_grad():
        acc = model(*axial, train=False, viewdirs=torch.tensor([[0.0, 0.0, 1.0]]))["acc"].item()
    assert acc == pytest.approx(1.0 - (1.0 - cfg.alpha_init) ** samples, rel=1e-5)

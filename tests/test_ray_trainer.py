"""What one step of the NeRF family's trainer does (spc3d.reconstruct.nerf_trainer.RayTrainer):
the model sees the sampled pixels' rays in training mode and is fitted to their colours, the MLP
NeRF is supervised on its coarse and fine outputs, the grid grows, smooths and refreshes its
occupancy on schedule, and the held-out check and renders run without building a graph."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spc3d.evaluation.metrics import psnr
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.objectives import BernoulliObjective, RGBObjective
from spc3d.reconstruct.views import Views

GRID = {"n_iters": 20, "batch_rays": 32, "chunk": 512, "n_samples": 8, "res_schedule": [[0, 6]]}
MLP = {"n_iters": 20, "batch_rays": 32, "chunk": 512, "preset": "cpu"}
SETTINGS = {"nerf-grid": GRID, "nerf-mlp": MLP}


@pytest.fixture(scope="module")
def views() -> Views:
    s = render_scene("courtyard", height=8, width=10, views=5, supersample=1)  # a training scene
    return Views(torch.as_tensor(s.images, dtype=torch.float32), s.cameras, list(s.names))


def trainer_of(views, kind, objective=None, **settings):
    trainer, _, _ = RECONSTRUCTORS[kind](views, objective, SETTINGS[kind] | settings, 0)
    return trainer


@pytest.mark.parametrize(
    ("kind", "own"),
    [("3dgs", RGBObjective("l1", 0.2)), ("nerf-mlp", RGBObjective("mse")), ("nerf-grid", RGBObjective("mse"))],
)
def test_each_factory_fits_its_models_own_loss_when_given_no_objective(views, kind, own):
    # 3DGS: 0.8 L1 + 0.2 D-SSIM (its ssim_weight); the NeRF family: MSE (RECONSTRUCTORS' factories)
    settings = SETTINGS.get(kind, {"iterations": 2, "init_points": 20})
    trainer, _, _ = RECONSTRUCTORS[kind](views, None, settings, 0)
    assert trainer.objective == own
    with pytest.raises(ValueError, match=r"^RGBObjective kind 'l2': use 'l1' or 'mse'$"):
        RGBObjective("l2")


class Recording(RGBObjective):
    """The RGB objective, keeping each call's prediction, target, grad mode and value."""

    def __init__(self):
        super().__init__("mse")
        self.calls = []

    def loss(self, pred, target):
        value = super().loss(pred, target)
        self.calls.append((pred.detach().clone(), target.clone(), torch.is_grad_enabled(), value.item()))
        return value


def record_forward(model):
    """Replace ``model``'s forward by one that records its arguments and output."""
    seen, forward = [], model.forward

    def spy(*args, **kwargs):
        out = forward(*args, **kwargs)
        seen.append((args, kwargs, {k: v.detach().clone() for k, v in out.items() if torch.is_tensor(v)}))
        return out

    model.forward = spy
    return seen


@pytest.mark.parametrize("kind", ["nerf-grid", "nerf-mlp"])
def test_a_step_fits_the_sampled_pixels_colours_from_their_rays_in_training_mode(views, kind):
    objective = Recording()
    trainer = trainer_of(views, kind, objective)
    rng = np.random.default_rng()
    rng.bit_generator.state = trainer.rng.bit_generator.state
    sel = torch.as_tensor(rng.integers(trainer.targets.shape[0], size=trainer.cfg.batch_rays))
    seen = record_forward(trainer.model)
    trainer.step(1)
    ((args, kwargs, _),) = seen
    origins, directions = args
    assert torch.equal(origins, trainer.rays[0][sel]) and torch.equal(directions, trainer.rays[1][sel])
    assert torch.equal(kwargs["viewdirs"], trainer.rays[2][sel]) and kwargs["train"] is True
    assert all(torch.equal(target, trainer.targets[sel]) for _, target, _, _ in objective.calls)


def test_the_mlp_nerf_is_fitted_on_its_coarse_and_fine_outputs(views):
    objective = Recording()
    trainer = trainer_of(views, "nerf-mlp", objective)
    assert trainer.model.fine is not None
    seen = record_forward(trainer.model)
    loss = trainer.step(1)["loss"]
    out = seen[0][2]
    (fine, _, _, a), (coarse, _, _, b) = objective.calls
    assert torch.equal(fine, out["rgb"]) and torch.equal(coarse, out["rgb_coarse"])
    assert loss == pytest.approx(a + b, rel=1e-6)


def test_an_mlp_nerf_without_a_fine_network_is_fitted_on_its_one_output(views):
    objective = Recording()
    trainer = trainer_of(views, "nerf-mlp", objective, n_fine=0)
    loss = trainer.step(1)["loss"]
    assert len(objective.calls) == 1 and loss == pytest.approx(objective.calls[0][3], rel=1e-6)


def test_the_grid_grows_at_its_scheduled_step_inside_a_training_step(views):
    trainer = trainer_of(views, "nerf-grid", res_schedule=[[0, 6], [3, 8]])
    resolutions = []
    for it in range(1, 5):
        trainer.step(it)
        resolutions.append(trainer.model.res)
    assert resolutions == [6, 6, 8, 8]


def test_the_grid_step_adds_the_total_variation_gradient(views):
    def density_after_three_steps(tv):  # the grid starts constant: its first steps make it rough
        trainer = trainer_of(views, "nerf-grid", tv_density=tv, tv_features=0.0)
        for it in range(1, 4):
            trainer.step(it)
        return trainer.model.density.detach().clone()

    plain = density_after_three_steps(0.0)
    assert torch.equal(density_after_three_steps(0.0), plain)  # the fit is deterministic
    assert not torch.equal(density_after_three_steps(1.0), plain)


def test_the_grid_refreshes_its_occupancy_every_so_often_from_its_warmup_on(views):
    trainer = trainer_of(views, "nerf-grid", occupancy_warmup=6, occupancy_every=3)
    refreshed, update = [], trainer.model.update_occupancy
    for it in range(1, 14):
        trainer.model.update_occupancy = lambda it=it: (refreshed.append(it), update())
        trainer.step(it)
    assert refreshed == [6, 9, 12]


@pytest.mark.parametrize("kind", ["nerf-grid", "nerf-mlp"])
def test_a_step_reports_its_loss_and_for_image_targets_the_training_psnr(views, kind):
    """The PSNR of the render clipped to [0, 1] as a viewer sees it (scaled 100× here to overshoot)."""
    trainer = trainer_of(views, kind)
    seen, forward = record_forward(trainer.model), trainer.model.forward
    trainer.model.forward = lambda *a, **k: {n: 100.0 * v if n == "rgb" else v for n, v in forward(*a, **k).items()}
    got = trainer.step(1)
    rng = np.random.default_rng(0)  # the trainer's generator, seeded with the fit's seed
    sel = torch.as_tensor(rng.integers(trainer.targets.shape[0], size=trainer.cfg.batch_rays))
    rgb = 100.0 * seen[0][2]["rgb"]
    assert rgb.max() > 1.0 and got["psnr"] == pytest.approx(psnr(rgb.clamp(0, 1), trainer.targets[sel]), rel=1e-6)
    assert got["loss"] > 0.0
    bits = trainer_of(views, kind, BernoulliObjective(100.0, 0.4, 1e-3, 10.0))
    assert math.isnan(bits.step(1)["psnr"])  # not against bit fractions


@pytest.mark.parametrize("kind", ["nerf-grid", "nerf-mlp"])
def test_the_check_loss_is_the_objective_on_the_held_out_views_without_a_graph(views, kind):
    objective = Recording()
    trainer = trainer_of(views, kind, objective, plateau_views=1, plateau_patience=2)
    assert trainer.check is not None
    cams, targets = trainer.check.cameras, trainer.check.targets
    expected = [RGBObjective("mse").loss(trainer.render(cams, j), targets[j]).item() for j in range(len(cams))]
    objective.calls.clear()
    assert trainer.check_loss() == pytest.approx(float(np.mean(expected)), rel=1e-5)
    assert objective.calls and not any(grad for _, _, grad, _ in objective.calls)


@pytest.mark.parametrize("kind", ["nerf-grid", "nerf-mlp"])
def test_a_render_builds_no_graph(views, kind):
    trainer = trainer_of(views, kind)
    image = trainer.render(views.cameras, 0)
    assert image.shape == views.targets[0].shape and not image.requires_grad

"""3DGS model and training: density control keeps Adam consistent, resume is exact, the SPAD
likelihood objective is finite and recovers the maximum-likelihood flux."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from spc3d.cameras import split_views
from spc3d.checkpoints import Checkpoint, CheckpointPolicy, fingerprint
from spc3d.inputs.scenes import render_scene
from spc3d.physics import spc
from spc3d.pixels import linear_to_srgb, srgb_to_linear
from spc3d.reconstruct import densify
from spc3d.reconstruct.gaussians import GaussianConfig, GaussianModel, knn_rms_distance, random_points
from spc3d.reconstruct.objectives import BernoulliObjective, RGBObjective
from spc3d.reconstruct.splatting import SplatTrainer, make_optimizer
from spc3d.reconstruct.views import Views
from spc3d.training import run

from conftest import InterruptAt, Interrupted


@pytest.fixture(scope="module")
def scene():
    return render_scene("courtyard", 24, 32, views=9, supersample=1)


def tiny_views(scene):
    train, _ = split_views(len(scene.names))
    return Views(torch.tensor(scene.images[train]), scene.cameras.subset(train), [scene.names[i] for i in train])


def test_knn_distance_of_a_grid():
    g = torch.stack(torch.meshgrid(*[torch.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    d = knn_rms_distance(g * 0.5)
    assert torch.allclose(d, torch.full_like(d, 0.5))  # every grid point has 3 neighbours at 0.5


def test_random_points_lie_in_the_frusta(scene):
    pts = random_points(scene.cameras, 500, seed=0).numpy()
    uv_depth = (scene.cameras.w2c[0, :, :3] @ pts.T).T + scene.cameras.w2c[0, :, 3]
    assert (uv_depth[:, 2] > 0).all()
    near, far = scene.cameras.bounds[:, 0].min(), scene.cameras.bounds[:, 1].max()
    assert near * 0.5 < np.median(uv_depth[:, 2]) < far


def test_append_and_select_keep_adam_state_aligned():
    model = GaussianModel(torch.randn(10, 3), torch.rand(10, 3), sh_degree=1)
    opt = make_optimizer(model, GaussianConfig(), extent=1.0)
    model.means.sum().backward()
    opt.step()
    before = opt.state[model.means]["exp_avg"].clone()
    densify.append(model, opt, densify.clone_params(model, torch.arange(10) < 3))
    assert len(model) == 13 and opt.state[model.means]["exp_avg"].shape == (13, 3)
    assert torch.equal(opt.state[model.means]["exp_avg"][:10], before)
    assert (opt.state[model.means]["exp_avg"][10:] == 0).all()  # copies start with zero moments
    keep = torch.arange(13) % 2 == 0
    densify.select(model, opt, keep)
    assert len(model) == 7 and torch.equal(opt.state[model.means]["exp_avg"][:5], before[::2])
    current = {p for g in opt.param_groups for p in g["params"]}
    assert model.means in opt.state and set(opt.state) <= current  # no moments of replaced tensors


def test_split_children_are_smaller_and_near_the_parent():
    model = GaussianModel(torch.zeros(1, 3), torch.rand(1, 3), sh_degree=0)
    model.log_scales.data.fill_(math.log(0.2))
    kids = densify.split_params(model, torch.tensor([True]))
    assert kids["means"].shape == (2, 3)
    assert torch.allclose(kids["log_scales"].exp(), torch.full((2, 3), 0.2 / 1.6))
    assert kids["means"].norm(dim=1).max() < 1.5  # within a few sigma of the parent


def test_densification_grows_where_gradients_demand(scene):
    cfg = GaussianConfig(
        iterations=60,
        densify_from=10,
        densify_until=60,
        densify_every=20,
        init_points=300,
        opacity_reset_every=10_000,
        densify_grad=1e-9,
        backend="native",
        sh_interval=1000,
    )
    t = SplatTrainer(tiny_views(scene), RGBObjective("l1", 0.2), cfg, seed=0)
    run(t, 60, desc="densify")
    assert len(t.model) > 300  # every Gaussian with a gradient was cloned or split
    capped = GaussianConfig(**{**cfg.__dict__, "max_gaussians": 320})
    t2 = SplatTrainer(tiny_views(scene), RGBObjective("l1", 0.2), capped, seed=0)
    run(t2, 60, desc="capped")
    assert len(t2.model) <= 320


def test_resume_matches_uninterrupted_run(scene, tmp_path, one_thread):
    cfg = GaussianConfig(
        iterations=24,
        densify_from=5,
        densify_until=20,
        densify_every=5,
        init_points=200,
        opacity_reset_every=1000,
        backend="native",
        sh_interval=8,
    )
    views = tiny_views(scene)
    full = SplatTrainer(views, RGBObjective("l1", 0.2), cfg, seed=3)
    run(full, 24, desc="full")
    ckpt = Checkpoint(tmp_path / "ckpt.pt", fingerprint("test", {"cfg": dataclasses.asdict(cfg)}, {}))
    first = SplatTrainer(views, RGBObjective("l1", 0.2), cfg, seed=3)
    with pytest.raises(Interrupted):  # fraction 0.5 of 24: a checkpoint at 12, killed at 15
        run(InterruptAt(first, 15), 24, ckpt, CheckpointPolicy(fraction=0.5, minutes=0), desc="part 1")
    second = SplatTrainer(views, RGBObjective("l1", 0.2), cfg, seed=3)
    rec = run(second, 24, ckpt, desc="part 2")
    assert rec["resumed_from"] == 12 and len(second.model) == len(full.model) > 200
    assert torch.equal(second.model.means, full.model.means)
    assert torch.equal(second.render(views.cameras, 0), full.render(views.cameras, 0))


def test_bernoulli_objective_recovers_the_mle_flux():
    params = spc.SPCParams(frames=16)
    obj = BernoulliObjective(
        flux_scale=2e4, q=params.q, exposure_s=params.exposure_s, dark_count_rate=params.dark_count_rate
    )
    S = torch.arange(1, 16, dtype=torch.float64)  # S = 0 and S = K have their optimum at 0 / infinity
    f = S / 16
    log_lin = torch.full_like(f, -1.0, requires_grad=True)  # optimise log-intensity: stays positive
    opt = torch.optim.LBFGS([log_lin], max_iter=200, tolerance_grad=1e-12, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = obj.loss(log_lin.exp(), f) * len(f)
        loss.backward()
        return loss

    opt.step(closure)
    expected = spc.mle_flux(S.numpy().astype(int), 16, params) / 2e4
    np.testing.assert_allclose(log_lin.detach().exp().numpy(), expected, rtol=1e-4)


@pytest.mark.parametrize("value", [0.0, 1e-12, 1.0, 1e6])
def test_bernoulli_loss_finite_at_extremes(value):
    obj = BernoulliObjective(flux_scale=1e5, q=0.45, exposure_s=1e-4, dark_count_rate=0.0)
    x = torch.full((4, 3), value, dtype=torch.float64, requires_grad=True)
    for target in (0.0, 1.0):
        loss = obj.loss(x, torch.full((4, 3), target, dtype=torch.float64))
        (g,) = torch.autograd.grad(loss, x)
        assert torch.isfinite(loss) and torch.isfinite(g).all()


def test_torch_srgb_matches_numpy():
    x = torch.linspace(0, 1, 101, dtype=torch.float64)
    np.testing.assert_allclose(srgb_to_linear(x).numpy(), spc.srgb_to_linear(x.numpy()), atol=1e-12)
    np.testing.assert_allclose(linear_to_srgb(x).numpy(), spc.linear_to_srgb(x.numpy()), atol=1e-12)


def test_cap_keeps_the_strongest_candidates():
    cand = torch.tensor([True, False, True, True, True])
    grads = torch.tensor([0.5, 9.0, 0.1, 0.7, 0.3])
    assert densify.cap_candidates(cand, grads, 2).tolist() == [True, False, False, True, False]
    assert densify.cap_candidates(cand, grads, 10).tolist() == cand.tolist()
    assert not densify.cap_candidates(cand, grads, 0).any()

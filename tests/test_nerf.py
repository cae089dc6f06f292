"""NeRF components: rays and NDC, volume compositing, the grid field, and tiny overfitting runs."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from spc3d.cameras import project, rotation_angle_deg
from spc3d.evaluation.metrics import psnr
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct import nerf, nerf_grid
from spc3d.reconstruct.rays import average_pose, camera_rays, ndc_rays, recenter, view_dirs
from spc3d.reconstruct.volume import composite, march_grid, sample_pdf


@pytest.fixture(scope="module")
def scene():
    return render_scene(
        "tabletop", 24, 32, views=9, supersample=1
    )  # a training scene: tests never look at evaluation scenes


@pytest.fixture(scope="module")
def ndc_data(scene):
    """NDC rays, unit view directions and colours of every view, each (N, H*W, 3)."""
    cams, _ = recenter(scene.cameras)
    fx, fy = cams.intrinsics[0, :2]
    out = []
    for i in range(len(cams)):
        o, d = camera_rays(cams, i)
        o_n, d_n = ndc_rays(o, d, fx, fy, cams.width, cams.height)
        out.append((o_n, d_n, view_dirs(d), torch.as_tensor(scene.images[i].reshape(-1, 3))))
    return [torch.stack(x) for x in zip(*out)]


# ---------------------------------------------------------------- rays
def _ndc_to_world(p: torch.Tensor, fx: float, fy: float, W: int, H: int, near: float) -> torch.Tensor:
    """Inverse of the NDC map of :mod:`spc3d.reconstruct.rays` for points (..., 3) with z_ndc < 1:
    z = 2 near / (1 - z_ndc), x = x_ndc z W / (2 fx), y = y_ndc z H / (2 fy). Checks ndc_rays."""
    z = 2.0 * near / (1.0 - p[..., 2])
    return torch.stack([p[..., 0] * z * W / (2.0 * fx), p[..., 1] * z * H / (2.0 * fy), z], dim=-1)


def test_camera_rays_project_to_pixel_centres(scene):
    cams = scene.cameras
    o, d = camera_rays(cams, 2, dtype=torch.float64)
    uv, z = project(cams.subset([2]), (o + 2.5 * d).numpy())
    v, u = np.mgrid[0 : cams.height, 0 : cams.width] + 0.5
    np.testing.assert_allclose(uv[0], np.stack([u.ravel(), v.ravel()], 1), atol=1e-9)
    np.testing.assert_allclose(z[0], 2.5, atol=1e-9)


def test_ndc_maps_near_to_zero_and_infinity_to_one():
    torch.manual_seed(0)
    fx, fy, W, H, near = 50.0, 45.0, 64, 48, 1.0
    o = torch.cat([torch.rand(100, 2, dtype=torch.float64) - 0.5, torch.zeros(100, 1, dtype=torch.float64)], 1)
    d = torch.cat([0.4 * (torch.rand(100, 2, dtype=torch.float64) - 0.5), torch.ones(100, 1, dtype=torch.float64)], 1)
    o_n, d_n = ndc_rays(o, d, fx, fy, W, H, near)
    assert torch.allclose(o_n[:, 2], torch.full((100,), -1.0, dtype=torch.float64))  # depth near -> t = 0
    for depth in (1.0, 2.0, 7.5, 1e3):
        p = o + (depth - o[:, 2:]) * d  # points at camera depth `depth`
        direct = torch.stack(
            [2 * fx / W * p[:, 0] / p[:, 2], 2 * fy / H * p[:, 1] / p[:, 2], 1 - 2 * near / p[:, 2]], 1
        )
        t = 1 - near / p[:, 2:]  # depth = near / (1 - t): t is linear in disparity
        assert torch.allclose(o_n + t * d_n, direct, atol=1e-9)
        # the NDC point at t maps back to the world point at that depth, on the world ray
        assert torch.allclose(_ndc_to_world(o_n + t * d_n, fx, fy, W, H, near), p, rtol=1e-7, atol=1e-9)
    far = o_n + 1.0 * d_n  # t = 1: infinity, z_ndc = 1
    assert torch.allclose(far[:, 2], torch.ones(100, dtype=torch.float64))


def test_recenter_keeps_relative_poses(scene):
    cams = scene.cameras
    new, (s, R, t) = recenter(cams)
    dist0 = np.linalg.norm(cams.centers[:, None] - cams.centers[None], axis=-1)
    dist1 = np.linalg.norm(new.centers[:, None] - new.centers[None], axis=-1)
    np.testing.assert_allclose(dist1, s * dist0, atol=1e-9)
    rel0 = cams.w2c[:, None, :, :3] @ np.swapaxes(cams.w2c[None, :, :, :3], -1, -2)
    rel1 = new.w2c[:, None, :, :3] @ np.swapaxes(new.w2c[None, :, :, :3], -1, -2)
    np.testing.assert_allclose(rel1, rel0, atol=1e-9)
    assert s == pytest.approx(1 / (0.75 * cams.bounds[:, 0].min()))
    assert new.bounds[:, 0].min() == pytest.approx(1 / 0.75)
    avg = average_pose(new)
    assert rotation_angle_deg(avg[:, :3], np.eye(3)) < 1e-6 and np.abs(avg[:, 3]).max() < 1e-9


# ---------------------------------------------------------------- volume
def _edges(n_rays, n_s, dtype=torch.float32):
    return torch.linspace(0, 1, n_s + 1, dtype=dtype).expand(n_rays, -1)


def test_weights_sum_to_acc_at_most_one():
    torch.manual_seed(0)
    out = composite(torch.rand(50, 32) * 20, torch.rand(50, 32, 3), _edges(50, 32))
    assert torch.allclose(out["weights"].sum(-1), out["acc"])
    assert (out["acc"] <= 1 + 1e-6).all() and (out["weights"] >= 0).all()


def test_empty_rays_show_background():
    bg = torch.tensor([0.2, 0.5, 0.9])
    out = composite(torch.zeros(4, 16), torch.rand(4, 16, 3), _edges(4, 16), background=bg)
    assert torch.equal(out["acc"], torch.zeros(4))
    assert torch.allclose(out["rgb"], bg.expand(4, 3))


def test_opaque_first_sample_takes_all_weight():
    sig = torch.zeros(3, 8)
    sig[:, 0] = 1e6
    out = composite(sig, torch.rand(3, 8, 3), _edges(3, 8))
    assert torch.allclose(out["weights"][:, 0], torch.ones(3))
    assert torch.equal(out["weights"][:, 1:], torch.zeros(3, 7))


@pytest.mark.parametrize("value", [0.0, 1e-8, 1e6])
def test_gradients_finite(value):
    sig = torch.full((2, 16), value, dtype=torch.float64, requires_grad=True)
    rgb = torch.rand(2, 16, 3, dtype=torch.float64, requires_grad=True)
    out = composite(sig, rgb, _edges(2, 16, torch.float64))
    (out["rgb"].sum() + out["depth"].sum() + out["acc"].sum()).backward()
    assert torch.isfinite(sig.grad).all() and torch.isfinite(rgb.grad).all()
    assert torch.autograd.gradcheck(
        lambda s: composite(s, rgb.detach(), _edges(2, 16, torch.float64))["rgb"],
        (torch.rand(2, 16, dtype=torch.float64, requires_grad=True) * 3,),
    )


def test_constant_density_matches_beer_lambert():
    sigma, length = 0.7, 3.0
    edges = torch.linspace(0, length, 101, dtype=torch.float64)[None]
    out = composite(torch.full((1, 100), sigma, dtype=torch.float64), torch.ones(1, 100, 3, dtype=torch.float64), edges)
    assert out["acc"].item() == pytest.approx(1 - math.exp(-sigma * length), rel=1e-12)


@pytest.mark.parametrize("deterministic", [True, False])
def test_sample_pdf_sorted_inside_and_concentrated(deterministic):
    torch.manual_seed(0)
    bins = torch.sort(torch.rand(20, 17), -1).values
    w = torch.full((20, 16), 1e-3)
    w[:, 5] = 1.0
    t = sample_pdf(bins, w, 64, deterministic=deterministic)
    assert t.shape == (20, 64)
    assert (t[:, 1:] >= t[:, :-1]).all()
    assert (t >= bins[:, :1]).all() and (t <= bins[:, -1:]).all()
    in_bin = (t >= bins[:, 5:6]) & (t <= bins[:, 6:7])
    assert in_bin.float().mean() > 0.9


# ---------------------------------------------------------------- grid field
def test_trilinear_matches_hand_value():
    x, y, z = torch.meshgrid(*(torch.arange(3.0),) * 3, indexing="ij")  # flat rows: z fastest
    grid = (1 + 2 * x + 3 * y + 4 * z + 5 * x * y * z).reshape(-1, 1)  # multilinear: reproduced exactly
    p = torch.tensor([[0.5, 1.25, 1.5]])
    value = nerf_grid.trilinear(grid, 3, p)
    assert value.item() == pytest.approx(1 + 1 + 3.75 + 6 + 5 * 0.5 * 1.25 * 1.5)


def test_trilinear_gradcheck():
    torch.manual_seed(0)
    grid = torch.randn(27, 2, dtype=torch.float64, requires_grad=True)
    coords = (torch.rand(10, 3, dtype=torch.float64) * 1.8 + 0.1).requires_grad_()
    assert torch.autograd.gradcheck(lambda g, c: nerf_grid.trilinear(g, 3, c), (grid, coords))


def test_upsample_preserves_field():
    torch.manual_seed(0)
    model = nerf_grid.GridNeRF(replace(nerf_grid.GridConfig(), res_schedule=((0, 16),), channels=2))
    z, y, x = torch.meshgrid(*(torch.linspace(-1, 1, 16),) * 3, indexing="ij")
    field = torch.stack([torch.sin(2 * x) * torch.cos(y) + z, x * y - z**2], -1).reshape(-1, 2)
    model.features.data.copy_(field)
    pts = torch.rand(500, 3) * 2 - 1
    before = nerf_grid.trilinear(model.features, model.res, model.to_grid(pts)[0])
    model.upsample(31)
    after = nerf_grid.trilinear(model.features, model.res, model.to_grid(pts)[0])
    assert model.features.shape == (31**3, 2)
    assert (before - after).abs().max() < 0.02


def test_occupancy_marks_trained_empty_space():
    torch.manual_seed(0)
    cfg = replace(
        nerf_grid.GridConfig(),
        res_schedule=((0, 12),),
        n_samples=24,
        xy_extent=1.0,
        perturb=False,
        white_bkgd=True,
        occupancy_thres=1e-3,
    )
    model = nerf_grid.GridNeRF(cfg)
    assert model.update_occupancy() == 11**3  # α_init is above the threshold: all occupied at first
    opt = torch.optim.Adam([model.density], lr=0.3)  # the grey colour head cannot explain white: density must go
    for _ in range(40):  # empty space in front of the white background for x, y in [0.2, 1]
        o = torch.cat([torch.rand(256, 2) * 0.8 + 0.2, -torch.ones(256, 1)], 1)
        d = torch.tensor([0.0, 0.0, 2.0]).expand(256, 3)
        loss = ((model(o, d, train=True)["rgb"] - 1.0) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.update_occupancy()
    occ = model.occupancy.view(11, 11, 11)  # (x, y, z) cells; cell i spans NDC [-1 + i·2/11, -1 + (i+1)·2/11]
    assert not occ[7:, 7:].any()  # cells with x, y in [0.27, 1]: trained to empty
    assert occ[:4, :4].all()  # cells with x, y < -0.27: never seen, still occupied
    cap = model.capacity()
    assert cap["occupied_cells"] < cap["cells"] and cap["resolution"] == 12
    model.cfg = replace(cfg, occupancy_thres=cfg.alpha_init)  # the default: untrained cells are dropped too
    model.update_occupancy()
    assert not model.occupancy.view(11, 11, 11)[:4, :4].any()


def test_tv_loss_zero_for_constant_grids():
    model = nerf_grid.GridNeRF(replace(nerf_grid.GridConfig(), res_schedule=((0, 8),)))
    model.density.data.fill_(0.3)
    model.features.data.fill_(1.7)
    assert model.tv_loss().item() == 0.0
    model.features.data.normal_()
    assert model.tv_loss().item() > 0.0


@pytest.mark.parametrize("deferred", [True, False])
def test_grid_forward_shapes_and_ranges(ndc_data, deferred):
    cfg = replace(nerf_grid.GridConfig(), res_schedule=((0, 8),), n_samples=16, deferred=deferred)
    o, d, v, _ = (x[0, :100] for x in ndc_data)
    out = nerf_grid.GridNeRF(cfg)(o, d, train=True, viewdirs=v)
    assert out["rgb"].shape == (100, 3) and out["depth"].shape == out["acc"].shape == (100,)
    assert ((out["acc"] > 0) & (out["acc"] < 1)).all() and ((out["depth"] >= 0) & (out["depth"] <= 1)).all()
    out["rgb"].sum().backward()


def _random_grid_model(dtype=torch.float64, **overrides):
    """A 6³ grid model with random density / features and some empty cells, and 40 NDC rays."""
    gen = torch.Generator().manual_seed(0)
    cfg = replace(nerf_grid.GridConfig(), res_schedule=((0, 6),), n_samples=24, channels=3, xy_extent=1.0, **overrides)
    model = nerf_grid.GridNeRF(cfg).to(dtype)
    model.density.data = torch.randn(model.density.shape, generator=gen, dtype=dtype) * 3 + 1
    model.features.data = torch.randn(model.features.shape, generator=gen, dtype=dtype)
    model.occupancy = torch.rand(model.occupancy.shape, generator=gen) > 0.3
    o = torch.cat([torch.rand(40, 2, generator=gen, dtype=dtype) * 2.4 - 1.2, -torch.ones(40, 1, dtype=dtype)], 1)
    d = torch.cat([torch.rand(40, 2, generator=gen, dtype=dtype) * 0.6 - 0.3, torch.full((40, 1), 2.0, dtype=dtype)], 1)
    return model, o, d  # some rays leave the box through its sides


@pytest.mark.parametrize("min_trans", [0.0, 1e-3, 0.3])
def test_native_march_matches_batched_pytorch(min_trans):
    """The numba marcher and the batched PyTorch path: same colours, depth, acc and grid gradients
    (empty cells, rays leaving the box, low-weight skipping and early termination included)."""
    outs = []
    for native in (True, False):
        torch.manual_seed(1)
        model, o, d = _random_grid_model(native=native, min_trans=min_trans)
        out = model(o, d, train=True)
        (out["rgb"].square().sum() + out["depth"].sum() + out["acc"].sum()).backward()
        outs.append([out["rgb"], out["depth"], out["acc"], model.density.grad, model.features.grad])
    for a, b in zip(*outs):
        assert torch.allclose(a, b, rtol=1e-9, atol=1e-12)
    assert outs[0][3].abs().sum() > 0 and outs[0][4].abs().sum() > 0


def test_native_march_gradcheck():
    """Hand-written backward of the marcher against finite differences (float64)."""
    model, o, d = _random_grid_model()
    t = (torch.arange(24, dtype=torch.float64) + torch.rand(40, 24, dtype=torch.float64)) / 24
    args = (o, d, t, model.occupancy, model.box(), model.res, model.act_shift, 0.0, 0.0)

    def fn(density, features):
        return march_grid(density, features, *args)  # features, acc, depth

    density = (model.density.detach() * 0.3).requires_grad_()  # moderate τ: finite differences stay accurate
    assert torch.autograd.gradcheck(fn, (density, model.features.detach().clone().requires_grad_()))


def test_native_march_independent_of_ray_order_and_grad_mode():
    """The marcher visits rays in its own (spatially sorted) order and records samples only when a
    gradient is needed: permuting the rays permutes the outputs, with the same grid gradients, and
    a no-grad march gives the same outputs."""
    model, o, d = _random_grid_model()
    t = (torch.arange(24, dtype=torch.float64) + torch.rand(40, 24, dtype=torch.float64)) / 24
    args = (model.occupancy, model.box(), model.res, model.act_shift, 1e-4, 1e-3)
    perm = torch.randperm(40, generator=torch.Generator().manual_seed(3))
    weights = torch.randn(3, dtype=torch.float64)
    outs, grads = [], []
    for p in (torch.arange(40), perm):
        density, features = (x.detach().clone().requires_grad_() for x in (model.density, model.features))
        feat, acc, depth = march_grid(density, features, o[p], d[p], t[p], *args)
        ((feat @ weights) * acc + depth.square()).sum().backward()
        outs.append([x[torch.argsort(p)].detach() for x in (feat, acc, depth)])
        grads.append([density.grad, features.grad])
    with torch.no_grad():
        plain = march_grid(model.density, model.features, o, d, t, *args)
    for a, b, c in zip(outs[0], outs[1], plain):
        assert torch.allclose(a, b, rtol=1e-12, atol=1e-14) and torch.equal(a, c)
    for a, b in zip(*grads):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-13)


def test_march_softplus_matches_torch():
    """The marcher's softplus / sigmoid (``log(1 + eˣ)`` with a series for small eˣ) against torch."""
    from spc3d.reconstruct.volume import _softplus_sigmoid

    x = torch.cat(
        [torch.linspace(-60, 40, 2001, dtype=torch.float64), torch.tensor([-10.0, 20.0], dtype=torch.float64)]
    )
    sp, sig = zip(*(_softplus_sigmoid(float(v)) for v in x))
    assert torch.allclose(torch.tensor(sp, dtype=torch.float64), torch.nn.functional.softplus(x), rtol=1e-9, atol=0)
    assert torch.allclose(torch.tensor(sig, dtype=torch.float64), torch.sigmoid(x), rtol=1e-8, atol=0)


def test_tv_gradient_added_in_place_matches_autograd():
    model, _, _ = _random_grid_model(tv_density=0.3, tv_features=0.02)
    model.tv_loss().backward()
    expected = [model.density.grad.clone(), model.features.grad.clone()]
    model.density.grad, model.features.grad = None, None
    model.add_tv_grad()
    assert torch.allclose(model.density.grad, expected[0], rtol=1e-12) and torch.allclose(
        model.features.grad, expected[1], rtol=1e-12
    )
    model.float()  # float32 grids: the numba kernel's path
    g = model.features.detach().clone().requires_grad_()
    nerf_grid.total_variation(g, model.res).backward()
    direct = torch.zeros_like(g)
    nerf_grid.add_tv_grad(direct, g, model.res, 1.0)
    assert torch.allclose(direct, g.grad, rtol=1e-4, atol=1e-9)


def test_grid_trainer_resumes_bit_for_bit(scene):
    """Trainer state (fused Adam, occupancy, resolution) round-trips: 6 steps = 4 + resume + 2,
    across an upsample and occupancy refreshes."""
    from spc3d.reconstruct.nerf_trainer import RayTrainer
    from spc3d.reconstruct.objectives import RGBObjective
    from spc3d.reconstruct.views import Views

    cfg = replace(
        nerf_grid.GridConfig(), res_schedule=((0, 6), (4, 9)), n_samples=12, batch_rays=64, n_iters=6
    )  # fmt: skip
    cfg = replace(cfg, occupancy_warmup=2, occupancy_every=2)
    views = Views(torch.as_tensor(scene.images), scene.cameras, list(scene.names))

    def trainer():
        return RayTrainer(views, RGBObjective("mse"), "nerf-grid", cfg, seed=3, device="cpu")

    a = trainer()
    for it in range(1, 7):
        a.step(it)
    b = trainer()
    for it in range(1, 5):  # the grid grows at step 4: the resumed trainer must grow before loading
        b.step(it)
    state, torch_rng = b.state(), torch.get_rng_state()  # a checkpoint holds both (spc3d.checkpoints)
    c = trainer()
    c.load(state)
    torch.set_rng_state(torch_rng)
    for it in range(5, 7):
        c.step(it)
    for (name, pa), pc in zip(a.model.state_dict().items(), c.model.state_dict().values()):
        assert torch.equal(pa, pc), name


def test_learning_rates():
    cfg = nerf_grid.GridConfig()
    assert nerf_grid.lr_at(cfg.n_iters, cfg)["density"] == pytest.approx(cfg.lr_grid * cfg.lr_decay)
    opt = nerf_grid.make_optimizer(nerf_grid.GridNeRF(replace(cfg, res_schedule=((0, 8),))), cfg)
    assert {g["name"]: g["lr"] for g in opt.param_groups} == {"density": 1.0, "features": 1.0, "mlp": 1e-3}
    ncfg = nerf.NerfConfig()
    assert nerf.lr_at(0, ncfg)["mlp"] == 5e-4 and nerf.lr_at(ncfg.n_iters, ncfg)["mlp"] == pytest.approx(5e-5)


# ---------------------------------------------------------------- overfitting smoke tests
def _fit(model, opt, lr_fn, cfg, data, iters, batch, extra_loss):
    """Plain MSE loop on all views; returns PSNR of views 0-1 before and after."""
    o, d, v, c = (x.reshape(-1, 3) for x in data)
    first = _psnr(model, data)
    for step in range(iters):
        nerf.set_lr(opt, lr_fn(step, cfg))
        sel = torch.randint(0, o.shape[0], (batch,))
        out = model(o[sel], d[sel], train=True, viewdirs=v[sel])
        loss = ((out["rgb"] - c[sel]) ** 2).mean() + extra_loss(out, c[sel])
        opt.zero_grad()
        loss.backward()
        opt.step()
    return first, _psnr(model, data)


def _psnr(model, data):
    o, d, v, c = (x[:2].reshape(-1, 3) for x in data)
    with torch.no_grad():
        return psnr(model(o, d, train=False, viewdirs=v)["rgb"], c)


def test_grid_nerf_overfits(ndc_data):
    torch.manual_seed(0)
    cfg = replace(nerf_grid.GridConfig(), res_schedule=((0, 32),), n_samples=48, n_iters=80)
    model = nerf_grid.GridNeRF(cfg)
    opt = nerf_grid.make_optimizer(model, cfg)
    before, after = _fit(model, opt, nerf_grid.lr_at, cfg, ndc_data, 80, 1024, lambda out, c: model.tv_loss())
    assert after > before + 5.0, (before, after)


def test_nerf_overfits(ndc_data):
    torch.manual_seed(0)
    cfg = replace(nerf.nerf_preset("cpu"), width=48, n_coarse=16, n_fine=8, n_iters=120, lr=2e-3, lr_final=5e-4)
    model = nerf.NeRF(cfg)
    opt = nerf.make_optimizer(model, cfg)

    def coarse(out, c):
        return ((out["rgb_coarse"] - c) ** 2).mean()

    before, after = _fit(model, opt, nerf.lr_at, cfg, ndc_data, 120, 256, coarse)
    assert after > before + 5.0, (before, after)


def test_total_variation_value_and_closed_form_gradient():
    """The closed-form TV gradient against finite differences, and its value against the definition."""
    g = torch.randn(4**3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0), requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: nerf_grid.total_variation(x, 4), (g,))
    v = g.detach().view(4, 4, 4, 3)
    direct = (
        sum(((v.narrow(a, 1, 3) - v.narrow(a, 0, 3)) ** 2).mean() for a in range(3)) / 3.0
    )  # mean squared neighbour difference, averaged over the axes
    assert float(nerf_grid.total_variation(g.detach(), 4)) == pytest.approx(float(direct), rel=1e-12)

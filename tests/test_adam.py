"""FusedAdam is torch.optim.Adam(fused=True) to the bit, through density control's parameter swaps
and checkpoints in either optimizer's layout, and a stage-2 job never imports torch._dynamo."""

import subprocess
import sys

import pytest
import torch

from spc3d.reconstruct.adam import FusedAdam
from spc3d.reconstruct.densify import append, select


def _params(seed: int) -> list[torch.nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(shape, generator=g)) for shape in ((50, 3), (50, 15, 3), (7,))]


def _groups(params, lrs=(1e-2, 3e-3, 1e-1)):
    return [{"params": [p], "lr": lr, "name": f"p{i}"} for i, (p, lr) in enumerate(zip(params, lrs))]


def _grads(params, step: int, skip: int | None = None):
    g = torch.Generator().manual_seed(100 + step)
    for i, p in enumerate(params):
        p.grad = None if i == skip else torch.randn(p.shape, generator=g) * (10.0 ** (i - 2))


@pytest.mark.parametrize("betas,eps", [((0.9, 0.999), 1e-15), ((0.9, 0.99), 1e-8)])
def test_updates_are_torchs_fused_adam_to_the_bit(betas, eps):
    mine, ref = _params(0), _params(0)
    a = FusedAdam(_groups(mine), betas=betas, eps=eps)
    b = torch.optim.Adam(_groups(ref), betas=betas, eps=eps, fused=True)
    for step in range(12):
        skip = 1 if step % 5 == 3 else None  # a parameter without a gradient is left alone, as torch does
        _grads(mine, step, skip), _grads(ref, step, skip)
        a.param_groups[0]["lr"] = b.param_groups[0]["lr"] = 1e-2 / (1 + step)  # schedules set lr per step
        a.step(), b.step()
    for p, q in zip(mine, ref):
        assert torch.equal(p, q)
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(a.state[p][key], b.state[q][key]), key


class _Model:  # what densify's append / select swap: parameters by the names of PARAM_NAMES
    pass


def test_density_control_swaps_and_checkpoints_round_trip():
    """append / select replace parameters inside the optimizer with their moments; the state_dict
    of either optimizer loads into the other and the next steps stay identical."""
    from spc3d.reconstruct.gaussians import PARAM_NAMES

    g = torch.Generator().manual_seed(1)
    model = _Model()
    for name in PARAM_NAMES:
        setattr(model, name, torch.nn.Parameter(torch.randn(20, 3, generator=g)))
    opt = FusedAdam([{"params": [getattr(model, n)], "lr": 1e-2, "name": n} for n in PARAM_NAMES], eps=1e-15)
    params = lambda: [getattr(model, n) for n in PARAM_NAMES]  # noqa: E731
    for step in range(3):
        _grads(params(), step)
        opt.step()
    append(model, opt, {n: torch.randn(5, 3, generator=g) for n in PARAM_NAMES})
    select(model, opt, torch.arange(25) % 4 != 0)
    assert all(
        getattr(model, n).shape == (18, 3) and opt.state[getattr(model, n)]["exp_avg"].shape == (18, 3)
        for n in PARAM_NAMES
    )
    saved = opt.state_dict()

    def resumed(cls, **kw):
        copy = [torch.nn.Parameter(p.detach().clone()) for p in params()]
        o = cls([{"params": [p], "lr": 0.0, "name": n} for p, n in zip(copy, PARAM_NAMES)], eps=1e-15, **kw)
        o.load_state_dict(saved)
        for step in range(3, 6):
            _grads(copy, step)
            o.step()
        return copy, o

    mine, a = resumed(FusedAdam)
    ref, b = resumed(torch.optim.Adam, fused=True)
    assert a.param_groups[0]["lr"] == 1e-2  # hyper-parameters come back with the moments
    assert all(torch.equal(p, q) for p, q in zip(mine, ref))
    back = FusedAdam([{"params": [p], "lr": 0.0} for p in mine], eps=1e-15)
    back.load_state_dict(b.state_dict())  # torch's layout read back
    assert all(torch.equal(back.state[p]["exp_avg"], b.state[q]["exp_avg"]) for p, q in zip(mine, ref))


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="must be floating-point tensors"):
        FusedAdam([{"params": [torch.zeros(3, dtype=torch.int64)]}])
    opt = FusedAdam([{"params": [torch.nn.Parameter(torch.zeros(3))]}])
    with pytest.raises(ValueError, match="do not match"):
        opt.load_state_dict({"state": {}, "param_groups": []})
    with pytest.raises(ValueError, match=r"saved moments \(4,\)"):
        z = torch.zeros(4)
        opt.load_state_dict(
            {
                "state": {0: {"step": torch.tensor(1.0), "exp_avg": z, "exp_avg_sq": z}},
                "param_groups": [{"params": [0], "lr": 1e-3}],
            }
        )


def test_stage2_training_steps_do_not_import_dynamo():
    """The reason FusedAdam exists: torch.optim's step imports torch._dynamo (seconds of CPU per job);
    the grid NeRF, the MLP NeRF and 3DGS all step without it."""
    code = """
import sys, torch
from spc3d.cameras import split_views
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct.gaussians import GaussianConfig
from spc3d.reconstruct.nerf_grid import GridConfig, GridNeRF, make_optimizer
from spc3d.reconstruct.objectives import RGBObjective
from spc3d.reconstruct.splatting import SplatTrainer
from spc3d.reconstruct.views import Views
cfg = GridConfig(res_schedule=((0, 8),))
m = GridNeRF(cfg)
opt = make_optimizer(m, cfg)
for p in m.parameters():
    p.grad = torch.ones_like(p)
opt.step()
from spc3d.reconstruct.nerf import NeRF, NerfConfig, make_optimizer as mlp_optimizer
mlp = NeRF(NerfConfig())
opt = mlp_optimizer(mlp, NerfConfig())
for p in mlp.parameters():
    p.grad = torch.ones_like(p)
opt.step()
scene = render_scene("tabletop", 24, 32, views=3, supersample=1)
train, _ = split_views(3)
views = Views(torch.tensor(scene.images[train]), scene.cameras.subset(train), [scene.names[i] for i in train])
cfg = GaussianConfig(iterations=2, init_points=200)
trainer = SplatTrainer(views, RGBObjective("l1", cfg.ssim_weight), cfg)
trainer.step(1), trainer.step(2)
print("torch._dynamo" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr

"""Stage-2 reconstructors: one model per file, built through the plain registry ``RECONSTRUCTORS``.

    3dgs        3D Gaussian Splatting (gaussians.py, densify.py, splatting.py; rasterizer in splat/)
    nerf        the paper's NeRF: MLP with positional encoding, coarse + fine (nerf.py)
    nerf-grid   explicit density/feature grids, coarse-to-fine, occupancy skipping (nerf_grid.py)

Each entry maps ``(views, objective, settings, seed, points=None)`` to ``(trainer, iterations, config)``
(``points``: optional (xyz (M, 3), rgb (M, 3)) sparse points to start from; 3DGS uses them); a trainer
has ``step / render / capacity / state / load`` and is driven by :func:`spc3d.training.run`.
``objective`` None means the model's own RGB loss (3DGS: 0.8 L1 + 0.2 D-SSIM; NeRF: MSE); a
:class:`objectives.BernoulliObjective` fits binary frames through the SPAD likelihood instead, a
:class:`objectives.JointObjective` the likelihood plus the model's own loss towards stage-1 images.
Their settings dataclasses live in :mod:`spc3d.specs.reconstructors` (torch-free: the workflow builds
and checks them at parse time).
"""

from __future__ import annotations

from spc3d import specs
from spc3d.reconstruct.objectives import JointObjective, RGBObjective
from spc3d.specs.reconstructors import config_3dgs, config_nerf, config_nerf_grid


def own_objective(objective, own: RGBObjective):
    """The objective a model fits: its own RGB loss ``own`` when none is given; a joint objective
    without an image loss gets ``own`` as its prior term."""
    if objective is None:
        return own
    if isinstance(objective, JointObjective) and objective.image is None:
        objective.image = own
    return objective


def make_3dgs(views, objective, settings: dict, seed: int, points=None):
    from spc3d.reconstruct.splatting import SplatTrainer

    cfg = config_3dgs(settings)
    xyz, rgb = points if points is not None else (None, None)
    trainer = SplatTrainer(views, own_objective(objective, RGBObjective("l1", cfg.ssim_weight)), cfg, seed, xyz, rgb)
    return trainer, cfg.iterations, cfg


def make_nerf(views, objective, settings: dict, seed: int, points=None):  # points: unused by NeRF
    from spc3d.reconstruct.nerf_trainer import RayTrainer

    cfg = config_nerf(settings)
    return RayTrainer(views, own_objective(objective, RGBObjective("mse")), "nerf", cfg, seed), cfg.n_iters, cfg


def make_nerf_grid(views, objective, settings: dict, seed: int, points=None):  # points: unused
    from spc3d.reconstruct.nerf_trainer import RayTrainer

    cfg = config_nerf_grid(settings)
    return RayTrainer(views, own_objective(objective, RGBObjective("mse")), "nerf-grid", cfg, seed), cfg.n_iters, cfg


# name -> factory, from the specs of spc3d.specs (a spec names its factory as "module:function"; the
# built-in ones are the functions above). Their settings: spc3d.specs.reconstructors.reconstructor_config.
RECONSTRUCTORS = {name: specs.load(spec.factory) for name, spec in specs.RECONSTRUCTORS.items()}

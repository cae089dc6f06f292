"""Stage-2 reconstructors: one model per file, built through the plain registry ``RECONSTRUCTORS``.

    3dgs        3D Gaussian Splatting (gaussians.py, densify.py, splatting.py; rasterizer in splat/)
    nerf        the paper's NeRF: MLP with positional encoding, coarse + fine (nerf.py)
    nerf-grid   explicit density/feature grids, coarse-to-fine, occupancy skipping (nerf_grid.py)

Each entry maps ``(views, objective, settings, seed, points=None)`` to ``(trainer, iterations, config)``
(``points``: optional (xyz (M, 3), rgb (M, 3)) sparse points to start from; 3DGS uses them); a trainer
has ``step / render / capacity / state / load`` and is driven by :func:`spc3d.training.run`.
``objective`` None means the model's own RGB loss (3DGS: 0.8 L1 + 0.2 D-SSIM; NeRF: MSE); a
:class:`objectives.BernoulliObjective` fits binary frames through the SPAD likelihood instead.
``CONFIGS`` builds each model's settings dataclass alone (the workflow checks them at parse time).
"""

from __future__ import annotations

from ..training import build_config
from .objectives import RGBObjective


def config_3dgs(settings: dict):
    from .gaussians import GaussianConfig

    return build_config(GaussianConfig, settings, "stage2.3dgs")


def config_nerf(settings: dict):
    from .nerf import NerfConfig, nerf_preset

    settings = dict(settings)
    return build_config(NerfConfig, settings, "stage2.nerf", nerf_preset(settings.pop("preset", "paper")))


def config_nerf_grid(settings: dict):
    from .nerf_grid import GridConfig

    return build_config(GridConfig, settings, "stage2.nerf-grid")


def make_3dgs(views, objective, settings: dict, seed: int, points=None):
    from .splatting import SplatTrainer

    cfg = config_3dgs(settings)
    xyz, rgb = points if points is not None else (None, None)
    trainer = SplatTrainer(views, objective or RGBObjective("l1", cfg.ssim_weight), cfg, seed, xyz, rgb)
    return trainer, cfg.iterations, cfg


def make_nerf(views, objective, settings: dict, seed: int, points=None):  # points: unused by NeRF
    from .nerf_trainer import RayTrainer

    cfg = config_nerf(settings)
    return RayTrainer(views, objective or RGBObjective("mse"), "nerf", cfg, seed), cfg.n_iters, cfg


def make_nerf_grid(views, objective, settings: dict, seed: int, points=None):  # points: unused
    from .nerf_trainer import RayTrainer

    cfg = config_nerf_grid(settings)
    return RayTrainer(views, objective or RGBObjective("mse"), "nerf-grid", cfg, seed), cfg.n_iters, cfg


RECONSTRUCTORS = {"3dgs": make_3dgs, "nerf": make_nerf, "nerf-grid": make_nerf_grid}
# The settings dataclass of each model from its config block (checked at parse time: spc3d.config).
CONFIGS = {"3dgs": config_3dgs, "nerf": config_nerf, "nerf-grid": config_nerf_grid}

"""Stage-2 reconstructors: one model per file, built through the plain registry ``RECONSTRUCTORS``.

    3dgs        3D Gaussian Splatting (gaussians.py, densify.py, splatting.py; rasterizer in splat/)
    nerf        the paper's NeRF: MLP with positional encoding, coarse + fine (nerf.py)
    nerf-grid   explicit density/feature grids, coarse-to-fine, occupancy skipping (nerf_grid.py)

Each entry maps ``(views, objective, settings, seed, points=None)`` to ``(trainer, iterations, config)``
(``points``: optional (xyz (M, 3), rgb (M, 3)) sparse points to start from; 3DGS uses them); a trainer
has ``step / render / capacity / state / load`` and is driven by :func:`train.run`. ``objective``
None means the model's own RGB loss (3DGS: 0.8 L1 + 0.2 D-SSIM; NeRF: MSE); a
:class:`objectives.BernoulliObjective` fits binary frames through the SPAD likelihood instead.
"""

from __future__ import annotations

from ..training import build_config
from .objectives import RGBObjective


def make_3dgs(views, objective, settings: dict, seed: int, points=None):
    from .gaussians import GaussianConfig
    from .splatting import SplatTrainer

    cfg = build_config(GaussianConfig, settings, "stage2.3dgs")
    xyz, rgb = points if points is not None else (None, None)
    trainer = SplatTrainer(views, objective or RGBObjective("l1", cfg.ssim_weight), cfg, seed, xyz, rgb)
    return trainer, cfg.iterations, cfg


def make_nerf(views, objective, settings: dict, seed: int, points=None):  # points: unused by NeRF
    from .nerf import NerfConfig, nerf_preset
    from .nerf_trainer import RayTrainer

    settings = dict(settings)
    base = nerf_preset(settings.pop("preset", "paper"))
    cfg = build_config(NerfConfig, settings, "stage2.nerf", base)
    return RayTrainer(views, objective or RGBObjective("mse"), "nerf", cfg, seed), cfg.n_iters, cfg


def make_nerf_grid(views, objective, settings: dict, seed: int, points=None):  # points: unused
    from .nerf_grid import GridConfig
    from .nerf_trainer import RayTrainer

    cfg = build_config(GridConfig, settings, "stage2.nerf-grid")
    return RayTrainer(views, objective or RGBObjective("mse"), "nerf-grid", cfg, seed), cfg.n_iters, cfg


RECONSTRUCTORS = {"3dgs": make_3dgs, "nerf": make_nerf, "nerf-grid": make_nerf_grid}

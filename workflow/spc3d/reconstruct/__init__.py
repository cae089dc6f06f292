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
``CONFIGS`` builds each model's settings dataclass alone (the workflow checks them at parse time).
"""

from __future__ import annotations

import math

from spc3d import models
from spc3d.reconstruct.objectives import JointObjective, RGBObjective
from spc3d.training import build_config


def config_3dgs(settings: dict):
    from spc3d.reconstruct.gaussians import GaussianConfig

    return build_config(GaussianConfig, settings, "stage2.3dgs")


def config_nerf(settings: dict):
    from spc3d.reconstruct.nerf import NerfConfig, nerf_preset

    settings = dict(settings)
    return build_config(NerfConfig, settings, "stage2.nerf", nerf_preset(settings.pop("preset", "paper")))


def config_nerf_grid(settings: dict):
    from spc3d.reconstruct.nerf_grid import GridConfig

    return build_config(GridConfig, settings, "stage2.nerf-grid")


def config_joint(settings: dict):
    """stage2.joint: the joint rows' prior weight schedule and penalty (:class:`objectives.JointConfig`)."""
    from spc3d.reconstruct.objectives import JointConfig

    return build_config(JointConfig, settings, "stage2.joint")


def check_joint(joint: dict) -> None:
    """stage2.joint and each of its per-model entries, as :func:`config_joint` builds them."""
    from spc3d.names import joint_settings

    models, choose = joint.get("models") or {}, joint.get("choose") or {}
    for key, given in (("models", models), ("choose", choose)):
        unknown = sorted(set(given) - set(CONFIGS))
        if unknown:
            raise ValueError(f"stage2.joint.{key}: unknown model(s) {unknown}; use one of {sorted(CONFIGS)}")
    for model in [None, *models]:
        config_joint(joint_settings(joint, model))
    for model, candidates in choose.items():
        check_candidates(candidates, f"stage2.joint.choose.{model}")


def check_candidates(candidates, where: str) -> list[float]:
    """Candidate prior weights of a fold's choice (spc3d.choices): distinct finite numbers >= 0."""
    values = [float(c) for c in candidates or ()]
    if not values or any(not math.isfinite(v) or v < 0 for v in values) or len(set(values)) != len(values):
        raise ValueError(f"{where} = {candidates}: need distinct finite weights >= 0, e.g. [0.1, 0.3, 1.0]")
    return values


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


# name -> factory and name -> settings dataclass builder, from the specs of spc3d.models (a spec
# names its functions as "module:function"; the built-in ones are the functions above).
RECONSTRUCTORS = {name: models.load(spec.factory) for name, spec in models.RECONSTRUCTORS.items()}
CONFIGS = {name: models.load(spec.config) for name, spec in models.RECONSTRUCTORS.items()}

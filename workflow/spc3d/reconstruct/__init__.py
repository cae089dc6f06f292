"""Stage-2 reconstructors: one model per file, built through the plain registry ``RECONSTRUCTORS``.

    3dgs        3D Gaussian Splatting (gaussians.py, densify.py, splatting.py; rasterizer in splat/)
    nerf-mlp    the paper's NeRF: MLP with positional encoding, coarse + fine (nerf.py)
    nerf-grid   explicit density/feature grids, coarse-to-fine, occupancy skipping (nerf_grid.py)

Each model's factory lives with its trainer (``splatting.make_3dgs``, ``nerf_trainer.make_nerf``,
``nerf_trainer.make_nerf_grid``) and its spec in :mod:`spc3d.specs` names it. So a stage-2 fit's code
key (:func:`spc3d.settings.grid.Grid.reconstruct_code`) covers its own model's code and not the
others': editing the NeRF trainer refits no 3DGS row.

A factory maps ``(views, objective, settings, seed, points=None)`` to ``(trainer, iterations, config)``
(``points``: optional (xyz (M, 3), rgb (M, 3)) sparse points to start from; 3DGS uses them); a trainer
has ``step / render / capacity / state / load`` and is driven by :func:`spc3d.training.run`.
``objective`` None means the model's own RGB loss (3DGS: 0.8 L1 + 0.2 D-SSIM; NeRF: MSE); a
:class:`objectives.BernoulliObjective` fits binary frames through the SPAD likelihood instead, a
:class:`objectives.JointObjective` the likelihood plus the model's own loss towards stage-1 images
(:func:`objectives.own_objective`). Their settings dataclasses live in :mod:`spc3d.specs.reconstructors`
(torch-free: the workflow builds and checks them at parse time).
"""

from __future__ import annotations

from spc3d import specs


def __getattr__(name: str):
    """``RECONSTRUCTORS``, the plain dict name -> factory, from the specs of :mod:`spc3d.specs` (a spec names
    its factory as ``"module:function"``; their settings: ``spc3d.specs.reconstructors.reconstructor_config``).
    Built on first use, not at import: loading the factories imports every trainer, which importing
    any module of this package (the objectives, say) does not need."""
    if name != "RECONSTRUCTORS":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    registry = globals()["RECONSTRUCTORS"] = {n: specs.load(spec.factory) for n, spec in specs.RECONSTRUCTORS.items()}
    return registry

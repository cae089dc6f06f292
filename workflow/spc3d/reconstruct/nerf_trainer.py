"""Training of the NeRF family (``nerf``: MLP, ``nerf-grid``: explicit grid) on NDC rays.

The training cameras are recentred and rescaled as the LLFF NeRF does (:func:`rays.recenter`);
every training pixel becomes one NDC ray, and each step fits a random batch of rays. Evaluation
cameras are mapped by the same similarity. The MLP NeRF is supervised on its coarse and fine
outputs (as the original); the grid adds its total-variation gradient in place after the backward
pass (no full-grid temporaries), grows its resolution on the configured schedule and refreshes its
occupancy mask (empty-space skipping) periodically.

The model, the rays and the targets live on CUDA when it is available (else the CPU); renders are
returned on the CPU. A checkpoint holds tensors on the device it was written on.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from spc3d.cameras import Cameras, transform_cameras
from spc3d.evaluation.metrics import psnr
from spc3d.reconstruct import nerf, nerf_grid
from spc3d.reconstruct.objectives import RGBObjective, Scheduled, own_objective
from spc3d.reconstruct.rays import camera_rays, ndc_rays, recenter, view_dirs
from spc3d.reconstruct.views import Views, hold_out
from spc3d.reconstruct.volume import render_chunked
from spc3d.specs.reconstructors import config_nerf, config_nerf_grid
from spc3d.training import Plateau, default_device, set_lr


def all_rays(cams: Cameras, idx) -> tuple[Tensor, Tensor, Tensor]:
    """NDC origins, NDC directions and unit world view directions of every pixel of views ``idx``."""
    o_all, d_all, v_all = [], [], []
    for i in idx:
        o, d = camera_rays(cams, int(i))
        fx, fy = cams.intrinsics[int(i), :2]
        o_n, d_n = ndc_rays(o, d, float(fx), float(fy), cams.width, cams.height)
        o_all.append(o_n), d_all.append(d_n), v_all.append(view_dirs(d))
    return torch.cat(o_all), torch.cat(d_all), torch.cat(v_all)


class RayTrainer:
    """Fits a NeRF (``kind`` "nerf": the MLP of model ``nerf-mlp``) or GridNeRF (``kind``
    "nerf-grid") to ``views`` on ``device`` (default: CUDA if available, else CPU)."""

    def __init__(
        self, views: Views, objective, kind: str, cfg, seed: int = 0, device: str | torch.device | None = None
    ):
        torch.manual_seed(seed)
        self.kind, self.cfg, self.objective = kind, cfg, objective
        self.views, self.check = hold_out(views, cfg.plateau_views if objective.stops_on_plateau else 0)
        views = self.views
        self.device = torch.device(device) if device is not None else default_device()
        self.cams, self.similarity = recenter(views.cameras)
        self.rays = tuple(r.to(self.device) for r in all_rays(self.cams, range(len(self.cams))))
        self.targets = views.targets.reshape(-1, views.targets.shape[-1]).to(self.device)
        self.model = (nerf.NeRF(cfg) if kind == "nerf" else nerf_grid.GridNeRF(cfg)).to(self.device)
        self.lib = nerf if kind == "nerf" else nerf_grid
        self.opt = self.lib.make_optimizer(self.model, cfg)
        self.rng = np.random.default_rng(seed)
        # A grid still growing on its schedule is not on a plateau: no stop before its last step.
        start = max(it for it, _ in cfg.res_schedule) if kind == "nerf-grid" else 0
        self.plateau = Plateau.of(cfg, objective.stops_on_plateau, start)  # (see objectives.py)
        self.plateau.views = self.check.names if self.check else []
        self.check_rays = []  # per held-out view: (NDC origins, directions, view dirs, targets) on the device
        if self.check:
            cams = transform_cameras(self.check.cameras, *self.similarity)
            for j in range(len(cams)):
                rays = (r.to(self.device) for r in all_rays(cams, [j]))
                target = self.check.targets[j].reshape(-1, self.check.targets.shape[-1]).to(self.device)
                self.check_rays.append((*rays, target))

    def step(self, it: int) -> dict:
        if self.kind == "nerf-grid":
            self._grid_schedule(it)
        set_lr(self.opt, self.lib.lr_at(it, self.cfg))
        if isinstance(self.objective, Scheduled):
            self.objective.at(it / self.cfg.n_iters)
        sel = torch.as_tensor(self.rng.integers(self.targets.shape[0], size=self.cfg.batch_rays), device=self.device)
        out = self.model(self.rays[0][sel], self.rays[1][sel], train=True, viewdirs=self.rays[2][sel])
        target = self.targets[sel]
        loss = self.objective.loss(out["rgb"], target)
        if self.kind == "nerf" and self.model.fine is not None:
            loss = loss + self.objective.loss(out["rgb_coarse"], target)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.kind == "nerf-grid":
            self.model.add_tv_grad()  # the total-variation term's gradient, added in place
        self.opt.step()
        value = loss.item()
        self.plateau.observe(it, value, 0, self.check_loss if self.check else None)
        rgb = self.objective.name == "rgb"
        return {"loss": value, "psnr": psnr(out["rgb"].clamp(0, 1), target) if rgb else math.nan}

    def _grid_schedule(self, it: int) -> None:
        """Coarse-to-fine growth and periodic occupancy refresh of the grid."""
        res = self.model.res_for_step(it)
        if res != self.model.res:
            self.model.upsample(res)
            self.opt = self.lib.make_optimizer(self.model, self.cfg, it)  # new parameter tensors
        if it >= self.cfg.occupancy_warmup and it % self.cfg.occupancy_every == 0:
            self.model.update_occupancy()

    def should_stop(self) -> bool:
        """The training objective has stopped improving (:class:`spc3d.training.Plateau`)."""
        return self.plateau.should_stop()

    @torch.no_grad()
    def render(self, cams: Cameras, i: int) -> Tensor:
        view = transform_cameras(cams.subset([i]), *self.similarity)
        o, d, v = (r.to(self.device) for r in all_rays(view, [0]))
        out = render_chunked(self.model, o, d, v, chunk=self.cfg.chunk)
        return self.objective.to_srgb(out["rgb"]).reshape(cams.height, cams.width, -1).cpu()

    @torch.no_grad()
    def check_loss(self) -> float:
        """The training objective on the views held out of the fit (mapped as the training cameras)."""
        losses = [
            self.objective.loss(render_chunked(self.model, o, d, v, chunk=self.cfg.chunk)["rgb"], target).item()
            for o, d, v, target in self.check_rays
        ]
        return float(np.mean(losses))

    def capacity(self) -> dict:
        if self.kind == "nerf-grid":
            return self.model.capacity()
        return {"parameters": int(sum(p.numel() for p in self.model.parameters()))}

    def state(self) -> dict:
        return {
            "model": self.model.state_dict(),
            "opt": self.opt.state_dict(),
            "rng": self.rng.bit_generator.state,
            "res": getattr(self.model, "res", None),
            "plateau": self.plateau.state(),
        }

    def load(self, state: dict) -> None:
        if self.kind == "nerf-grid" and state["res"] != self.model.res:
            self.model.upsample(state["res"])  # shapes first; values come from the state dict
            self.model.occupancy = state["model"]["occupancy"].to(self.device, copy=True)
        self.model.load_state_dict(state["model"])
        self.opt = self.lib.make_optimizer(self.model, self.cfg)
        self.opt.load_state_dict(state["opt"])
        self.rng.bit_generator.state = state["rng"]
        self.plateau.load(state["plateau"])


def make_nerf(views, objective, settings: dict, seed: int, points=None):  # points: unused by NeRF
    """The ``nerf-mlp`` factory (:data:`spc3d.reconstruct.RECONSTRUCTORS`); its own loss is the MSE."""
    cfg = config_nerf(settings)
    return RayTrainer(views, own_objective(objective, RGBObjective("mse")), "nerf", cfg, seed), cfg.n_iters, cfg


def make_nerf_grid(views, objective, settings: dict, seed: int, points=None):  # points: unused
    """The ``nerf-grid`` factory (:data:`spc3d.reconstruct.RECONSTRUCTORS`); its own loss is the MSE."""
    cfg = config_nerf_grid(settings)
    return RayTrainer(views, own_objective(objective, RGBObjective("mse")), "nerf-grid", cfg, seed), cfg.n_iters, cfg

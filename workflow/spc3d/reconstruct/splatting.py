"""3DGS training: one random training view per step, per-parameter Adam, density control.

Learning rates as the reference implementation (Kerbl et al. 2023, graphdeco-inria/gaussian-splatting,
``arguments/__init__.py``): positions 1.6e-4 -> 1.6e-6 times
the scene extent, decayed exponentially over the run; SH DC 2.5e-3 (rest / 20), opacity 0.05,
scales 5e-3, rotations 1e-3. The active SH degree rises by one every ``sh_interval`` iterations,
but only while it still pays: if the mean loss over the last interval did not drop by at least
0.5 % against the interval before, the degree stays (capacity follows the scene).

Training stops with a FloatingPointError naming the iteration when the loss is not finite (a
NaN target, say: it would turn every Gaussian and Adam moment into NaN) or when no Gaussian is
finite any more (checked every ``densify_every`` iterations; non-finite Gaussians are never
drawn and get zero gradient). A camera the projection rejects (non-finite pose or intrinsics)
raises its CameraError with the camera's index.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from spc3d.cameras import Cameras
from spc3d.evaluation.metrics import psnr
from spc3d.reconstruct.adam import FusedAdam
from spc3d.reconstruct.densify import DensityControl
from spc3d.reconstruct.gaussians import PARAM_NAMES, GaussianConfig, GaussianModel, initial_model, scene_extent
from spc3d.reconstruct.objectives import RGBObjective, Scheduled, own_objective
from spc3d.reconstruct.pose_refine import PoseCorrections, RowAdam, heldout_cameras
from spc3d.reconstruct.splat.project import CameraError
from spc3d.reconstruct.views import Views, hold_out
from spc3d.specs.reconstructors import config_3dgs
from spc3d.training import Plateau


def make_optimizer(model: GaussianModel, cfg: GaussianConfig, extent: float) -> FusedAdam:
    lrs = {
        "means": cfg.lr_means * extent,
        "log_scales": cfg.lr_scales,
        "quats": cfg.lr_quats,
        "opacity_logits": cfg.lr_opacity,
        "sh_dc": cfg.lr_sh_dc,
        "sh_rest": cfg.lr_sh_rest,
    }
    groups = [{"params": [getattr(model, n)], "lr": lrs[n], "name": n} for n in PARAM_NAMES]
    # fused: one pass over each parameter per step instead of ~10 tensor ops (same update, the
    # last bits may differ from the op-by-op path); torch.optim.Adam(fused=True)'s kernel (adam.py)
    return FusedAdam(groups, lr=0.0, eps=1e-15)


def log_linear(it: int, start: int, end: int, first: float, last: float) -> float:
    """Exponential (log-linear) decay from ``first`` at iteration ``start`` to ``last`` at ``end``."""
    if first == last:  # a constant lr, exactly (exp(log(x)) need not round back to x)
        return first
    t = min(max((it - start) / max(end - start, 1), 0.0), 1.0)
    return math.exp((1 - t) * math.log(first) + t * math.log(last))


def means_lr(it: int, cfg: GaussianConfig, extent: float) -> float:
    """Exponential decay from lr_means to lr_means_final over the run, times extent."""
    return extent * log_linear(it, 0, cfg.iterations, cfg.lr_means, cfg.lr_means_final)


def pose_lr(it: int, cfg: GaussianConfig) -> float:
    """The camera corrections' lr: exponential decay from pose_lr (at pose_from) to pose_lr_final."""
    return log_linear(it, cfg.pose_from, cfg.iterations, cfg.pose_lr, cfg.pose_lr_final)


class SplatTrainer:
    """Fits a :class:`GaussianModel` to ``views`` under ``objective`` (see objectives.py)."""

    def __init__(
        self,
        views: Views,
        objective,
        cfg: GaussianConfig,
        seed: int = 0,
        points: np.ndarray | None = None,
        colors: np.ndarray | None = None,
    ):
        self.objective, self.cfg = objective, cfg
        self.views, self.check = hold_out(views, cfg.plateau_views if objective.stops_on_plateau else 0)
        views = self.views
        self.extent = scene_extent(views.cameras)
        self.model = initial_model(views.cameras, cfg, seed, points, colors)
        self.opt = make_optimizer(self.model, cfg, self.extent)
        self.control = DensityControl(self.model, cfg, self.extent, seed)
        self.background = torch.tensor(cfg.background, dtype=torch.float32)
        self.rng = np.random.default_rng(seed)
        self.losses: list[float] = []
        self.degree_loss = math.inf  # mean loss of the interval before the last degree decision
        self.poses = PoseCorrections(views.cameras, self.extent) if cfg.pose_refine else None
        self.pose_opt = RowAdam(self.poses.delta) if self.poses else None
        self.plateau = Plateau.of(cfg, objective.stops_on_plateau)  # (see objectives.py)
        self.plateau.views = self.check.names if self.check else []

    def step(self, it: int) -> dict:
        # The density-control pass of the previous step runs here, not at its end: a training that
        # stops at step k (or a window judged at k) ends on the fitted model, not on one whose new
        # Gaussians have not been fitted yet. A full run performs the same operations in the same order.
        if it > 1:
            self.control.step(it - 1, self.model, self.opt)
        for group in self.opt.param_groups:
            if group["name"] == "means":
                group["lr"] = means_lr(it, self.cfg, self.extent)
        if isinstance(self.objective, Scheduled):
            self.objective.at(it / self.cfg.iterations)
        i = int(self.rng.integers(len(self.views.cameras)))
        refine = self.poses is not None and it >= self.cfg.pose_from
        out = self._render(self.views.cameras, i, self.poses.motion(i) if refine else None)
        out["proj"].means2d.retain_grad()
        loss = self.objective.loss(out["image"], self.views.targets[i])
        value = loss.item()
        if not math.isfinite(value):  # it would turn every Gaussian and Adam moment into NaN
            raise FloatingPointError(
                f"3DGS training stopped at iteration {it}: the loss on training view {i} is {value} "
                f"({int(torch.isfinite(out['image']).all(-1).sum())} of {out['image'][..., 0].numel()} pixels "
                f"rendered finite, target finite: {bool(torch.isfinite(self.views.targets[i]).all())}, "
                f"{int(self.finite_gaussians().sum())} of {len(self.model)} Gaussians finite)"
            )
        if it % self.cfg.densify_every == 0 and not self.finite_gaussians().any():
            raise FloatingPointError(
                f"3DGS training stopped at iteration {it}: none of the {len(self.model)} "
                "Gaussians has finite parameters any more"
            )
        self.opt.zero_grad(set_to_none=True)
        if refine:
            self.pose_opt.zero_grad()
        loss.backward()
        self.control.observe(
            out["proj"].means2d, out["proj"].radii, self.views.cameras.height, self.views.cameras.width
        )
        self.opt.step()
        if refine:
            self.pose_opt.step(i, pose_lr(it, self.cfg))
        self.losses = self.losses[-(self.cfg.sh_interval - 1) :] + [value]  # one interval is all it needs
        self.plateau.observe(it, value, i, self.check_loss if self.check else None)
        if it % self.cfg.sh_interval == 0:
            self.maybe_raise_degree()
        # Training PSNR only means something against image targets (not against bit fractions).
        rgb = self.objective.name == "rgb"
        return {"loss": value, "psnr": psnr(out["image"].clamp(0, 1), self.views.targets[i]) if rgb else math.nan}

    def should_stop(self) -> bool:
        """The training objective has stopped improving (:class:`spc3d.training.Plateau`)."""
        return self.plateau.should_stop()

    @torch.no_grad()
    def check_loss(self) -> float:
        """The training objective on the views held out of the fit: their cameras as given, or with
        refined training cameras, mapped into the refined world as the scored views are (a drift of
        the whole refined world must not read as a worse fit)."""
        cams, targets = self.heldout_cameras(self.views.cameras, self.check.cameras), self.check.targets
        losses = [self.objective.loss(self._render(cams, j)["image"], targets[j]).item() for j in range(len(cams))]
        return float(np.mean(losses))

    def maybe_raise_degree(self) -> None:
        """Raise the SH degree while the loss still improves by >= 0.5 % per interval."""
        recent = float(np.mean(self.losses[-self.cfg.sh_interval :]))
        if self.model.active_degree < self.cfg.sh_degree and recent < 0.995 * self.degree_loss:
            self.model.active_degree += 1
        self.degree_loss = recent

    def _render(self, cams: Cameras, i: int, motion=None) -> dict:
        """``model.render`` of view i (moved by ``motion``: a camera correction); a camera the
        projection rejects is named by its index."""
        try:
            return self.model.render(cams, i, self.background, self.cfg.backend, motion)
        except CameraError as e:
            msg = str(e).removeprefix("camera: ")
            raise CameraError(f"camera {i} (of {len(cams)}): {msg}") from None

    def finite_gaussians(self) -> Tensor:
        """(N,) bool: the Gaussians whose parameters are all finite (the others are never drawn)."""
        ok = torch.ones(len(self.model), dtype=torch.bool)
        for n in PARAM_NAMES:
            fin = torch.isfinite(getattr(self.model, n).detach())
            ok &= fin.flatten(1).all(1) if fin.dim() > 1 else fin
        return ok

    @torch.no_grad()
    def render(self, cams: Cameras, i: int) -> Tensor:
        out = self._render(cams, i)
        return self.objective.to_srgb(out["image"])

    def capacity(self) -> dict:
        return self.model.capacity() | {"densify": self.control.history}

    def heldout_cameras(self, reference_train: Cameras, reference_test: Cameras) -> Cameras:
        """Where to render the held-out views: their reference cameras, or with refined training
        cameras, those mapped into the refined world (:func:`.pose_refine.heldout_cameras`)."""
        if self.poses is None:
            return reference_test
        return heldout_cameras(self.poses.refined(self.views.cameras), reference_train, reference_test)

    def state(self) -> dict:
        return {
            "params": {n: getattr(self.model, n).detach().clone() for n in PARAM_NAMES},
            "active_degree": self.model.active_degree,
            "opt": self.opt.state_dict(),
            "control": (self.control.grad_sum, self.control.count, self.control.max_radii),
            "split_rng": self.control.generator.get_state(),
            "rng": self.rng.bit_generator.state,
            "losses": self.losses,
            "degree_loss": self.degree_loss,
            "plateau": self.plateau.state(),
            "densify": [list(h) for h in self.control.history],
            "poses": None if self.poses is None else (self.poses.delta.detach().clone(), self.pose_opt.state_dict()),
        }

    def load(self, state: dict) -> None:
        for n in PARAM_NAMES:
            setattr(self.model, n, torch.nn.Parameter(state["params"][n]))
        self.model.active_degree = state["active_degree"]
        self.opt = make_optimizer(self.model, self.cfg, self.extent)
        self.opt.load_state_dict(state["opt"])
        self.control.grad_sum, self.control.count, self.control.max_radii = state["control"]
        self.control.generator.set_state(state["split_rng"])
        self.rng.bit_generator.state = state["rng"]
        self.losses, self.degree_loss = state["losses"], state["degree_loss"]
        self.plateau.load(state["plateau"])
        self.control.history = [list(h) for h in state["densify"]]
        if self.poses is not None:
            delta, opt = state["poses"]
            with torch.no_grad():
                self.poses.delta.copy_(delta)
            self.pose_opt.load_state_dict(opt)


def make_3dgs(views, objective, settings: dict, seed: int, points=None):
    """The ``3dgs`` factory (:data:`spc3d.reconstruct.RECONSTRUCTORS`): a trainer of the settings' config, started
    from ``points`` (xyz, rgb) when given; its own loss is 0.8 L1 + 0.2 D-SSIM (``ssim_weight``)."""
    cfg = config_3dgs(settings)
    xyz, rgb = points if points is not None else (None, None)
    trainer = SplatTrainer(views, own_objective(objective, RGBObjective("l1", cfg.ssim_weight)), cfg, seed, xyz, rgb)
    return trainer, cfg.iterations, cfg

"""Adaptive density control of 3DGS: capacity goes where the gradients ask for it, and only there.

Every iteration, for the Gaussians visible in the rendered view, accumulate the norm of the
view-space positional gradient (``means2d.grad`` converted to NDC units, i.e. scaled by W/2, H/2,
which is what 3DGS's threshold 2e-4 refers to) and the largest screen radius. Every
``densify_every`` iterations inside [densify_from, densify_until]:

- **clone** small Gaussians (max scale <= percent_dense x extent) whose mean gradient exceeds the
  threshold (under-reconstruction: a copy at the same place, the optimiser pulls them apart);
- **split** large ones (over-reconstruction) into two, sampled from the Gaussian, scales / 1.6;
- **prune** Gaussians with opacity < prune_opacity and, after the first opacity reset, those wider
  than max_screen_size pixels on screen or 0.1 x extent in the world;
- never grow beyond ``max_gaussians`` (the highest-gradient candidates win).

Every ``opacity_reset_every`` iterations opacities are clamped to <= 0.01, so that Gaussians that
are not needed fade and get pruned. The Adam state follows every change (moments of copies are
zero, moments of pruned Gaussians are dropped).
"""

from __future__ import annotations

import torch
from torch import Tensor

from spc3d.reconstruct.adam import FusedAdam
from spc3d.reconstruct.gaussians import PARAM_NAMES, GaussianConfig, GaussianModel
from spc3d.reconstruct.splat import quat_to_rotmat


class DensityControl:
    """Gradient statistics and the clone / split / prune / reset operations."""

    def __init__(self, model: GaussianModel, cfg: GaussianConfig, extent: float, seed: int = 0):
        self.cfg, self.extent = cfg, extent
        self.generator = torch.Generator().manual_seed(seed)  # own stream: checkpoints restore it
        self.history: list[list[int]] = []  # [iteration, Gaussians before, cloned, split, pruned, after]
        self.reset_stats(len(model))

    def reset_stats(self, n: int) -> None:
        self.grad_sum, self.count, self.max_radii = torch.zeros(n), torch.zeros(n), torch.zeros(n)

    def observe(self, means2d: Tensor, radii: Tensor, height: int, width: int) -> None:
        """Accumulate after ``loss.backward()``; ``means2d`` had ``retain_grad()``."""
        visible = radii > 0
        if means2d.grad is None:
            return
        # masks by torch.where rather than boolean indexing (no gathers and scatters); invisible
        # Gaussians add exactly 0 and keep their maximum
        g = means2d.grad * torch.tensor([width / 2.0, height / 2.0])  # pixel -> NDC units
        self.grad_sum += torch.where(visible, g.norm(dim=-1), 0.0)
        self.count += visible
        torch.where(visible, torch.maximum(self.max_radii, radii), self.max_radii, out=self.max_radii)

    def step(self, it: int, model: GaussianModel, opt: FusedAdam) -> None:
        """Run the schedule for iteration ``it`` (1-based)."""
        c = self.cfg
        if c.densify_from < it <= c.densify_until and it % c.densify_every == 0:
            before = len(model)
            cloned, split = self.densify_and_prune(model, opt, prune_big=it > c.opacity_reset_every)
            self.history.append([it, before, cloned, split, before + cloned + split - len(model), len(model)])
        if it <= c.densify_until and it % c.opacity_reset_every == 0:
            reset_opacity(model, opt)

    def densify_and_prune(self, model: GaussianModel, opt: FusedAdam, prune_big: bool) -> tuple[int, int]:
        """One density-control pass; returns (Gaussians cloned, Gaussians split)."""
        grads = self.grad_sum / self.count.clamp_min(1)  # clamp: never-seen Gaussians have 0 / 0
        big = model.scales.detach().max(1).values > self.cfg.percent_dense * self.extent
        cand = grads >= self.cfg.densify_grad
        room = max(self.cfg.max_gaussians - len(model), 0)
        cand = cap_candidates(cand, grads, room)  # a clone adds one; a split adds two, removes one
        clone, split = cand & ~big, cand & big
        new = concat_dicts(clone_params(model, clone), split_params(model, split, self.generator))
        n_old = len(model)
        append(model, opt, new)
        keep = torch.ones(len(model), dtype=torch.bool)
        keep[:n_old] &= ~split  # split parents are replaced by their two children
        keep &= model.opacities.detach() >= self.cfg.prune_opacity
        if prune_big:
            radii = torch.cat([self.max_radii, torch.zeros(len(model) - n_old)])
            keep &= (radii <= self.cfg.max_screen_size) & (model.scales.detach().max(1).values <= 0.1 * self.extent)
        if keep.sum() == 0:
            keep[model.opacities.detach().argmax()] = True  # never prune to an empty model
        select(model, opt, keep)
        self.reset_stats(len(model))
        return int(clone.sum()), int(split.sum())


def cap_candidates(cand: Tensor, grads: Tensor, room: int) -> Tensor:
    """Keep at most ``room`` candidates, those with the highest mean gradient."""
    if int(cand.sum()) <= room:
        return cand
    out = torch.zeros_like(cand)
    out[torch.where(cand, grads, torch.full_like(grads, -1.0)).topk(room).indices] = True
    return out


def clone_params(model: GaussianModel, mask: Tensor) -> dict[str, Tensor]:
    return {name: getattr(model, name).detach()[mask] for name in PARAM_NAMES}


def split_params(
    model: GaussianModel, mask: Tensor, generator: torch.Generator | None = None, n: int = 2
) -> dict[str, Tensor]:
    """Two children per masked Gaussian, centred at samples of it, scales divided by 0.8 n."""
    p = clone_params(model, mask)
    scales = p["log_scales"].exp().repeat(n, 1)
    rots = quat_to_rotmat(p["quats"]).repeat(n, 1, 1)
    noise = torch.randn(scales.shape, generator=generator)
    offset = (rots @ (noise * scales)[:, :, None])[:, :, 0]
    out = {k: v.repeat(n, *([1] * (v.dim() - 1))) for k, v in p.items()}
    out["means"] = out["means"] + offset
    out["log_scales"] = (scales / (0.8 * n)).log()
    return out


def concat_dicts(a: dict[str, Tensor], b: dict[str, Tensor]) -> dict[str, Tensor]:
    return {k: torch.cat([a[k], b[k]]) for k in a}


def append(model: GaussianModel, opt: FusedAdam, new: dict[str, Tensor]) -> None:
    """Add Gaussians; their Adam moments start at zero."""
    for name in PARAM_NAMES:
        old = getattr(model, name)
        param = torch.nn.Parameter(torch.cat([old.detach(), new[name]]).contiguous())
        _replace_in_optimizer(opt, old, param, lambda s, added=new[name]: torch.cat([s, torch.zeros_like(added)]))
        setattr(model, name, param)


def select(model: GaussianModel, opt: FusedAdam, keep: Tensor) -> None:
    """Keep only the Gaussians where ``keep`` is True (parameters and Adam moments)."""
    for name in PARAM_NAMES:
        old = getattr(model, name)
        param = torch.nn.Parameter(old.detach()[keep].contiguous())
        _replace_in_optimizer(opt, old, param, lambda s: s[keep])
        setattr(model, name, param)


def reset_opacity(model: GaussianModel, opt: FusedAdam, ceiling: float = 0.01) -> None:
    """Clamp opacities to <= ``ceiling`` and zero their Adam moments (3DGS's opacity reset)."""
    logit = torch.logit(torch.tensor(ceiling))
    old = model.opacity_logits
    param = torch.nn.Parameter(torch.minimum(old.detach(), logit).contiguous())
    _replace_in_optimizer(opt, old, param, torch.zeros_like)
    model.opacity_logits = param


def _replace_in_optimizer(opt: FusedAdam, old: Tensor, new: Tensor, fix_state) -> None:
    """Swap ``old`` for ``new`` in its param group, mapping Adam's moment tensors with ``fix_state``."""
    for group in opt.param_groups:
        for i, p in enumerate(group["params"]):
            if p is old:
                state = opt.state.pop(old, None)
                group["params"][i] = new
                if state:
                    opt.state[new] = {
                        k: (fix_state(v) if k in ("exp_avg", "exp_avg_sq") else v) for k, v in state.items()
                    }
                return
    raise KeyError("parameter not found in the optimizer")

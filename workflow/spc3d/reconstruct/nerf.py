"""NeRF (Mildenhall et al. 2020) for forward-facing scenes, rendered along NDC rays.

Rays come in already mapped to NDC (:func:`spc3d.reconstruct.rays.ndc_rays`), with t ∈ [0, 1]
from the near plane to infinity. A coarse MLP is evaluated at stratified samples; a fine MLP at
the union of those and inverse-CDF samples drawn from the coarse weights. The loss the paper uses
is MSE on both ``rgb_coarse`` and ``rgb``.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from spc3d.reconstruct.adam import FusedAdam
from spc3d.reconstruct.volume import composite, edges_from_points, sample_pdf, stratified_t
from spc3d.specs.reconstructors import NerfConfig, nerf_preset  # noqa: F401 - nerf_preset: part of this module's API
from spc3d.training import set_lr  # noqa: F401 - set_lr: part of this module's API (lr_at -> set_lr)


def positional_encoding(x: torch.Tensor, n_freqs: int) -> torch.Tensor:
    """(..., D) -> (..., D·(1 + 2·n_freqs)): x, then sin and cos of 2^k x for k < n_freqs."""
    scales = 2.0 ** torch.arange(n_freqs, dtype=x.dtype, device=x.device)
    xs = (x[..., None, :] * scales[:, None]).flatten(-2)  # (..., L·D)
    return torch.cat([x, torch.sin(xs), torch.cos(xs)], dim=-1)


class NerfMLP(nn.Module):
    """The paper's MLP: PE(xyz) -> density and feature; [feature, PE(dir)] -> rgb."""

    def __init__(self, cfg: NerfConfig):
        super().__init__()
        self.cfg = cfg
        in_xyz, in_dir = 3 * (1 + 2 * cfg.freqs_xyz), 3 * (1 + 2 * cfg.freqs_dir)
        dims = [in_xyz] + [cfg.width + (in_xyz if i - 1 in cfg.skips else 0) for i in range(1, cfg.depth)]
        self.trunk = nn.ModuleList(nn.Linear(d, cfg.width) for d in dims)
        self.sigma = nn.Linear(cfg.width, 1)
        self.feature = nn.Linear(cfg.width, cfg.width)
        view_in = cfg.width + (in_dir if cfg.use_viewdirs else 0)
        self.view = nn.Linear(view_in, cfg.width // 2)
        self.rgb = nn.Linear(cfg.width // 2, 3)

    def forward(self, xyz: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz (N, 3), dirs (N, 3) unit -> raw density (N,), rgb (N, 3) in [0, 1]."""
        x = positional_encoding(xyz, self.cfg.freqs_xyz)
        h = x
        for i, layer in enumerate(self.trunk):
            h = F.relu(layer(h))
            if i in self.cfg.skips:
                h = torch.cat([x, h], dim=-1)
        sigma = self.sigma(h).squeeze(-1)
        feat = self.feature(h)
        if self.cfg.use_viewdirs:
            feat = torch.cat([feat, positional_encoding(dirs, self.cfg.freqs_dir)], dim=-1)
        return sigma, torch.sigmoid(self.rgb(F.relu(self.view(feat))))


class NeRF(nn.Module):
    """Coarse + fine NeRF on NDC rays."""

    def __init__(self, cfg: NerfConfig = NerfConfig()):
        super().__init__()
        self.cfg = cfg
        self.coarse = NerfMLP(cfg)
        self.fine = NerfMLP(cfg) if cfg.n_fine > 0 else None

    def _render(self, mlp: NerfMLP, o, d, vd, t, edges, train: bool) -> dict[str, torch.Tensor]:
        """t (R, S) sample parameters, edges (R, S+1) -> composite dict."""
        n_rays, n_s = t.shape
        pts = o[:, None] + t[..., None] * d[:, None]  # (R, S, 3)
        raw, rgb = mlp(pts.reshape(-1, 3), vd[:, None].expand(-1, n_s, -1).reshape(-1, 3))
        raw = raw.view(n_rays, n_s)
        if train and self.cfg.raw_noise_std > 0:
            raw = raw + torch.randn_like(raw) * self.cfg.raw_noise_std
        bg = 1.0 if self.cfg.white_bkgd else 0.0
        return composite(F.relu(raw), rgb.view(n_rays, n_s, 3), edges, bg, dir_norm=d.norm(dim=-1))

    def forward(
        self, rays_o: torch.Tensor, rays_d: torch.Tensor, train: bool, viewdirs: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """NDC rays_o, rays_d (R, 3); viewdirs (R, 3) unit world directions (default: normalised rays_d).

        Returns rgb_coarse (R, 3), rgb (R, 3), depth (R,) (NDC t), acc (R,) — of the fine pass when
        there is one.
        """
        vd = viewdirs if viewdirs is not None else rays_d / rays_d.norm(dim=-1, keepdim=True)
        t, edges = stratified_t(rays_o.shape[0], self.cfg.n_coarse, train and self.cfg.perturb, device=rays_o.device)
        out_c = self._render(self.coarse, rays_o, rays_d, vd, t, edges, train)
        if self.fine is None:
            return {"rgb_coarse": out_c["rgb"], "rgb": out_c["rgb"], "depth": out_c["depth"], "acc": out_c["acc"]}
        t_f = sample_pdf(edges, out_c["weights"], self.cfg.n_fine, deterministic=not (train and self.cfg.perturb))
        t_all = torch.sort(torch.cat([t, t_f], dim=-1), dim=-1).values
        out_f = self._render(self.fine, rays_o, rays_d, vd, t_all, edges_from_points(t_all), train)
        return {"rgb_coarse": out_c["rgb"], "rgb": out_f["rgb"], "depth": out_f["depth"], "acc": out_f["acc"]}


def lr_at(step: int, cfg: NerfConfig) -> dict[str, float]:
    """Learning rate per parameter group at ``step``: lr · (lr_final / lr)^(step / n_iters)."""
    return {"mlp": cfg.lr * (cfg.lr_final / cfg.lr) ** (step / max(cfg.n_iters, 1))}


def make_optimizer(model: NeRF, cfg: NerfConfig) -> FusedAdam:
    """Adam (β = 0.9, 0.999, as the paper) over all weights, one group named 'mlp' (the fused
    kernel, without torch.optim's start-up cost: adam.py)."""
    return FusedAdam([{"params": list(model.parameters()), "name": "mlp", "lr": cfg.lr}], betas=(0.9, 0.999))


__all__ = ["NerfConfig", "nerf_preset", "NeRF", "NerfMLP", "positional_encoding", "lr_at", "make_optimizer", "set_lr"]

"""A DVGO / Plenoxels-like explicit-grid NeRF for forward-facing scenes, on NDC rays.

Two dense voxel grids over the NDC box [−e, e]² × [−1, 1] (z_ndc = 2t − 1, so t ∈ [0, 1] spans the
frustum from the near plane to infinity): a density grid (1 channel, activated by softplus with a
shift so that the initial per-sample α equals ``alpha_init``) and a feature grid decoded by a small
MLP with the encoded viewing direction. Grid values live at the R³ vertices, vertex i of an axis at
lo + i (hi − lo) / (R − 1) (``align_corners=True``), stored flat (R³, C) with z fastest: vertex
(ix, iy, iz) is row (ix·R + iy)·R + iz (NDC rays run mostly along z, so a ray's consecutive samples
read neighbouring rows).

On the CPU the deferred model renders with :func:`.volume.march_grid` (numba): per ray it skips
samples outside the box or in empty cells, stops once the transmittance falls to ``min_trans`` and
gathers features only where a sample's weight exceeds ``weight_thres``. Elsewhere (CUDA, or
``native=False``) the same samples go through batched PyTorch: trilinear interpolation as a
weighted sum of 8 gathered rows (``F.embedding_bag`` with per-sample weights forward, ``index_add_``
backward), which lets density and features be gathered for different subsets of the samples.

After ``upsample`` the parameters are new tensors: build a new optimizer (DVGO does the same).
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F
from numba import njit

from spc3d.reconstruct.adam import FusedAdam
from spc3d.reconstruct.nerf import positional_encoding
from spc3d.reconstruct.volume import accumulate, composite_weights, march_grid, stratified_t
from spc3d.specs.reconstructors import GridConfig


def corner_weights(coords: torch.Tensor, res: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Vertex rows (N, 8) and trilinear weights (N, 8) of grid coords (N, 3) (x, y, z in [0, R−1])."""
    i0 = coords.detach().floor().clamp(0, res - 2)  # the last cell owns the upper boundary
    f = coords - i0
    i0 = i0.long()
    base = (i0[:, 0] * res + i0[:, 1]) * res + i0[:, 2]
    dx, dy, dz = torch.meshgrid(*(torch.arange(2, device=coords.device),) * 3, indexing="ij")
    offs = ((dx * res + dy) * res + dz).reshape(8)
    wx = torch.stack([1 - f[:, 0], f[:, 0]], -1)
    wy = torch.stack([1 - f[:, 1], f[:, 1]], -1)
    wz = torch.stack([1 - f[:, 2], f[:, 2]], -1)
    w = wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]  # (N, 2, 2, 2) x, y, z
    return base[:, None] + offs, w.reshape(-1, 8)


class _WeightedGather(torch.autograd.Function):
    """out[n] = Σ_k w[n, k] · grid[idx[n, k]]: forward by ``embedding_bag``, grid gradient by ``index_add_``.

    ``embedding_bag``'s own backward sorts the indices, which made it slower than ``index_add_``.
    """

    @staticmethod
    def forward(ctx, grid: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(grid, idx, w)
        return F.embedding_bag(idx, grid, per_sample_weights=w, mode="sum")

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        grid, idx, w = ctx.saved_tensors
        grad_grid = grad_w = None
        if ctx.needs_input_grad[0]:
            rows = (grad_out[:, None, :] * w[..., None]).reshape(-1, grid.shape[1])  # (N·8, C)
            grad_grid = torch.zeros_like(grid).index_add_(0, idx.reshape(-1), rows)
        if ctx.needs_input_grad[2]:
            grad_w = (grid[idx] * grad_out[:, None, :]).sum(-1)  # (N, 8)
        return grad_grid, None, grad_w


def weighted_gather(grid: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Flat grid (V, C), rows idx (N, 8), weights w (N, 8) -> (N, C)."""
    return _WeightedGather.apply(grid, idx, w)


def trilinear(grid: torch.Tensor, res: int, coords: torch.Tensor) -> torch.Tensor:
    """Interpolate a flat grid (R³, C) at grid coords (N, 3) -> (N, C)."""
    idx, w = corner_weights(coords, res)
    return weighted_gather(grid, idx, w)


class _TotalVariation(torch.autograd.Function):
    """TV = (1/3) Σ_axes mean((g[i+1] − g[i])²) of a grid (R, R, R, C), with its gradient in closed
    form (:func:`add_tv_grad`).

    Autograd through ``narrow`` / ``pow`` allocated and zero-filled a full-grid tensor per slice and
    per power (12 per step for two grids): at 96³ x 13 channels that was ~40 % of a training step.
    """

    @staticmethod
    def forward(ctx, g: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(g)
        res = g.shape[0]
        return sum(torch.square(g.narrow(a, 1, res - 1) - g.narrow(a, 0, res - 1)).mean() for a in range(3)) / 3.0

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        (g,) = ctx.saved_tensors
        grad = torch.zeros_like(g)
        add_tv_grad(grad.view(-1, g.shape[-1]), g.view(-1, g.shape[-1]), g.shape[0], grad_out)
        return grad


def total_variation(grid: torch.Tensor, res: int) -> torch.Tensor:
    """Mean squared difference of neighbouring vertices over the three axes of a flat grid (R³, C)."""
    return _TotalVariation.apply(grid.view(res, res, res, -1))


def add_tv_grad(grad: torch.Tensor, grid: torch.Tensor, res: int, weight) -> None:
    """grad (R³, C) += weight · d total_variation(grid) / d grid, in place (DVGO's
    ``total_variation_add_grad``): each difference d along an axis adds 2d/(3N) to the vertex after
    it and subtracts it from the one before (N: differences per axis, (R − 1) R² C).

    On the CPU a numba kernel (a vertex's gradient is s · Σ_neighbours (g_v − g_n)); elsewhere, or
    for a 0-dim tensor ``weight`` (autograd's incoming gradient), three PyTorch passes.
    """
    g = grid.detach()
    if g.device.type == "cpu" and not torch.is_tensor(weight) and grad.is_contiguous() and g.is_contiguous():
        scale = 2.0 * weight / (3.0 * (res - 1) * res * res * g.shape[1])
        _tv_add_grad(g.numpy(), grad.numpy(), res, grad.numpy().dtype.type(scale))  # scale in the grid's dtype
        return
    g4, grad4 = g.view(res, res, res, -1), grad.view(res, res, res, -1)
    for a in range(3):
        d = g4.narrow(a, 1, res - 1) - g4.narrow(a, 0, res - 1)
        d.mul_(weight * 2.0 / (3.0 * d.numel()))
        grad4.narrow(a, 1, res - 1).add_(d)
        grad4.narrow(a, 0, res - 1).sub_(d)


@njit(cache=True, nogil=True)
def _tv_add_grad(g, grad, res, scale):
    """grad[v] += scale · Σ_n (g[v] − g[n]) over the (up to 6) axis neighbours n of every vertex v.

    Line by line (a z line of R·C contiguous values, z fastest), one neighbour direction per pass:
    each pass is a contiguous, vectorised loop over an L1-resident line of ``grad`` (much faster
    than one loop over vertices with six tests each).
    """
    n_c = g.shape[1]
    line, sx = res * n_c, res * res * n_c  # elements per z line; stride of x
    g1, gr = g.reshape(-1), grad.reshape(-1)
    for ix in range(res):
        for iy in range(res):
            a = (ix * res + iy) * line
            if ix > 0:
                _add_diff(gr, g1, a, a - sx, line, scale)
            if ix < res - 1:
                _add_diff(gr, g1, a, a + sx, line, scale)
            if iy > 0:
                _add_diff(gr, g1, a, a - line, line, scale)
            if iy < res - 1:
                _add_diff(gr, g1, a, a + line, line, scale)
            _add_diff(gr, g1, a + n_c, a, line - n_c, scale)  # z − 1
            _add_diff(gr, g1, a, a + n_c, line - n_c, scale)  # z + 1


@njit(inline="always")
def _add_diff(gr, g1, a, b, n, scale):
    """gr[a : a + n] += scale · (g1[a : a + n] − g1[b : b + n])."""
    out, x, y = gr[a : a + n], g1[a : a + n], g1[b : b + n]
    for j in range(n):
        out[j] += scale * (x[j] - y[j])


def resample(grid: torch.Tensor, res: int, new_res: int) -> torch.Tensor:
    """Trilinear resampling of a flat grid (R³, C) to (R'³, C) (vertex-aligned)."""
    g = grid.view(res, res, res, -1).permute(3, 0, 1, 2)[None]  # (1, C, X, Y, Z)
    g = F.interpolate(g, size=(new_res,) * 3, mode="trilinear", align_corners=True)
    return g[0].permute(1, 2, 3, 0).reshape(new_res**3, -1).contiguous()


class ColourHead(nn.Module):
    """[features, PE(viewdir)] -> rgb in [0, 1]."""

    def __init__(self, cfg: GridConfig):
        super().__init__()
        dims = [cfg.channels + 3 * (1 + 2 * cfg.freqs_dir)] + [cfg.mlp_width] * cfg.mlp_depth
        layers: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            layers += [nn.Linear(a, b), nn.ReLU(inplace=True)]
        self.net = nn.Sequential(*layers, nn.Linear(dims[-1], 3))
        self.freqs_dir = cfg.freqs_dir

    def forward(self, feat: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """feat (K, C), dirs (K, 3) -> rgb (K, 3)."""
        return torch.sigmoid(self.net(torch.cat([feat, positional_encoding(dirs, self.freqs_dir)], -1)))


class GridNeRF(nn.Module):
    """Density + feature voxel grids with a small colour head, rendered on NDC rays."""

    def __init__(self, cfg: GridConfig = GridConfig()):
        super().__init__()
        self.cfg = cfg
        self.res = cfg.res_schedule[0][1]
        self.density = nn.Parameter(torch.zeros(self.res**3, 1))
        self.features = nn.Parameter(torch.zeros(self.res**3, cfg.channels))
        self.head = ColourHead(cfg)
        # softplus(shift) = −log(1 − α_init) / step: the initial α of one sample is α_init
        self.act_shift = math.log(math.expm1(-math.log1p(-cfg.alpha_init) / cfg.step_ref))
        e = cfg.xy_extent
        self.register_buffer("lo", torch.tensor([-e, -e, -1.0]))
        self.register_buffer("hi", torch.tensor([e, e, 1.0]))
        self.register_buffer("occupancy", torch.ones((self.res - 1) ** 3, dtype=torch.bool))

    def to_grid(self, pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """NDC points (N, 3) -> grid coords (N, 3) in [0, R−1] and inside-box mask (N,)."""
        u = (pts - self.lo) / (self.hi - self.lo)
        inside = ((u >= 0) & (u <= 1)).all(-1)
        return u * (self.res - 1), inside

    def cell_index(self, coords: torch.Tensor) -> torch.Tensor:
        """Flat cell index (N,) of grid coords (N, 3) inside the box."""
        c = coords.detach().floor().long().clamp(0, self.res - 2)  # upper boundary -> last cell
        n = self.res - 1
        return (c[:, 0] * n + c[:, 1]) * n + c[:, 2]

    def sigma(self, raw: torch.Tensor) -> torch.Tensor:
        """Density activation: softplus(raw + shift)."""
        return F.softplus(raw + self.act_shift)

    def forward(
        self, rays_o: torch.Tensor, rays_d: torch.Tensor, train: bool, viewdirs: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """NDC rays (R, 3) -> rgb (R, 3), depth (R,) (NDC t), acc (R,), rgb_coarse (= rgb)."""
        vd = viewdirs if viewdirs is not None else rays_d / rays_d.norm(dim=-1, keepdim=True)
        perturb = train and self.cfg.perturb
        t, edges = stratified_t(rays_o.shape[0], self.cfg.n_samples, perturb, device=rays_o.device, dtype=rays_o.dtype)
        bg = 1.0 if self.cfg.white_bkgd else 0.0
        if self.cfg.deferred:
            if self.cfg.native and rays_o.device.type == "cpu":
                ray_feat, acc, depth = march_grid(
                    self.density, self.features, rays_o, rays_d, t, self.occupancy, self.box(), self.res,
                    self.act_shift, self.cfg.weight_thres, self.cfg.min_trans,
                )  # fmt: skip
            else:
                ray_feat, acc, depth = self._march_torch(rays_o, rays_d, t, edges)
            colour = self.head(ray_feat / acc.detach().clamp(min=1e-6)[:, None], vd)  # clamp: empty rays have acc 0
            out = {"rgb": acc[:, None] * colour + (1.0 - acc)[:, None] * bg, "depth": depth, "acc": acc}
        else:
            weights, ids, idx, w = self._weights(rays_o, rays_d, t, edges)
            mids = 0.5 * (edges[:, 1:] + edges[:, :-1])
            out = accumulate(weights, self._colours(weights, ids, idx, w, vd), mids, edges[:, -1], bg)
        return {"rgb_coarse": out["rgb"], "rgb": out["rgb"], "depth": out["depth"], "acc": out["acc"]}

    def box(self) -> tuple[float, ...]:
        """The grid box for :func:`march_grid`: lo (3) and vertex spacing⁻¹ (R − 1) / (hi − lo) (3)."""
        return tuple(self.lo.tolist()) + tuple(((self.res - 1) / (self.hi - self.lo)).tolist())

    def _weights(self, rays_o, rays_d, t, edges):
        """Compositing weights (R, S) of the samples t (R, S); the kept samples' flat ids (M,) and their
        vertex rows / trilinear weights (M, 8)."""
        n_rays, n_s = t.shape
        coords, inside = self.to_grid((rays_o[:, None] + t[..., None] * rays_d[:, None]).reshape(-1, 3))
        keep = inside.clone()
        keep[inside] = self.occupancy[self.cell_index(coords[inside])]
        ids = keep.nonzero().squeeze(-1)  # (M,) samples that are inside occupied cells
        idx, w = corner_weights(coords[ids], self.res)
        sig = weighted_gather(self.density, idx, w).squeeze(-1)
        sigma = torch.zeros(n_rays * n_s, dtype=sig.dtype, device=sig.device).index_put((ids,), self.sigma(sig))
        deltas = (edges[:, 1:] - edges[:, :-1]) * rays_d.norm(dim=-1, keepdim=True)
        return composite_weights(sigma.view(n_rays, n_s), deltas, self.cfg.min_trans), ids, idx, w

    def _march_torch(self, rays_o, rays_d, t, edges) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Batched PyTorch twin of :func:`march_grid`: composited features (R, C), acc (R,), depth (R,)."""
        weights, ids, idx, w = self._weights(rays_o, rays_d, t, edges)
        sel = weights.detach().view(-1)[ids] > self.cfg.weight_thres
        ids_c = ids[sel]
        feat = weighted_gather(self.features, idx[sel], w[sel]) * weights.view(-1)[ids_c, None]  # (K, C)
        ray_feat = torch.zeros(weights.shape[0], feat.shape[1], dtype=feat.dtype, device=feat.device).index_add(
            0, ids_c // t.shape[1], feat
        )
        acc, mids = weights.sum(-1), 0.5 * (edges[:, 1:] + edges[:, :-1])
        depth = (weights * mids).sum(-1) + (1.0 - acc) * edges[:, -1]
        return ray_feat, acc, depth

    def _colours(self, weights, ids, idx, w, vd) -> torch.Tensor:
        """rgb (R, S, 3): the colour head on samples with weight > weight_thres, 0 elsewhere."""
        sel = weights.detach().view(-1)[ids] > self.cfg.weight_thres
        ids_c = ids[sel]
        feat = weighted_gather(self.features, idx[sel], w[sel])
        rgb = self.head(feat, vd[ids_c // weights.shape[1]])
        out = torch.zeros(weights.numel(), 3, dtype=rgb.dtype, device=rgb.device).index_put((ids_c,), rgb)
        return out.view(*weights.shape, 3)

    @torch.no_grad()
    def update_occupancy(self) -> int:
        """Mark cells whose α at their 8 vertices (the max over the cell, trilinearly) is below the threshold.

        Returns the number of occupied cells.
        """
        r = self.res
        alpha = -torch.expm1(-self.sigma(self.density.view(1, 1, r, r, r)) * self.cfg.step_ref)
        cell_max = F.max_pool3d(alpha, kernel_size=2, stride=1)  # (1, 1, R−1, R−1, R−1)
        self.occupancy = (cell_max > self.cfg.occupancy_thres).reshape(-1)
        return int(self.occupancy.sum())

    @torch.no_grad()
    def upsample(self, new_res: int) -> None:
        """Trilinearly resample both grids to new_res³ (replaces the parameters) and refresh occupancy."""
        self.density = nn.Parameter(resample(self.density.data, self.res, new_res))
        self.features = nn.Parameter(resample(self.features.data, self.res, new_res))
        self.res = new_res
        self.update_occupancy()

    def res_for_step(self, step: int) -> int:
        """Grid resolution the schedule prescribes at ``step``."""
        return max((it, r) for it, r in self.cfg.res_schedule if it <= step)[1]

    def tv_loss(self) -> torch.Tensor:
        """Weighted total variation of the density and feature grids (0 for constant grids)."""
        return self.cfg.tv_density * total_variation(self.density, self.res) + self.cfg.tv_features * total_variation(
            self.features, self.res
        )

    @torch.no_grad()
    def add_tv_grad(self) -> None:
        """Add the gradient of ``tv_loss`` to the grids' ``.grad`` (after ``backward``, before the
        optimizer step): the same update as backpropagating ``tv_loss``, without its temporaries."""
        for grid, weight in ((self.density, self.cfg.tv_density), (self.features, self.cfg.tv_features)):
            if weight > 0:
                if grid.grad is None:
                    grid.grad = torch.zeros_like(grid)
                add_tv_grad(grid.grad, grid, self.res, weight)

    def capacity(self) -> dict[str, int]:
        """Grid resolution, occupied / total cells, and parameter count."""
        return {
            "resolution": self.res,
            "occupied_cells": int(self.occupancy.sum()),
            "cells": (self.res - 1) ** 3,
            "parameters": sum(p.numel() for p in self.parameters()),
        }


def lr_at(step: int, cfg: GridConfig) -> dict[str, float]:
    """Learning rate per parameter group at ``step`` (exponential decay by ``lr_decay`` over n_iters)."""
    f = cfg.lr_decay ** (step / max(cfg.n_iters, 1))
    return {"density": cfg.lr_grid * f, "features": cfg.lr_grid * f, "mlp": cfg.lr_mlp * f}


def make_optimizer(model: GridNeRF, cfg: GridConfig, step: int = 0) -> FusedAdam:
    """Adam (β = 0.9, 0.99, as DVGO) with groups 'density', 'features', 'mlp' at ``lr_at(step)``."""
    lrs = lr_at(step, cfg)
    groups = [
        {"params": [model.density], "name": "density"},
        {"params": [model.features], "name": "features"},
        {"params": list(model.head.parameters()), "name": "mlp"},
    ]
    for g in groups:
        g["lr"] = lrs[g["name"]]
    # one fused kernel per group: ~6x faster than the foreach step on a 96³ x 13 grid (one CPU core);
    # torch.optim.Adam(fused=True)'s kernel without torch.optim's start-up cost (adam.py)
    return FusedAdam(groups, betas=(0.9, 0.99))

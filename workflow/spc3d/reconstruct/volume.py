"""Volume rendering: numerically stable compositing and inverse-CDF (hierarchical) sampling.

Compositing along a ray with samples i = 0..S−1, densities σ_i ≥ 0 and interval lengths δ_i > 0:

    τ_i = σ_i δ_i,   α_i = 1 − exp(−τ_i) = −expm1(−τ_i),   log T_i = −Σ_{j<i} τ_j,   w_i = T_i α_i

Transmittance stays in log space (an exclusive cumulative sum), so there is no product of many
(1 − α) factors to underflow, and σ = 1e6 gives w = 1 at the first sample and exact zeros after.
"""

from __future__ import annotations

import torch

_LOG_T_MIN = -80.0  # exp below about -87 is denormal in float32 (slow on CPU); T < e^-80 is set to 0
_TAU_MAX = 1e4  # optical depth of one interval is capped: α = 1 to float precision far below this


def interval_lengths(t_vals: torch.Tensor, n_samples: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(deltas (R, S), mids (R, S)) from edges (R, S+1) or deltas (R, S).

    For deltas the mids are measured from 0: cumsum(δ) − δ/2.
    """
    if t_vals.shape[-1] == n_samples + 1:
        return t_vals[..., 1:] - t_vals[..., :-1], 0.5 * (t_vals[..., 1:] + t_vals[..., :-1])
    if t_vals.shape[-1] == n_samples:
        return t_vals, torch.cumsum(t_vals, -1) - 0.5 * t_vals
    raise ValueError(f"t_vals must have S+1={n_samples + 1} edges or S={n_samples} deltas, got {t_vals.shape[-1]}")


def composite_weights(sigmas: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """Weights (R, S) from densities (R, S) and interval lengths (R, S)."""
    tau = (sigmas.clamp(min=0.0) * deltas.clamp(min=0.0)).clamp(max=_TAU_MAX)  # σ ≥ 0 and δ ≥ 0 physically
    alpha = -torch.expm1(-tau)
    log_t = -(torch.cumsum(tau, -1) - tau)  # exclusive cumulative sum
    trans = torch.where(log_t > _LOG_T_MIN, torch.exp(log_t.clamp(min=_LOG_T_MIN)), torch.zeros_like(log_t))
    return trans * alpha


def composite(
    sigmas: torch.Tensor, rgbs: torch.Tensor, t_vals: torch.Tensor, background=0.0, dir_norm: torch.Tensor | None = None
) -> dict[str, torch.Tensor]:
    """Alpha-composite S samples on R rays.

    sigmas (R, S); rgbs (R, S, 3); t_vals: edges (R, S+1) or deltas (R, S) in ray-parameter units;
    dir_norm (R,) optional |d| turning parameter intervals into distances; background: float or (3,)
    or (R, 3), added with the leftover transmittance. Returns rgb (R, 3), depth (R,) (expected
    parameter, the leftover mass placed at the far end), acc (R,), weights (R, S).
    """
    deltas, mids = interval_lengths(t_vals, sigmas.shape[-1])
    t_end = t_vals[..., -1] if t_vals.shape[-1] == sigmas.shape[-1] + 1 else mids[..., -1] + 0.5 * t_vals[..., -1]
    if dir_norm is not None:
        deltas = deltas * dir_norm[:, None]
    return accumulate(composite_weights(sigmas, deltas), rgbs, mids, t_end, background)


def accumulate(
    weights: torch.Tensor, rgbs: torch.Tensor, mids: torch.Tensor, t_end: torch.Tensor, background=0.0
) -> dict[str, torch.Tensor]:
    """Sum weighted samples: weights (R, S), rgbs (R, S, 3), mids (R, S), t_end (R,) -> composite dict."""
    acc = weights.sum(-1)
    bg = torch.as_tensor(background, dtype=rgbs.dtype, device=rgbs.device)
    rgb = (weights[..., None] * rgbs).sum(-2) + (1.0 - acc)[:, None] * bg
    depth = (weights * mids).sum(-1) + (1.0 - acc) * t_end
    return {"rgb": rgb, "depth": depth, "acc": acc, "weights": weights}


def stratified_t(
    n_rays: int, n_samples: int, perturb: bool, near: float = 0.0, far: float = 1.0, device=None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(points (R, S), edges (R, S+1)): one sample per uniform bin, jittered when ``perturb``."""
    edges = torch.linspace(near, far, n_samples + 1, device=device).expand(n_rays, -1)
    u = torch.rand(n_rays, n_samples, device=device) if perturb else torch.full((n_rays, n_samples), 0.5, device=device)
    return edges[:, :-1] + u * (edges[:, 1:] - edges[:, :-1]), edges


def edges_from_points(points: torch.Tensor, near: float = 0.0, far: float = 1.0) -> torch.Tensor:
    """Edges (R, S+1) around sorted points (R, S): midpoints between them, plus near and far."""
    mids = 0.5 * (points[:, 1:] + points[:, :-1])
    lo = torch.full_like(points[:, :1], near)
    hi = torch.full_like(points[:, :1], far)
    return torch.cat([lo, mids, hi], dim=1)


def sample_pdf(
    bins: torch.Tensor, weights: torch.Tensor, n_samples: int, deterministic: bool = False, eps: float = 1e-5
) -> torch.Tensor:
    """Inverse-CDF samples (R, n) from the piecewise-constant pdf of weights (R, B) on edges (R, B+1).

    Sorted along each ray and inside [bins[:, 0], bins[:, -1]]. ``deterministic`` uses evenly spaced
    quantiles. ``eps`` is added to every weight so that rays with all-zero weights sample uniformly.
    """
    w = weights.detach() + eps
    cdf = torch.cumsum(w / w.sum(-1, keepdim=True), -1)
    cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf], -1)  # (R, B+1)
    n_rays = weights.shape[0]
    if deterministic:
        u = torch.linspace(0.0, 1.0, n_samples + 2, device=weights.device)[1:-1].expand(n_rays, -1)
    else:
        u = torch.rand(n_rays, n_samples, device=weights.device).sort(-1).values
    u = u.contiguous()
    hi = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)  # bin index + 1
    lo = hi - 1
    c0, c1 = cdf.gather(-1, lo), cdf.gather(-1, hi)
    b0, b1 = bins.detach().gather(-1, lo), bins.detach().gather(-1, hi)
    frac = ((u - c0) / (c1 - c0).clamp(min=1e-12)).clamp(0.0, 1.0)  # empty bins: avoid 0/0
    return b0 + frac * (b1 - b0)


@torch.no_grad()
def render_chunked(
    model, rays_o: torch.Tensor, rays_d: torch.Tensor, viewdirs: torch.Tensor | None = None, chunk: int = 4096
) -> dict[str, torch.Tensor]:
    """Evaluate ``model(rays_o, rays_d, train=False, viewdirs=...)`` in chunks of rays (no grad)."""
    outs: dict[str, list] = {}
    for i in range(0, rays_o.shape[0], chunk):
        vd = None if viewdirs is None else viewdirs[i : i + chunk]
        for k, v in model(rays_o[i : i + chunk], rays_d[i : i + chunk], train=False, viewdirs=vd).items():
            outs.setdefault(k, []).append(v)
    return {k: torch.cat(v) for k, v in outs.items()}

"""Volume rendering: numerically stable compositing and inverse-CDF (hierarchical) sampling.

Compositing along a ray with samples i = 0..S−1, densities σ_i ≥ 0 and interval lengths δ_i > 0:

    τ_i = σ_i δ_i,   α_i = 1 − exp(−τ_i) = −expm1(−τ_i),   log T_i = −Σ_{j<i} τ_j,   w_i = T_i α_i

Transmittance stays in log space (an exclusive cumulative sum), so there is no product of many
(1 − α) factors to underflow, and σ = 1e6 gives w = 1 at the first sample and exact zeros after.

:func:`march_grid` is the same compositing fused with trilinear look-ups in a voxel grid (numba,
CPU): it skips samples outside the box or in empty cells and stops a ray once its transmittance
falls to ``min_trans`` (early termination), which a batched PyTorch pass cannot do. It runs on one
thread (the workflow gives each training job one).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

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


def composite_weights(sigmas: torch.Tensor, deltas: torch.Tensor, min_trans: float = 0.0) -> torch.Tensor:
    """Weights (R, S) from densities (R, S) and interval lengths (R, S).

    Samples reached with transmittance T <= ``min_trans`` get weight 0 (early ray termination).
    """
    tau = (sigmas.clamp(min=0.0) * deltas.clamp(min=0.0)).clamp(max=_TAU_MAX)  # σ ≥ 0 and δ ≥ 0 physically
    alpha = -torch.expm1(-tau)
    log_t = -(torch.cumsum(tau, -1) - tau)  # exclusive cumulative sum
    trans = torch.where(log_t > _LOG_T_MIN, torch.exp(log_t.clamp(min=_LOG_T_MIN)), torch.zeros_like(log_t))
    if min_trans > 0.0:
        trans = torch.where(trans > min_trans, trans, torch.zeros_like(trans))
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
    n_rays: int, n_samples: int, perturb: bool, near: float = 0.0, far: float = 1.0, device=None, dtype=None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(points (R, S), edges (R, S+1)): one sample per uniform bin, jittered when ``perturb``."""
    kw = {"device": device, "dtype": dtype}
    edges = torch.linspace(near, far, n_samples + 1, **kw).expand(n_rays, -1)
    u = torch.rand(n_rays, n_samples, **kw) if perturb else torch.full((n_rays, n_samples), 0.5, **kw)
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


# ---------------------------------------------------------------- fused grid marching (numba, CPU)
#
# A grid of R³ vertices stored flat with z fastest: vertex (ix, iy, iz) is row (ix·R + iy)·R + iz,
# cell (ix, iy, iz) is (ix·(R−1) + iy)·(R−1) + iz. NDC rays in a forward-facing scene run mostly
# along z, so consecutive samples of a ray read neighbouring rows (2x faster than x fastest).
# Samples: ``t`` (R, S), one per uniform bin of [0, 1]; interval δ = |d| / S; depth is the bin centre.
#
# Rays are marched in the order of :func:`_ray_order` (by the x, y tile they cross at t = ½), so
# that consecutive rays read and write neighbouring grid rows: a random training batch otherwise
# misses the caches on nearly every feature row (~1.7x slower backward). The forward march records
# what the backward needs of every kept sample (its cell, trilinear fractions, weight, transmittance,
# dσ/draw · δ and interpolated features), so the backward is one scatter pass without replaying the
# march, its density look-ups and transcendentals, or the 8 x C dot products of the feature rows.


# Reassociation lets LLVM vectorise the channel loops; no flag that assumes finite values.
_FASTMATH = {"reassoc", "contract", "arcp", "nsz"}
_ORDER_TILE = 4  # ray ordering: x, y tile width in cells


@njit(cache=True, nogil=True)
def _ray_order(o, d, box, res, tile):
    """Ray indices sorted (stably) by the x, y tile of grid cells each ray crosses at t = ½."""
    n = o.shape[0]
    n_tiles = (res - 2) // tile + 1
    keys = np.empty(n, dtype=np.int64)
    for r in range(n):
        ux = (o[r, 0] + 0.5 * d[r, 0] - box[0]) * box[3] / tile
        uy = (o[r, 1] + 0.5 * d[r, 1] - box[1]) * box[4] / tile
        tx = min(max(int(ux), 0), n_tiles - 1) if ux == ux else 0  # ux == ux: not NaN
        ty = min(max(int(uy), 0), n_tiles - 1) if uy == uy else 0
        keys[r] = tx * n_tiles + ty
    return np.argsort(keys, kind="mergesort")


@njit(inline="always")
def _softplus_sigmoid(x):
    """softplus(x) = log(1 + eˣ) and its derivative sigmoid(x), to 1e-9 relative.

    ``log(1 + e)`` (cheaper than ``log1p``) loses relative precision only for small
    e, where the series e − e²/2 is used instead (relative error ≈ e²/3 < 1e-9 for x < −10).
    """
    if x > 20.0:
        return x, 1.0
    e = math.exp(x)
    return (e - 0.5 * e * e if x < -10.0 else math.log(1.0 + e)), e / (1.0 + e)


@njit(inline="always")
def _corner(base, k, sx, sy, fx, fy, fz):
    """Row and trilinear weight of corner k (bit 2: x, bit 1: y, bit 0: z) of the cell at ``base``."""
    bx, by, bz = k >> 2, (k >> 1) & 1, k & 1
    w = (fx if bx else 1.0 - fx) * (fy if by else 1.0 - fy) * (fz if bz else 1.0 - fz)
    return base + bx * sx + by * sy + bz, w


@njit(cache=True, nogil=True, fastmath=_FASTMATH)
def _march_forward(o, d, t, box, res, density, feats, occ, shift, weight_thres, min_trans, order,
                   ray_feat, acc, depth, save, n_kept, k_s, k_base, k_frac, k_w, k_tr, k_gr, k_feat):  # fmt: skip
    """March the rays in ``order``; with ``save``, record each kept sample j < n_kept[r] of ray r:
    its bin k_s, cell row k_base, fractions k_frac (3), weight k_w, transmittance after it k_tr,
    dτ/draw k_gr (0 where τ was clamped) and interpolated features k_feat (C)."""
    n_s = t.shape[1]
    n_c = feats.shape[1]
    top, sy, sx = res - 1, res, res * res
    fsum, fi = np.empty(n_c), np.empty(n_c)
    for r in order:
        ox, oy, oz, dx, dy, dz = o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2]
        delta = math.sqrt(dx * dx + dy * dy + dz * dz) / n_s
        ax, bx = (ox - box[0]) * box[3], dx * box[3]
        ay, by = (oy - box[1]) * box[4], dy * box[4]
        az, bz = (oz - box[2]) * box[5], dz * box[5]
        trans, a, dep, nk = 1.0, 0.0, 0.0, 0
        fsum[:] = 0.0
        for s in range(n_s):
            ux, uy, uz = ax + t[r, s] * bx, ay + t[r, s] * by, az + t[r, s] * bz
            if not (ux >= 0.0 and ux <= top and uy >= 0.0 and uy <= top and uz >= 0.0 and uz <= top):
                continue
            ix, iy, iz = min(int(ux), res - 2), min(int(uy), res - 2), min(int(uz), res - 2)
            if not occ[(ix * top + iy) * top + iz]:
                continue
            fx, fy, fz = ux - ix, uy - iy, uz - iz
            base = (ix * res + iy) * res + iz
            p01, p10 = base + sy, base + sx  # the z pairs of rows (x, y) = (0, 1), (1, 0), (1, 1)
            p11 = p10 + sy
            gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
            raw = gx * (
                gy * (gz * density[base] + fz * density[base + 1]) + fy * (gz * density[p01] + fz * density[p01 + 1])
            )
            raw += fx * (
                gy * (gz * density[p10] + fz * density[p10 + 1]) + fy * (gz * density[p11] + fz * density[p11 + 1])
            )
            x = raw + shift
            sp, sig = _softplus_sigmoid(x)
            tau = sp * delta
            alpha = -math.expm1(-min(tau, _TAU_MAX))
            w = trans * alpha
            trans *= 1.0 - alpha
            a += w
            dep += w * (s + 0.5)
            if w > weight_thres:
                fi[:] = 0.0
                for k in range(8):
                    row, wk = _corner(base, k, sx, sy, fx, fy, fz)
                    for c in range(n_c):
                        fi[c] += wk * feats[row, c]
                for c in range(n_c):
                    fsum[c] += w * fi[c]
                if save:
                    for c in range(n_c):
                        k_feat[r, nk, c] = fi[c]
            if save:
                k_s[r, nk], k_base[r, nk], k_w[r, nk], k_tr[r, nk] = s, base, w, trans
                k_frac[r, nk, 0], k_frac[r, nk, 1], k_frac[r, nk, 2] = fx, fy, fz
                k_gr[r, nk] = 0.0 if tau >= _TAU_MAX else delta * sig  # a clamped τ has no gradient
            nk += 1
            if trans <= min_trans:
                break
        n_kept[r] = nk
        for c in range(n_c):
            ray_feat[r, c] = fsum[c]
        acc[r], depth[r] = a, dep / n_s + (1.0 - a)  # depth: the leftover mass at t = 1


@njit(cache=True, nogil=True, fastmath=_FASTMATH)
def _march_backward(res, n_s, weight_thres, order, n_kept, k_s, k_base, k_frac, k_w, k_tr, k_gr, k_feat,
                    g_feat, g_acc, g_depth, grad_density, grad_feats):  # fmt: skip
    """Gradients from the forward's record. Per kept sample i with weight w_i, T_{i+1} = T_i (1 − α_i)
    and upstream g_i = dL/dw_i (= g_acc + g_depth (t_i − 1) + f_i · g_feat): the feature rows get
    w_i · trilinear weight · g_feat, and dL/dτ_i = g_i T_{i+1} − Σ_{j>i} g_j w_j."""
    n_c = grad_feats.shape[1]
    sy, sx = res, res * res
    gf, g_buf, t_buf = np.empty(n_c), np.empty(n_s), np.empty(n_s)
    for r in order:
        for c in range(n_c):
            gf[c] = g_feat[r, c]
        total = 0.0
        for j in range(n_kept[r]):
            w = k_w[r, j]
            g = g_acc[r] + g_depth[r] * ((k_s[r, j] + 0.5) / n_s - 1.0)
            if w > weight_thres:
                dot = 0.0
                for c in range(n_c):
                    dot += k_feat[r, j, c] * gf[c]
                g += dot
                fx, fy, fz = k_frac[r, j, 0], k_frac[r, j, 1], k_frac[r, j, 2]
                for k in range(8):
                    row, wk = _corner(k_base[r, j], k, sx, sy, fx, fy, fz)
                    wk *= w
                    for c in range(n_c):
                        grad_feats[row, c] += wk * gf[c]
            g_buf[j], t_buf[j] = g * w, g * k_tr[r, j]
            total += g * w
        prefix = 0.0
        for j in range(n_kept[r]):
            prefix += g_buf[j]
            g_raw = (t_buf[j] - (total - prefix)) * k_gr[r, j]
            fx, fy, fz = k_frac[r, j, 0], k_frac[r, j, 1], k_frac[r, j, 2]
            for k in range(8):
                row, wk = _corner(k_base[r, j], k, sx, sy, fx, fy, fz)
                grad_density[row] += wk * g_raw


class _MarchGrid(torch.autograd.Function):
    @staticmethod
    def forward(ctx, density, features, rays_o, rays_d, t, occupancy, box, res, shift, weight_thres, min_trans, save):
        n, dt = rays_o.shape[0], features.dtype
        n_s, n_c = t.shape[1], features.shape[1]
        o, d = rays_o.detach().contiguous().numpy(), rays_d.detach().contiguous().numpy()
        box = np.asarray(box, dtype=np.float64)
        order = _ray_order(o, d, box, res, _ORDER_TILE)
        ray_feat = torch.empty(n, n_c, dtype=dt)
        acc, depth = torch.empty(n, dtype=dt), torch.empty(n, dtype=dt)
        m, s = (n, n_s) if save else (0, 0)  # the record: empty when no gradient will be asked for
        ft = features.detach().numpy().dtype  # the record in the grid's precision
        record = (
            np.zeros(n, dtype=np.int32),  # n_kept
            np.empty((m, s), dtype=np.int32),  # k_s
            np.empty((m, s), dtype=np.int32),  # k_base
            np.empty((m, s, 3), dtype=ft),  # k_frac
            np.empty((m, s), dtype=ft),  # k_w
            np.empty((m, s), dtype=ft),  # k_tr
            np.empty((m, s), dtype=ft),  # k_gr
            np.empty((m, s, n_c), dtype=ft),  # k_feat
        )
        _march_forward(
            o, d, t.detach().contiguous().numpy(), box, res, density.detach().view(-1).numpy(),
            features.detach().numpy(), occupancy.numpy(), float(shift), float(weight_thres), float(min_trans),
            order, ray_feat.numpy(), acc.numpy(), depth.numpy(), save, *record,
        )  # fmt: skip
        ctx.record, ctx.order, ctx.sizes = record, order, (res, n_s, float(weight_thres), density.shape, features.shape)
        return ray_feat, acc, depth

    @staticmethod
    def backward(ctx, g_feat, g_acc, g_depth):
        grads = [None] * 12
        if ctx.needs_input_grad[0] or ctx.needs_input_grad[1]:
            res, n_s, weight_thres, d_shape, f_shape = ctx.sizes
            grad_density = torch.zeros(d_shape, dtype=g_feat.dtype)
            grad_feats = torch.zeros(f_shape, dtype=g_feat.dtype)
            ups = [g.contiguous().numpy() for g in (g_feat, g_acc, g_depth)]
            _march_backward(
                res, n_s, weight_thres, ctx.order, *ctx.record, *ups, grad_density.view(-1).numpy(),
                grad_feats.numpy(),
            )  # fmt: skip
            grads[0], grads[1] = grad_density, grad_feats
        return tuple(grads)


def march_grid(
    density: torch.Tensor,  # [R³, 1] raw density (σ = softplus(raw + shift))
    features: torch.Tensor,  # [R³, C]
    rays_o: torch.Tensor,  # [N, 3]
    rays_d: torch.Tensor,  # [N, 3]
    t: torch.Tensor,  # [N, S] one sample per uniform bin of [0, 1]
    occupancy: torch.Tensor,  # [(R−1)³] bool: cells to sample
    box: tuple[float, ...],  # lo_x, lo_y, lo_z, (R−1)/(hi−lo) per axis
    res: int,
    shift: float,
    weight_thres: float,
    min_trans: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Composited features Σ w_i f_i (N, C) (f only where w_i > weight_thres), acc Σ w_i (N,) and
    depth (N,) (leftover mass at t = 1) of CPU rays through a grid in z-fastest layout.

    Differentiable in ``density`` and ``features`` (hand-written backward, float32 or float64).
    Equal to the batched PyTorch composite (:func:`composite_weights` with ``min_trans``) of the
    same samples: samples outside the box or in empty cells have σ = 0.
    """
    save = torch.is_grad_enabled() and (density.requires_grad or features.requires_grad)
    args = (rays_o, rays_d, t, occupancy, box, res, shift, weight_thres, min_trans, save)
    return _MarchGrid.apply(density, features, *args)

"""``eval_sh`` with a hand-written gradient in numba: the same colour, one pass per direction.

:func:`.project.eval_sh` (pure PyTorch) is the definition; autograd through its ~40 small ops on
(N,) columns and the (N, 16, 3) product, plus the ``torch.cat`` of the DC and higher
coefficients that feeds it, took about a fifth of a 3DGS training step at degree 3.
:func:`eval_sh_native` takes the DC and the higher coefficients as the model stores them and
evaluates, per Gaussian, in float64:

* d = v / |v| with |v|² clamped at 1e-24 (a zero direction stays finite, as eval_sh);
* the real SH basis Y_k(d) of degrees 0..degree (project.py's ``_sh_basis``);
* rgb_c = max(Σ_k Y_k sh_kc + 0.5, 0), NaN kept as torch's ``clamp_min``.

Backward (g = dL/drgb where the clamp let it through, i.e. where Σ + 0.5 >= 0, as torch):
dL/dsh_kc = Y_k g_c (zero for the coefficients above the active degree, as autograd gives them),
dL/dd = Σ_k (Σ_c g_c sh_kc) ∇Y_k(d) with the gradients of the basis polynomials in closed form,
and dL/dv = (dL/dd - d (d · dL/dd)) / |v|, or dL/dd / |v| where the norm was clamped.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit
from torch import Tensor

from spc3d.reconstruct.splat.native_prep import CHUNK, gather_columns
from spc3d.reconstruct.splat.native_threads import in_chunks, next_chunk
from spc3d.reconstruct.splat.project import SH_C0, SH_C1, SH_C2, SH_C3

_C2 = np.array(SH_C2)
_C3 = np.array(SH_C3)


@njit(inline="always")
def _unit_columns(inp, n, d, inv, keep):
    """Rows 0..2 of ``inp`` (directions, one per column) normalised into d (3, CHUNK); 1 / the
    clamped norm into inv; keep: 1.0 where the norm was not clamped (its gradient then counts)."""
    for j in range(n):
        vx, vy, vz = inp[0, j], inp[1, j], inp[2, j]
        n2 = vx * vx + vy * vy + vz * vz
        r = 1.0 / math.sqrt(max(n2, 1e-24))
        d[0, j], d[1, j], d[2, j], inv[j] = vx * r, vy * r, vz * r, r
        keep[j] = 0.0 if n2 < 1e-24 else 1.0


@njit(inline="always")
def _basis_columns(degree, n, d, c2, c3, b):
    """Y_0..Y_{(degree+1)²-1} (rows of b) at the unit directions d (3, CHUNK), columns 0..n-1."""
    for j in range(n):
        b[0, j] = SH_C0
    if degree >= 1:
        for j in range(n):
            x, y, z = d[0, j], d[1, j], d[2, j]
            b[1, j], b[2, j], b[3, j] = -SH_C1 * y, SH_C1 * z, -SH_C1 * x
    if degree >= 2:
        for j in range(n):
            x, y, z = d[0, j], d[1, j], d[2, j]
            xx, yy, zz = x * x, y * y, z * z
            b[4, j], b[5, j], b[6, j] = c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * zz - xx - yy)
            b[7, j], b[8, j] = c2[3] * x * z, c2[4] * (xx - yy)
    if degree >= 3:
        for j in range(n):
            x, y, z = d[0, j], d[1, j], d[2, j]
            xx, yy, zz = x * x, y * y, z * z
            b[9, j], b[10, j] = c3[0] * y * (3 * xx - yy), c3[1] * x * y * z
            b[11, j], b[12, j] = c3[2] * y * (4 * zz - xx - yy), c3[3] * z * (2 * zz - 3 * xx - 3 * yy)
            b[13, j], b[14, j] = c3[4] * x * (4 * zz - xx - yy), c3[5] * z * (xx - yy)
            b[15, j] = c3[6] * x * (xx - 3 * yy)


@njit(inline="always")
def _colours(k, n, b, sh, acc):
    """acc (3, CHUNK) = Σ_{k' < k} Y_k' sh_k'c + 0.5 (before the clamp); sh: rows 3 k' + c."""
    for c in range(3):
        for j in range(n):
            acc[c, j] = b[0, j] * sh[c, j]
        for q in range(1, k):
            for j in range(n):
                acc[c, j] += b[q, j] * sh[3 * q + c, j]
        for j in range(n):
            acc[c, j] += 0.5


@njit(inline="always")
def _gather(dirs, dc, rest, c0, n, inp, sh):
    """Directions into rows 0..2 of inp, the coefficients (DC, then rest) into rows of sh, one
    column per Gaussian."""
    gather_columns(dirs, c0, n, inp, 0)
    gather_columns(rest, c0, n, sh, gather_columns(dc, c0, n, sh, 0))


@njit(cache=True, nogil=True, error_model="numpy")
def _sh_forward(degree, dirs, dc, rest, c2, c3, counter, total, rgb):
    """rgb (N, 3) of the chunks of the ``total`` Gaussians this worker takes. dc (N, 3), rest
    (N, 3 (K - 1)): the coefficients flattened."""
    k = (degree + 1) ** 2
    inp, sh = np.empty((3, CHUNK)), np.empty((3 + rest.shape[1], CHUNK))
    d, inv, keep, b, acc = np.empty((3, CHUNK)), np.empty(CHUNK), np.empty(CHUNK), np.empty((16, CHUNK)), np.empty(
        (3, CHUNK))
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        _gather(dirs, dc, rest, c0, n, inp, sh)
        _unit_columns(inp, n, d, inv, keep)
        _basis_columns(degree, n, d, c2, c3, b)
        _colours(k, n, b, sh, acc)
        for j in range(n):
            for c in range(3):
                s = acc[c, j]
                rgb[c0 + j, c] = s if not s < 0.0 else 0.0  # NaN stays NaN (torch's clamp_min)


@njit(cache=True, nogil=True, error_model="numpy")
def _sh_backward(degree, dirs, dc, rest, c2, c3, g_rgb, counter, total, g_dirs, g_dc, g_rest):
    """dL/d(dirs, DC, rest) of the chunks this worker takes (g_rest zero above the degree);
    coefficients and their gradients flattened as in _sh_forward."""
    k = (degree + 1) ** 2
    inp, sh = np.empty((3, CHUNK)), np.empty((3 + rest.shape[1], CHUNK))
    d, inv, keep, b, acc = np.empty((3, CHUNK)), np.empty(CHUNK), np.empty(CHUNK), np.empty((16, CHUNK)), np.empty(
        (3, CHUNK))
    g, gb, gsh = np.empty((3, CHUNK)), np.zeros((16, CHUNK)), np.zeros((3 + rest.shape[1], CHUNK))
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        _gather(dirs, dc, rest, c0, n, inp, sh)
        gather_columns(g_rgb, c0, n, g, 0)
        _unit_columns(inp, n, d, inv, keep)
        _basis_columns(degree, n, d, c2, c3, b)
        _colours(k, n, b, sh, acc)
        for c in range(3):  # the clamp's mask: torch passes the gradient where its input >= 0
            for j in range(n):
                g[c, j] = g[c, j] if acc[c, j] >= 0.0 else 0.0
        for q in range(k):  # dL/dsh = Y g; dL/dY = Σ_c g_c sh_c
            for j in range(n):
                g0, g1, g2 = g[0, j], g[1, j], g[2, j]
                gsh[3 * q, j], gsh[3 * q + 1, j], gsh[3 * q + 2, j] = b[q, j] * g0, b[q, j] * g1, b[q, j] * g2
                gb[q, j] = g0 * sh[3 * q, j] + g1 * sh[3 * q + 1, j] + g2 * sh[3 * q + 2, j]
        for j in range(n):
            x, y, z = d[0, j], d[1, j], d[2, j]
            gx, gy, gz = 0.0, 0.0, 0.0
            if degree >= 1:
                gx -= SH_C1 * gb[3, j]
                gy -= SH_C1 * gb[1, j]
                gz += SH_C1 * gb[2, j]
            if degree >= 2:
                gx += c2[0] * y * gb[4, j] - 2 * c2[2] * x * gb[6, j] + c2[3] * z * gb[7, j] + 2 * c2[4] * x * gb[8, j]
                gy += c2[0] * x * gb[4, j] + c2[1] * z * gb[5, j] - 2 * c2[2] * y * gb[6, j] - 2 * c2[4] * y * gb[8, j]
                gz += c2[1] * y * gb[5, j] + 4 * c2[2] * z * gb[6, j] + c2[3] * x * gb[7, j]
            if degree >= 3:
                xx, yy, zz = x * x, y * y, z * z
                gx += (c3[0] * 6 * x * y * gb[9, j] + c3[1] * y * z * gb[10, j] - c3[2] * 2 * x * y * gb[11, j]
                       - c3[3] * 6 * x * z * gb[12, j] + c3[4] * (4 * zz - 3 * xx - yy) * gb[13, j]
                       + c3[5] * 2 * x * z * gb[14, j] + c3[6] * 3 * (xx - yy) * gb[15, j])
                gy += (c3[0] * 3 * (xx - yy) * gb[9, j] + c3[1] * x * z * gb[10, j]
                       + c3[2] * (4 * zz - xx - 3 * yy) * gb[11, j] - c3[3] * 6 * y * z * gb[12, j]
                       - c3[4] * 2 * x * y * gb[13, j] - c3[5] * 2 * y * z * gb[14, j] - c3[6] * 6 * x * y * gb[15, j])
                gz += (c3[1] * x * y * gb[10, j] + c3[2] * 8 * y * z * gb[11, j]
                       + c3[3] * (6 * zz - 3 * xx - 3 * yy) * gb[12, j] + c3[4] * 8 * x * z * gb[13, j]
                       + c3[5] * (xx - yy) * gb[14, j])
            dot = keep[j] * (x * gx + y * gy + z * gz)  # a clamped norm is constant: no projection
            r = inv[j]
            g_dirs[c0 + j, 0], g_dirs[c0 + j, 1], g_dirs[c0 + j, 2] = (gx - x * dot) * r, (gy - y * dot) * r, (
                gz - z * dot) * r
        for j in range(n):
            for c in range(3):
                g_dc[c0 + j, c] = gsh[c, j]
            for q in range(rest.shape[1]):  # zero above the active degree (gsh rows stay 0 there)
                g_rest[c0 + j, q] = gsh[3 + q, j]


class _EvalSHNative(torch.autograd.Function):
    @staticmethod
    def forward(ctx, degree, dirs, sh_dc, sh_rest):
        n = dirs.shape[0]
        arrays = (dirs.detach().contiguous().numpy(), sh_dc.detach().reshape(n, 3).contiguous().numpy(),
                  sh_rest.detach().reshape(n, 3 * sh_rest.shape[1]).contiguous().numpy())
        rgb = np.empty((n, 3), arrays[1].dtype)
        in_chunks(_sh_forward, n, (degree, *arrays, _C2, _C3), (rgb,))
        ctx.degree, ctx.arrays = degree, arrays
        return torch.from_numpy(rgb)

    @staticmethod
    def backward(ctx, g_rgb):
        dirs, dc, rest = ctx.arrays
        n = len(dirs)
        g_dirs, g_dc, g_rest = np.empty(dirs.shape, dirs.dtype), np.empty(dc.shape, dc.dtype), np.empty(rest.shape,
                                                                                                       rest.dtype)
        in_chunks(_sh_backward, n, (ctx.degree, dirs, dc, rest, _C2, _C3, g_rgb.contiguous().numpy()),
                  (g_dirs, g_dc, g_rest))
        return (None, torch.from_numpy(g_dirs), torch.from_numpy(g_dc).reshape(n, 1, 3),
                torch.from_numpy(g_rest).reshape(n, rest.shape[1] // 3, 3))


def eval_sh_native(degree: int, sh_dc: Tensor, sh_rest: Tensor, dirs: Tensor) -> Tensor:
    """``eval_sh(degree, torch.cat([sh_dc, sh_rest], 1), dirs)`` without the concatenation:
    sh_dc (N, 1, 3), sh_rest (N, K - 1, 3), dirs (N, 3) (one float dtype, CPU); colour (N, 3) in
    that dtype, gradients to all three by hand (module docstring)."""
    n = dirs.shape[0]
    if sh_dc.shape != (n, 1, 3) or sh_rest.dim() != 3 or sh_rest.shape[0] != n or sh_rest.shape[2] != 3:
        raise ValueError(f"eval_sh_native: expected sh_dc (N, 1, 3) and sh_rest (N, K-1, 3) for N = {n} directions, "
                         f"got {tuple(sh_dc.shape)} and {tuple(sh_rest.shape)}")
    if not 0 <= degree <= 3 or sh_rest.shape[1] + 1 < (degree + 1) ** 2:
        raise ValueError(f"eval_sh_native: degree must be 0..3 with >= (degree+1)^2 coefficients, got {degree}, "
                         f"{sh_rest.shape[1] + 1}")
    if dirs.shape != (n, 3) or not (dirs.dtype == sh_dc.dtype == sh_rest.dtype):
        raise ValueError(f"eval_sh_native: dirs must be (N, 3) of the coefficients' dtype, got {tuple(dirs.shape)} "
                         f"{dirs.dtype}, coefficients {sh_dc.dtype} / {sh_rest.dtype}")
    return _EvalSHNative.apply(int(degree), dirs, sh_dc, sh_rest)

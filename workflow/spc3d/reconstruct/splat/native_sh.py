"""``eval_sh`` with a hand-written gradient in numba: the same colour, one pass per direction.

:func:`.project.eval_sh` (pure PyTorch) is the definition; autograd through its ~40 small ops on
(N,) columns and the (N, 16, 3) product, plus the ``torch.cat`` of the DC and higher
coefficients that feeds it, took about a fifth of a 3DGS training step at degree 3.
:func:`eval_sh_native` takes the DC and the higher coefficients as the model stores them and
evaluates, per Gaussian, in float64:

* d = v / |v| with |v|² clamped at 1e-24 (a zero direction stays finite, as eval_sh);
* the real SH basis Y_k(d) of degrees 0..degree (project.py's ``_sh_basis``);
* rgb_c = max(Σ_k Y_k sh_kc + 0.5, 0), NaN kept as torch's ``clamp_min``.

Backward (g = dL/drgb where the clamp let it through, i.e. where Σ + 0.5 >= 0, as torch; the forward
keeps that mask):
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

from spc3d.reconstruct.splat.native_prep import CHUNK
from spc3d.reconstruct.splat.native_threads import in_chunks, next_chunk
from spc3d.reconstruct.splat.project import SH_C0, SH_C1, SH_C2, SH_C3

_C2 = np.array(SH_C2)
_C3 = np.array(SH_C3)


@njit(inline="always")
def _unit(dirs, i):
    """(x, y, z) of dirs[i] normalised, 1 / clamped norm, and whether the norm was clamped."""
    vx, vy, vz = float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2])
    n2 = vx * vx + vy * vy + vz * vz
    inv = 1.0 / math.sqrt(max(n2, 1e-24))
    return vx * inv, vy * inv, vz * inv, inv, n2 < 1e-24


@njit(inline="always")
def _basis(degree, x, y, z, c2, c3, b):
    """Y_0..Y_{(degree+1)²-1} at the unit direction (x, y, z) into b."""
    b[0] = SH_C0
    if degree >= 1:
        b[1], b[2], b[3] = -SH_C1 * y, SH_C1 * z, -SH_C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        b[4], b[5], b[6] = c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * zz - xx - yy)
        b[7], b[8] = c2[3] * x * z, c2[4] * (xx - yy)
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        b[9], b[10] = c3[0] * y * (3 * xx - yy), c3[1] * x * y * z
        b[11], b[12] = c3[2] * y * (4 * zz - xx - yy), c3[3] * z * (2 * zz - 3 * xx - 3 * yy)
        b[13], b[14] = c3[4] * x * (4 * zz - xx - yy), c3[5] * z * (xx - yy)
        b[15] = c3[6] * x * (xx - 3 * yy)


@njit(inline="always")
def _colour(i, k, dc, rest, b, c):
    """Σ_{k' < k} Y_k' sh_k'c + 0.5 of Gaussian i, channel c (before the clamp)."""
    s = b[0] * float(dc[i, c])
    for q in range(1, k):
        s += b[q] * float(rest[i, 3 * (q - 1) + c])
    return s + 0.5


@njit(cache=True, nogil=True, error_model="numpy")
def _sh_forward(degree, dirs, dc, rest, c2, c3, counter, total, rgb, passed):
    """rgb (N, 3) of the chunks of the ``total`` Gaussians this worker takes, and ``passed`` (N, 3):
    1 where the clamp lets the gradient through (its input >= 0, as torch's). dc (N, 3), rest
    (N, 3 (K - 1)): the coefficients flattened."""
    k = (degree + 1) ** 2
    b = np.empty(16)
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        for i in range(c0, c0 + n):
            x, y, z, _, _ = _unit(dirs, i)
            _basis(degree, x, y, z, c2, c3, b)
            for c in range(3):
                s = _colour(i, k, dc, rest, b, c)
                rgb[i, c] = s if not s < 0.0 else 0.0  # NaN stays NaN (torch's clamp_min)
                passed[i, c] = s >= 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _sh_backward(degree, dirs, rest, c2, c3, g_rgb, passed, counter, total, g_dirs, g_dc, g_rest):
    """dL/d(dirs, DC, rest) of the chunks this worker takes (g_rest zero above the degree);
    coefficients and their gradients flattened as in _sh_forward, ``passed`` its clamp mask."""
    k = (degree + 1) ** 2
    b, gb = np.empty(16), np.zeros(16)
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        for i in range(c0, c0 + n):
            x, y, z, inv, clamped = _unit(dirs, i)
            _basis(degree, x, y, z, c2, c3, b)
            g0 = float(g_rgb[i, 0]) if passed[i, 0] else 0.0  # the forward's clamp mask
            g1 = float(g_rgb[i, 1]) if passed[i, 1] else 0.0
            g2 = float(g_rgb[i, 2]) if passed[i, 2] else 0.0
            g_dc[i, 0], g_dc[i, 1], g_dc[i, 2] = b[0] * g0, b[0] * g1, b[0] * g2
            for q in range(1, k):  # dL/dsh = Y g; dL/dY = Σ_c g_c sh_c
                r = 3 * (q - 1)
                g_rest[i, r], g_rest[i, r + 1], g_rest[i, r + 2] = b[q] * g0, b[q] * g1, b[q] * g2
                gb[q] = g0 * float(rest[i, r]) + g1 * float(rest[i, r + 1]) + g2 * float(rest[i, r + 2])
            for r in range(3 * (k - 1), rest.shape[1]):  # above the active degree
                g_rest[i, r] = 0.0
            gx, gy, gz = 0.0, 0.0, 0.0
            if degree >= 1:
                gx -= SH_C1 * gb[3]
                gy -= SH_C1 * gb[1]
                gz += SH_C1 * gb[2]
            if degree >= 2:
                gx += c2[0] * y * gb[4] - 2 * c2[2] * x * gb[6] + c2[3] * z * gb[7] + 2 * c2[4] * x * gb[8]
                gy += c2[0] * x * gb[4] + c2[1] * z * gb[5] - 2 * c2[2] * y * gb[6] - 2 * c2[4] * y * gb[8]
                gz += c2[1] * y * gb[5] + 4 * c2[2] * z * gb[6] + c2[3] * x * gb[7]
            if degree >= 3:
                xx, yy, zz = x * x, y * y, z * z
                gx += (c3[0] * 6 * x * y * gb[9] + c3[1] * y * z * gb[10] - c3[2] * 2 * x * y * gb[11]
                       - c3[3] * 6 * x * z * gb[12] + c3[4] * (4 * zz - 3 * xx - yy) * gb[13]
                       + c3[5] * 2 * x * z * gb[14] + c3[6] * 3 * (xx - yy) * gb[15])
                gy += (c3[0] * 3 * (xx - yy) * gb[9] + c3[1] * x * z * gb[10] + c3[2] * (4 * zz - xx - 3 * yy) * gb[11]
                       - c3[3] * 6 * y * z * gb[12] - c3[4] * 2 * x * y * gb[13] - c3[5] * 2 * y * z * gb[14]
                       - c3[6] * 6 * x * y * gb[15])
                gz += (c3[1] * x * y * gb[10] + c3[2] * 8 * y * z * gb[11] + c3[3] * (6 * zz - 3 * xx - 3 * yy) * gb[12]
                       + c3[4] * 8 * x * z * gb[13] + c3[5] * (xx - yy) * gb[14])
            dot = 0.0 if clamped else x * gx + y * gy + z * gz  # a clamped norm is constant: no projection
            g_dirs[i, 0], g_dirs[i, 1], g_dirs[i, 2] = (gx - x * dot) * inv, (gy - y * dot) * inv, (gz - z * dot) * inv


class _EvalSHNative(torch.autograd.Function):
    @staticmethod
    def forward(ctx, degree, dirs, sh_dc, sh_rest):
        n = dirs.shape[0]
        arrays = (dirs.detach().contiguous().numpy(), sh_dc.detach().reshape(n, 3).contiguous().numpy(),
                  sh_rest.detach().reshape(n, 3 * sh_rest.shape[1]).contiguous().numpy())
        rgb, passed = np.empty((n, 3), arrays[1].dtype), np.empty((n, 3), np.bool_)
        in_chunks(_sh_forward, n, (degree, *arrays, _C2, _C3), (rgb, passed))
        ctx.degree, ctx.arrays, ctx.passed = degree, arrays, passed
        return torch.from_numpy(rgb)

    @staticmethod
    def backward(ctx, g_rgb):
        dirs, dc, rest = ctx.arrays
        n = len(dirs)
        g_dirs, g_dc, g_rest = np.empty(dirs.shape, dirs.dtype), np.empty(dc.shape, dc.dtype), np.empty(rest.shape,
                                                                                                       rest.dtype)
        in_chunks(_sh_backward, n, (ctx.degree, dirs, rest, _C2, _C3, g_rgb.contiguous().numpy(), ctx.passed),
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

"""The 3DGS training SSIM on the CPU in one numba pass: ``1 - mean SSIM`` and its gradient together.

:class:`.metrics._SSIMLoss` defines the loss and its closed-form gradient (see its docstring). Its
torch form blurs with dense banded matrices: each output pixel costs a multiply per row or column
of the image instead of per tap, about ten times the work of the 11-tap filter on 96x128 views.
Here the separable 'same' zero-padded blur runs tap by tap over contiguous rows (vectorised), the
five moments, the SSIM map and the three gradient maps are computed pixel by pixel without
temporaries, and the gradient w.r.t. ``pred`` is formed in the same call: a training step always
asks for it, so the backward only scales it. Same value and gradient as ``metrics.ssim_loss`` to
float rounding (tests/test_metrics.py, gradcheck in float64).
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

# LLVM vectorises the loops below only with indices it can prove non-negative (numba's wraparound
# of negative indices otherwise makes every address data-dependent): hence the uint64 indices
# (12x faster blur than the same loops on int64; see splat/native_simd.py for the other rules).
_KERNEL = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"contract"}}
N_TAPS = 11  # the SSIM window (metrics.SSIM_WINDOW): a compile-time trip count, so LLVM unrolls the
# taps and vectorises across the row (7x faster than a run-time tap count)


@njit(**_KERNEL)
def _blur(src, dst, taps):
    """dst[p] = separable blur of plane src[p] by ``taps`` (N_TAPS of them) with zero padding
    ('same' size), for every plane of (P, H, W) C-contiguous arrays. One zeroed scratch holds a
    padded row and the padded row-blurred plane, so every tap reads inside it."""
    n_planes, height, width = src.shape
    half = N_TAPS // 2
    h, w, plane = uint64(height), uint64(width), uint64(height * width)
    row = uint64(width + 2 * half)  # the padded row; the row-blurred plane follows, with half zero rows each side
    buf = np.zeros(row + uint64((height + 2 * half) * width), src.dtype)
    s, d = src.reshape(-1), dst.reshape(-1)
    for p in range(uint64(n_planes)):
        base = p * plane
        for y in range(h):
            for x in range(w):
                buf[uint64(half) + x] = s[base + y * w + x]
            out = row + (y + uint64(half)) * w
            for x in range(w):
                acc = taps[0] * buf[x]
                for k in range(uint64(1), uint64(N_TAPS)):
                    acc += taps[k] * buf[x + k]
                buf[out + x] = acc
        for y in range(h):
            top = row + y * w
            for x in range(w):
                acc = taps[0] * buf[top + x]
                for k in range(uint64(1), uint64(N_TAPS)):
                    acc += taps[k] * buf[top + k * w + x]
                d[base + y * w + x] = acc


@njit(**_KERNEL)
def ssim_loss_and_grad(x, y, taps, consts, grad):
    """``1 - mean SSIM`` of the planes x, y (P, H, W) (one dtype, C-contiguous); writes its gradient
    w.r.t. x into ``grad`` (P, H, W). consts: c1, c2 and -1 / x.size (d(1 - mean S) / dS) in the
    planes' dtype, so that the per-pixel loop vectorises in it; the SSIM sum is accumulated in
    float64."""
    n_planes, height, width = x.shape
    n = uint64(x.size)
    c1, c2, g = consts[0], consts[1], consts[2]
    xf, yf, gf = x.reshape(-1), y.reshape(-1), grad.reshape(-1)
    work = np.empty(5 * n, x.dtype)  # x, y, x², y², xy: blurred into the five local moments
    for i in range(n):
        work[i], work[n + i], work[2 * n + i] = xf[i], yf[i], xf[i] * xf[i]
        work[3 * n + i], work[4 * n + i] = yf[i] * yf[i], xf[i] * yf[i]
    mom = np.empty(5 * n, x.dtype)
    _blur(work.reshape(5 * n_planes, height, width), mom.reshape(5 * n_planes, height, width), taps)
    smap = work[:n]  # the products are spent: SSIM per pixel, then dL/d(mu_x, exx, exy) per pixel
    for i in range(n):
        mu_x, mu_y, exx, eyy, exy = mom[i], mom[n + i], mom[2 * n + i], mom[3 * n + i], mom[4 * n + i]
        mxy, mxx, myy = mu_x * mu_y, mu_x * mu_x, mu_y * mu_y
        a1, a2 = 2 * mxy + c1, 2 * (exy - mxy) + c2
        b1, b2 = mxx + myy + c1, (exx - mxx) + (eyy - myy) + c2
        den = b1 * b2
        si = a1 * a2 / den
        smap[i] = si
        work[n + i] = g * (2 * mu_y * (a2 - a1) / den - 2 * mu_x * si * (1 / b1 - 1 / b2))
        work[2 * n + i] = g * -si / b2
        work[3 * n + i] = g * 2 * a1 / den
    total = 0.0
    for i in range(n):
        total += smap[i]
    _blur(work[n : 4 * n].reshape(3 * n_planes, height, width), mom[: 3 * n].reshape(3 * n_planes, height, width), taps)
    for i in range(n):
        gf[i] = mom[i] + 2 * xf[i] * mom[n + i] + yf[i] * mom[2 * n + i]
    return 1.0 - total / x.size

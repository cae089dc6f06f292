"""``project_gaussians`` with hand-written gradients in numba: same contract, less time.

The pure-PyTorch :func:`.project.project_gaussians` is the readable definition and stays the
reference; autograd through its ~100 small tensor ops costs more than the native rasterizer's
own set-up, forward and backward (docs/benchmarks.md has the measurements). This module evaluates
the same formulas per Gaussian in float64 and back-propagates them by hand; radii follow project.py's
``_radii`` formula in float64 (identical for float64 inputs, for float32 inputs an occasional
radius can differ by 1 px where float32 rounding crosses an integer). Keeping every per-Gaussian
step out of torch also avoids torch's intra-op overhead on tiny tensor ops.

Speed: the per-Gaussian code uses only scalars and tuples, no branches (selects) and no divisions
it can share, and runs on chunks of 256 Gaussians gathered into local column buffers, so LLVM
vectorises it (8 float64 lanes); the chunks are split over torch's threads (a scalar loop
with scratch arrays or array views per Gaussian was slower).

The derivation follows the forward step by step (names as in ``_core``):

* conic = (c, -b, a) / det,  det = |r0 x r1|² + lp (a0 + c0) + lp²  (Cauchy-Binet, see project.py)
* a0, b, c0 = r0·r0, r0·r1, r1·r1 with rows r = J W M,  M = R(q / |q|) diag(s)
* J W rows: (fx / z)(W0 - u W2), (fy / z)(W1 - v W2), u = clamp(x / z), v = clamp(y / z)

Culled Gaussians behave exactly as in the PyTorch version (z replaced by 1, no gradient through
the determinant), so gradients agree everywhere, including at the clamps.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit
from torch import Tensor

from spc3d.reconstruct.splat.native_prep import CHUNK, gather_columns
from spc3d.reconstruct.splat.native_threads import in_chunks, next_chunk
from spc3d.reconstruct.splat.project import MAX_RADIUS, Projected, check_camera, check_gaussians


@njit(inline="always")
def _cross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@njit(inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(inline="always")
def _axpy(alpha, x, y):
    """alpha x + y for 3-tuples."""
    return alpha * x[0] + y[0], alpha * x[1] + y[1], alpha * x[2] + y[2]


@njit(inline="always")
def _rotation(q):
    """(1 / |q| with the norm clamped, q / |q|, rows of R(q / |q|)); the clamp keeps a zero
    quaternion finite."""
    qn = math.sqrt(max(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3], 1e-24))
    inv = 1.0 / qn
    w, x, y, z = q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv
    R0 = (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y))
    R1 = (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x))
    R2 = (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))
    return inv, (w, x, y, z), (R0, R1, R2)


@njit(inline="always")
def _core(m, s, q, W, cam, near, low_pass):
    """Forward of one Gaussian, scalars and tuples only (no scratch arrays, no branches: LLVM
    vectorises the loops over Gaussians). W: rows (3 x 4-tuples) of w2c; cam: see _camera_vector.
    Returns (x, y, z, zs, in_front), (1 / |q|, qhat, R), (u_free, v_free, inv_z), (J0, J1), M, (r0, r1),
    (a0, b, c0, det)."""
    x = W[0][0] * m[0] + W[0][1] * m[1] + W[0][2] * m[2] + W[0][3]
    y = W[1][0] * m[0] + W[1][1] * m[1] + W[1][2] * m[2] + W[1][3]
    z = W[2][0] * m[0] + W[2][1] * m[1] + W[2][2] * m[2] + W[2][3]
    in_front = z > near
    zs = z if in_front else 1.0  # culled: harmless z = 1, as project.py
    inv_qn, qhat, R = _rotation(q)
    inv_z = 1.0 / zs
    u, v = x * inv_z, y * inv_z
    u_free, v_free = (cam[4] <= u) & (u <= cam[5]), (cam[6] <= v) & (v <= cam[7])
    u, v = min(max(u, cam[4]), cam[5]), min(max(v, cam[6]), cam[7])
    fz, gz = cam[0] * inv_z, cam[1] * inv_z
    J0 = (fz * (W[0][0] - u * W[2][0]), fz * (W[0][1] - u * W[2][1]), fz * (W[0][2] - u * W[2][2]))
    J1 = (gz * (W[1][0] - v * W[2][0]), gz * (W[1][1] - v * W[2][1]), gz * (W[1][2] - v * W[2][2]))
    M = ((R[0][0] * s[0], R[0][1] * s[1], R[0][2] * s[2]), (R[1][0] * s[0], R[1][1] * s[1], R[1][2] * s[2]),
         (R[2][0] * s[0], R[2][1] * s[1], R[2][2] * s[2]))
    r0 = (J0[0] * M[0][0] + J0[1] * M[1][0] + J0[2] * M[2][0], J0[0] * M[0][1] + J0[1] * M[1][1] + J0[2] * M[2][1],
          J0[0] * M[0][2] + J0[1] * M[1][2] + J0[2] * M[2][2])
    r1 = (J1[0] * M[0][0] + J1[1] * M[1][0] + J1[2] * M[2][0], J1[0] * M[0][1] + J1[1] * M[1][1] + J1[2] * M[2][1],
          J1[0] * M[0][2] + J1[1] * M[1][2] + J1[2] * M[2][2])
    a0, b, c0 = _dot(r0, r0), _dot(r0, r1), _dot(r1, r1)
    n = _cross(r0, r1)
    det = _dot(n, n) + low_pass * (a0 + c0) + low_pass * low_pass
    return (x, y, z, zs, in_front), (inv_qn, qhat, R), (u_free, v_free, inv_z), (J0, J1), M, (r0, r1), (a0, b, c0, det)


@njit(inline="always")
def _radius(a, c, det, mx, my, height, width):
    """3-sigma radius in pixels (float) from the largest eigenvalue, 0 when the footprint is
    off-image (project.py's ``_radii``); branch-free."""
    mid = 0.5 * (a + c)
    r = math.ceil(3.0 * math.sqrt(mid + math.sqrt(max(mid * mid - det, 0.1))))  # max: rounding
    keep = (abs(r) < np.inf) & (mx + r > 0) & (mx - r < width) & (my + r > 0) & (my - r < height)
    return min(r, MAX_RADIUS) if keep else 0.0  # min: int32 range


@njit(inline="always")
def _camera(W_arr, cam_arr):
    """w2c rows and the camera vector as tuples (loaded once, outside the loops)."""
    W = ((W_arr[0, 0], W_arr[0, 1], W_arr[0, 2], W_arr[0, 3]), (W_arr[1, 0], W_arr[1, 1], W_arr[1, 2], W_arr[1, 3]),
         (W_arr[2, 0], W_arr[2, 1], W_arr[2, 2], W_arr[2, 3]))
    cam = (cam_arr[0], cam_arr[1], cam_arr[2], cam_arr[3], cam_arr[4], cam_arr[5], cam_arr[6], cam_arr[7])
    return W, cam


@njit(cache=True, nogil=True, error_model="numpy")  # numpy: no zero test before each division
def _project_forward(means, scales, quats, W_arr, cam_arr, near, low_pass, height, width, counter, total, means2d,
                     conics, depths, cov2d, radii):
    """The chunks of the ``total`` Gaussians this worker takes (``next_chunk``) into means2d
    (N, 2), conics (N, 3), depths (N,), cov2d (N, 3) (separate contiguous arrays: the rasterizer
    reads them; any float dtype, computed in float64) and radii (N,) int32."""
    W, cam = _camera(W_arr, cam_arr)
    inp, out = np.empty((10, CHUNK)), np.empty((10, CHUNK))
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        gather_columns(quats, c0, n, inp, gather_columns(scales, c0, n, inp, gather_columns(means, c0, n, inp, 0)))
        for j in range(CHUNK):  # the vectorised loop (a full chunk: stale columns are ignored)
            m, s, q = (inp[0, j], inp[1, j], inp[2, j]), (inp[3, j], inp[4, j], inp[5, j]), (inp[6, j], inp[7, j],
                                                                                             inp[8, j], inp[9, j])
            (x, y, z, zs, in_front), _, _, _, _, _, (a0, b, c0_, det) = _core(m, s, q, W, cam, near, low_pass)
            ok = in_front & (det > 0.0) & (det < np.inf)
            inv_ds = 1.0 / det if ok else 1.0
            a, c = a0 + low_pass, c0_ + low_pass
            mx, my = cam[0] * x / zs + cam[2], cam[1] * y / zs + cam[3]
            out[0, j], out[1, j], out[2, j], out[3, j], out[4, j] = mx, my, c * inv_ds, -b * inv_ds, a * inv_ds
            out[5, j], out[6, j], out[7, j], out[8, j] = z, a, b, c
            out[9, j] = _radius(a, c, det, mx, my, height, width) if ok else 0.0
        for j in range(n):
            i = c0 + j
            means2d[i, 0], means2d[i, 1] = out[0, j], out[1, j]
            conics[i, 0], conics[i, 1], conics[i, 2] = out[2, j], out[3, j], out[4, j]
            depths[i], cov2d[i, 0], cov2d[i, 1], cov2d[i, 2] = out[5, j], out[6, j], out[7, j], out[8, j]
            radii[i] = np.int32(out[9, j])


@njit(inline="always")
def _quat_backward(qhat, inv_qn, clamped, G):
    """dL/dq (4-tuple) from G = dL/dR (rows), R = R(q / |q|) (clamped norm: see _rotation)."""
    w, x, y, z = qhat
    gw = 2 * (-z * G[0][1] + y * G[0][2] + z * G[1][0] - x * G[1][2] - y * G[2][0] + x * G[2][1])
    gx = 2 * (y * G[0][1] + z * G[0][2] + y * G[1][0] - 2 * x * G[1][1] - w * G[1][2] + z * G[2][0]
              + w * G[2][1] - 2 * x * G[2][2])
    gy = 2 * (-2 * y * G[0][0] + x * G[0][1] + w * G[0][2] + x * G[1][0] + z * G[1][2] - w * G[2][0]
              + z * G[2][1] - 2 * y * G[2][2])
    gz = 2 * (-2 * z * G[0][0] - w * G[0][1] + x * G[0][2] + w * G[1][0] - 2 * z * G[1][1] + y * G[1][2]
              + x * G[2][0] + y * G[2][1])
    dot = 0.0 if clamped else w * gw + x * gx + y * gy + z * gz  # clamped: the norm is constant there
    return (gw - w * dot) * inv_qn, (gx - x * dot) * inv_qn, (gy - y * dot) * inv_qn, (gz - z * dot) * inv_qn


@njit(inline="always")
def _jacobian_backward(x, y, zs, u_free, v_free, inv_z, W, cam, gJ0, gJ1, g_mx, g_my):
    """dL/d(x, y, zs) through the J W rows and the projected centre."""
    fx, fy = cam[0], cam[1]
    inv_z2 = inv_z * inv_z
    u, v = min(max(x * inv_z, cam[4]), cam[5]), min(max(y * inv_z, cam[6]), cam[7])
    g_A0 = gJ0[0] * (W[0][0] - u * W[2][0]) + gJ0[1] * (W[0][1] - u * W[2][1]) + gJ0[2] * (W[0][2] - u * W[2][2])
    g_A1 = gJ1[0] * (W[1][0] - v * W[2][0]) + gJ1[1] * (W[1][1] - v * W[2][1]) + gJ1[2] * (W[1][2] - v * W[2][2])
    g_u = -fx * inv_z * (gJ0[0] * W[2][0] + gJ0[1] * W[2][1] + gJ0[2] * W[2][2])
    g_v = -fy * inv_z * (gJ1[0] * W[2][0] + gJ1[1] * W[2][1] + gJ1[2] * W[2][2])
    g_u, g_v = (g_u if u_free else 0.0), (g_v if v_free else 0.0)  # clamped: no gradient
    g_x = g_mx * fx * inv_z + g_u * inv_z
    g_y = g_my * fy * inv_z + g_v * inv_z
    g_zs = (-(g_A0 * fx + g_A1 * fy) - (g_mx * fx * x + g_my * fy * y) - g_u * x - g_v * y) * inv_z2
    return g_x, g_y, g_zs


@njit(cache=True, nogil=True, error_model="numpy")
def _project_backward(means, scales, quats, W_arr, cam_arr, near, low_pass, g_m2d, g_con, g_depth, g_cov, counter,
                      total, g_means, g_scales, g_quats):
    """The chunks of the ``total`` Gaussians this worker takes: dL/dmeans (N, 3), dL/dscales
    (N, 3), dL/dquats (N, 4) (written, any float dtype) from dL/d(means2d, conics, depths, cov2d)
    (zeros where an output had none)."""
    W, cam = _camera(W_arr, cam_arr)
    inp, out = np.empty((19, CHUNK)), np.empty((10, CHUNK))
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        row = gather_columns(quats, c0, n, inp,
                             gather_columns(scales, c0, n, inp, gather_columns(means, c0, n, inp, 0)))
        gather_columns(g_cov, c0, n, inp,
                       gather_columns(g_depth, c0, n, inp,
                                      gather_columns(g_con, c0, n, inp, gather_columns(g_m2d, c0, n, inp, row))))
        for j in range(CHUNK):  # the vectorised loop: arrays only indexed here (passing one to a
            # function would add reference counting calls, which stop vectorisation)
            grads = (inp[10, j], inp[11, j], inp[12, j], inp[13, j], inp[14, j], inp[15, j], inp[16, j],
                     inp[17, j], inp[18, j])
            m, s, q = (inp[0, j], inp[1, j], inp[2, j]), (inp[3, j], inp[4, j], inp[5, j]), (inp[6, j], inp[7, j],
                                                                                             inp[8, j], inp[9, j])
            gm, gs, gq, good = _backward_one(m, s, q, grads, W, cam, near, low_pass)
            # zero (selects, not a branch) for a Gaussian with non-finite parameters or covariance
            out[0, j], out[1, j], out[2, j] = ((gm[0] if good else 0.0), (gm[1] if good else 0.0),
                                               (gm[2] if good else 0.0))
            out[3, j], out[4, j], out[5, j] = ((gs[0] if good else 0.0), (gs[1] if good else 0.0),
                                               (gs[2] if good else 0.0))
            out[6, j], out[7, j] = (gq[0] if good else 0.0), (gq[1] if good else 0.0)
            out[8, j], out[9, j] = (gq[2] if good else 0.0), (gq[3] if good else 0.0)
        for j in range(n):
            i = c0 + j
            g_means[i, 0], g_means[i, 1], g_means[i, 2] = out[0, j], out[1, j], out[2, j]
            g_scales[i, 0], g_scales[i, 1], g_scales[i, 2] = out[3, j], out[4, j], out[5, j]
            g_quats[i, 0], g_quats[i, 1], g_quats[i, 2], g_quats[i, 3] = out[6, j], out[7, j], out[8, j], out[9, j]


@njit(inline="always")
def _backward_one(m, s, q, grads, W, cam, near, low_pass):
    """One Gaussian's dL/d(mean, scale, quaternion) (3-, 3-, 4-tuples) from its parameters and
    the output gradients ``grads`` (means2d x, y, conic a, b, c, depth, cov2d a, b, c), and whether
    they count: False where a parameter or the 2-D covariance (overflow) is not finite, whose
    gradient would be NaN (such a Gaussian is culled: the caller writes zeros)."""
    ((x, y, z, zs, in_front), (inv_qn, qhat, R), (u_free, v_free, inv_z), (J0, J1), M, (r0, r1),
     (a0, b, c0, det)) = _core(m, s, q, W, cam, near, low_pass)
    g0, g1, g2, g3, g4, g5, g6, g7, g8 = grads
    ok = in_front & (det > 0.0) & (det < np.inf)
    inv_ds = 1.0 / det if ok else 1.0
    a, c = a0 + low_pass, c0 + low_pass
    g_det = -(g2 * c - g3 * b + g4 * a) * (inv_ds * inv_ds) if ok else 0.0
    g_a0 = g6 + g4 * inv_ds + g_det * low_pass
    g_c0 = g8 + g2 * inv_ds + g_det * low_pass
    g_b = g7 - g3 * inv_ds
    # rows r0, r1: a0 = |r0|², b = r0·r1, c0 = |r1|², det through |n|², n = r0 x r1
    n = _cross(r0, r1)
    gr0 = _axpy(2 * g_a0, r0, _axpy(g_b, r1, _axpy(2 * g_det, _cross(r1, n), (0.0, 0.0, 0.0))))
    gr1 = _axpy(2 * g_c0, r1, _axpy(g_b, r0, _axpy(2 * g_det, _cross(n, r0), (0.0, 0.0, 0.0))))
    # r_i[j] = Σ_k J_i[k] M[k][j]
    gJ0 = (_dot(gr0, M[0]), _dot(gr0, M[1]), _dot(gr0, M[2]))
    gJ1 = (_dot(gr1, M[0]), _dot(gr1, M[1]), _dot(gr1, M[2]))
    gM0 = (J0[0] * gr0[0] + J1[0] * gr1[0], J0[0] * gr0[1] + J1[0] * gr1[1], J0[0] * gr0[2] + J1[0] * gr1[2])
    gM1 = (J0[1] * gr0[0] + J1[1] * gr1[0], J0[1] * gr0[1] + J1[1] * gr1[1], J0[1] * gr0[2] + J1[1] * gr1[2])
    gM2 = (J0[2] * gr0[0] + J1[2] * gr1[0], J0[2] * gr0[1] + J1[2] * gr1[1], J0[2] * gr0[2] + J1[2] * gr1[2])
    # M[k][j] = R[k][j] s[j]
    g_s = (gM0[0] * R[0][0] + gM1[0] * R[1][0] + gM2[0] * R[2][0],
           gM0[1] * R[0][1] + gM1[1] * R[1][1] + gM2[1] * R[2][1],
           gM0[2] * R[0][2] + gM1[2] * R[1][2] + gM2[2] * R[2][2])
    gR = ((gM0[0] * s[0], gM0[1] * s[1], gM0[2] * s[2]), (gM1[0] * s[0], gM1[1] * s[1], gM1[2] * s[2]),
          (gM2[0] * s[0], gM2[1] * s[1], gM2[2] * s[2]))
    clamped = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] < 1e-24
    gq = _quat_backward(qhat, inv_qn, clamped, gR)
    g_x, g_y, g_zs = _jacobian_backward(x, y, zs, u_free, v_free, inv_z, W, cam, gJ0, gJ1, g0, g1)
    g_z = g5 + (g_zs if in_front else 0.0)
    g_m = (W[0][0] * g_x + W[1][0] * g_y + W[2][0] * g_z, W[0][1] * g_x + W[1][1] * g_y + W[2][1] * g_z,
           W[0][2] * g_x + W[1][2] * g_y + W[2][2] * g_z)
    good = (det < np.inf) & _finite3(m) & _finite3(s) & _finite3(q) & (abs(q[3]) < np.inf)
    return g_m, g_s, gq, good


@njit(inline="always")
def _finite3(v):
    """The first three entries of a tuple are finite (not NaN, not ±inf)."""
    return (abs(v[0]) < np.inf) & (abs(v[1]) < np.inf) & (abs(v[2]) < np.inf)


def _camera_vector(fx, fy, cx, cy, height, width) -> np.ndarray:
    """(8,) fx, fy, cx, cy and the x/z, y/z clamp limits of project.py's ``_jw_rows``."""
    half_x, half_y = 0.5 * width / fx, 0.5 * height / fy
    return np.array([fx, fy, cx, cy, -cx / fx - 0.3 * half_x, (width - cx) / fx + 0.3 * half_x,
                     -cy / fy - 0.3 * half_y, (height - cy) / fy + 0.3 * half_y], dtype=np.float64)


def _array(t: Tensor | None, shape: tuple, dtype) -> np.ndarray:
    """A gradient as a numpy view (no copy); None (no gradient) as zeros (a branch-free kernel)."""
    return np.zeros(shape, dtype) if t is None else t.detach().cpu().numpy()


class _ProjectNative(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, scales, quats, w2c, cam, near, low_pass, height, width):
        ctx.set_materialize_grads(False)  # depths / cov2d usually get no gradient: no zero tensors
        arrays = tuple(t.detach().cpu().numpy() for t in (means, scales, quats))
        arrays += (w2c,)  # float64 (3, 4), checked (project_gaussians_native)
        n, dt = len(means), arrays[0].dtype
        out = (np.empty((n, 2), dt), np.empty((n, 3), dt), np.empty(n, dt), np.empty((n, 3), dt), np.zeros(n, np.int32))
        in_chunks(_project_forward, n, (*arrays, cam, near, low_pass, height, width), out)
        ctx.saved = (arrays, cam, near, low_pass)
        return tuple(torch.from_numpy(o) for o in out)  # means2d, conics, depths, cov2d, radii

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_depth, g_cov, _g_radii):
        arrays, cam, near, low_pass = ctx.saved
        n, dt = len(arrays[0]), arrays[0].dtype
        grads = (_array(g_m2d, (n, 2), dt), _array(g_con, (n, 3), dt), _array(g_depth, (n,), dt).reshape(n, 1),
                 _array(g_cov, (n, 3), dt))
        out = tuple(np.empty(a.shape, a.dtype) for a in arrays[:3])  # dL/d(means, scales, quats)
        in_chunks(_project_backward, len(arrays[0]), (*arrays, cam, near, low_pass, *grads), out)
        return (*(torch.from_numpy(o) for o in out), None, None, None, None, None, None)


def project_gaussians_native(
    means: Tensor, scales: Tensor, quats: Tensor, w2c: Tensor, fx: float, fy: float, cx: float, cy: float,
    height: int, width: int, near: float = 0.01, low_pass: float = 0.3,
) -> Projected:
    """Same arguments and outputs as :func:`.project.project_gaussians` (no gradient to w2c).

    Any parameter values: a Gaussian with a non-finite mean, scale or quaternion (or whose 2-D
    covariance overflows) is culled (radius 0) and gets zero gradient. A camera with non-finite
    values, a focal length <= 0 or an empty image raises :class:`.project.CameraError`."""
    check_gaussians(means, scales, quats)
    w2c, fx, fy, cx, cy, height, width, near, low_pass = check_camera(w2c, fx, fy, cx, cy, height, width, near,
                                                                      low_pass)
    cam = _camera_vector(fx, fy, cx, cy, height, width)
    means2d, conics, depths, cov2d, radii = _ProjectNative.apply(means, scales, quats, w2c, cam, near, low_pass,
                                                                 height, width)
    return Projected(means2d, conics, depths, radii, cov2d)

"""Image-quality metrics (PSNR, SSIM, LPIPS) and the differentiable SSIM training loss.

Layouts
-------
- Reported metrics ``psnr``, ``ssim``, ``lpips`` take ONE image pair: sRGB (H, W, 3) float arrays
  in [0, 1], numpy or torch (any (H, W, C) works for PSNR/SSIM), and return Python floats. They are
  numpy code (:mod:`.scores`, re-exported here), so that a scoring job never imports torch.
- Batched torch functions (``ssim_map``, ``ssim_loss``, ``ssim_loss_fast``, ``lpips_batch``)
  take (B, C, H, W) tensors in [0, 1] and keep gradients.

Conventions (pinned)
--------------------
- PSNR: data range 1, ``10 log10(1 / MSE)`` over all pixels and channels, computed in float64;
  identical images give ``float('inf')``.
- SSIM (reported metric, ``ssim``): Wang et al. (2004) — Gaussian window 11x11, sigma 1.5,
  K1 = 0.01, K2 = 0.03, data range 1, population covariance (no N/(N-1) factor), 'valid'
  filtering (no padding: only windows fully inside the image, i.e. a 5-pixel border is dropped),
  mean over the map and the channels, float64. This equals scikit-image's
  ``structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
  data_range=1, channel_axis=-1)``. Images must be at least 11x11.
- SSIM training loss (``ssim_loss``, ``ssim_loss_fast``; 3DGS's L1 + SSIM is
  :class:`spc3d.reconstruct.objectives.RGBObjective`): the 3D Gaussian Splatting
  convention — the same window and constants, but zero 'same' padding (map the size of the
  image, borders included), in the input dtype. Do not report it as the metric.
- LPIPS: v0.1 net-lin with AlexNet (``net="alex"``) or VGG16 (``net="vgg"``) as in the official
  code; images are scaled ``x * 2 - 1``. Name the backbone wherever a value is reported (3DGS
  reports VGG, gsplat/nerfstudio AlexNet). Networks: ``spc3d.evaluation.lpips_net``; weights:
  ``spc3d.evaluation.lpips_weights``.

Constant and all-black images give finite values everywhere (C1, C2 > 0 keep SSIM's
denominators positive; identical constant images give SSIM 1); LPIPS of identical images is 0.
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F

from spc3d.evaluation.lpips_net import get_lpips_net
from spc3d.evaluation.scores import (  # noqa: F401  (the reported metrics, torch-free: re-exported here)
    DATA_RANGE,
    LPIPS_MIN_SIZE,
    SSIM_K1,
    SSIM_K2,
    SSIM_SIGMA,
    SSIM_WINDOW,
    gaussian_taps,
    lpips,
    psnr,
    ssim,
    ssim_index,
)


# ---------------------------------------------------------------------------------------------
# SSIM
# ---------------------------------------------------------------------------------------------
def gaussian_window(
    size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """Normalised 1-D Gaussian taps (size,), centred on the middle tap (:func:`.scores.gaussian_taps`)."""
    return torch.from_numpy(gaussian_taps(size, sigma)).to(dtype)


def _blur(x: torch.Tensor, window: torch.Tensor, pad: int) -> torch.Tensor:
    """Separable depthwise Gaussian filter of (B, C, H, W) ``x`` with zero padding ``pad``."""
    c, k = x.shape[1], window.numel()
    x = F.conv2d(x, window.view(1, 1, 1, k).expand(c, 1, 1, k), padding=(0, pad), groups=c)
    return F.conv2d(x, window.view(1, 1, k, 1).expand(c, 1, k, 1), padding=(pad, 0), groups=c)


def ssim_map(
    pred: torch.Tensor,
    target: torch.Tensor,
    padding: str = "valid",
    window_size: int = SSIM_WINDOW,
    sigma: float = SSIM_SIGMA,
) -> torch.Tensor:
    """Per-pixel SSIM of (B, C, H, W) tensors in [0, 1], differentiable.

    ``padding="valid"``: (B, C, H - w + 1, W - w + 1), the Wang et al. / skimage metric map;
    ``padding="same"``: (B, C, H, W) with zero padding, the 3DGS training-loss map.
    Population covariance, K1 = 0.01, K2 = 0.03, data range 1.
    """
    if pred.shape != target.shape or pred.ndim != 4:
        raise ValueError(
            f"expected two (B, C, H, W) tensors of one shape, got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    if padding not in ("valid", "same"):
        raise ValueError(f"padding must be 'valid' or 'same', got {padding!r}")
    if padding == "valid" and min(pred.shape[-2:]) < window_size:
        raise ValueError(
            f"'valid' SSIM needs images of at least {window_size}x{window_size}, got {tuple(pred.shape[-2:])}"
        )
    window = gaussian_window(window_size, sigma, pred.dtype).to(pred.device)
    pad = window_size // 2 if padding == "same" else 0
    mu_x, mu_y = _blur(pred, window, pad), _blur(target, window, pad)
    var_x = _blur(pred * pred, window, pad) - mu_x**2
    var_y = _blur(target * target, window, pad) - mu_y**2
    cov = _blur(pred * target, window, pad) - mu_x * mu_y
    return ssim_index(mu_x, mu_y, var_x, var_y, cov)


def ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``1 - mean SSIM`` (3DGS convention: 'same' zero padding) of (B, C, H, W); scalar tensor."""
    return 1.0 - ssim_map(pred, target, padding="same").mean()


def _band(n: int, size: int, sigma: float, dtype: torch.dtype, device) -> torch.Tensor:
    """(n, n) matrix of the 'same' zero-padded 1-D Gaussian filter: ``x @ band`` filters the last
    axis of x (the matrix is symmetric, so ``band @ x`` filters the one before)."""
    key = (n, size, sigma, dtype, str(device))
    if key not in _BANDS:
        w, half = gaussian_window(size, sigma, torch.float64), size // 2
        offset = torch.arange(n)[None, :] - torch.arange(n)[:, None]
        inside = offset.abs() <= half
        band = torch.zeros(n, n, dtype=torch.float64)
        band[inside] = w[(offset + half)[inside]]
        _BANDS[key] = band.to(dtype=dtype, device=device)
    return _BANDS[key]


_BANDS: dict = {}  # filter matrices by (image side, window, sigma, dtype, device): a few small ones per run


def _blur_banded(x: torch.Tensor, size: int, sigma: float) -> torch.Tensor:
    """:func:`_blur` of (B, C, H, W) with 'same' zero padding, as two matrix products (on CPU
    several times faster than the depthwise convolutions, though they multiply by the zeros
    outside the band too)."""
    h, w = x.shape[-2:]
    rows = (x.reshape(-1, w) @ _band(w, size, sigma, x.dtype, x.device)).reshape(x.shape)
    return torch.matmul(_band(h, size, sigma, x.dtype, x.device), rows)


class _SSIMLoss(torch.autograd.Function):
    """1 - mean SSIM ('same' padding) with a closed-form gradient w.r.t. pred.

    Forward: the five local moments (means, second moments, cross moment) in one stacked blur.
    Backward: with S = A1 A2 / (B1 B2), A1 = 2 mu_x mu_y + c1, A2 = 2 (exy - mu_x mu_y) + c2,
    B1 = mu_x² + mu_y² + c1, B2 = exx - mu_x² + eyy - mu_y² + c2 and e.. the blurred products,
    dS/dmu_x = 2 mu_y (A2 - A1) / (B1 B2) - 2 mu_x S (1 / B1 - 1 / B2), dS/dexx = -S / B2,
    dS/dexy = 2 A1 / (B1 B2); the blur is symmetric with zero padding, hence self-adjoint, so
    dL/dpred = blur(dL/dmu_x) + 2 pred blur(dL/dexx) + target blur(dL/dexy): one stacked blur.
    """

    @staticmethod
    def forward(ctx, pred, target, size, sigma):
        c = pred.shape[1]
        moments = _blur_banded(torch.cat([pred, target, pred * pred, target * target, pred * target], 1), size, sigma)
        mu_x, mu_y, exx, eyy, exy = moments.split(c, 1)
        c1, c2 = (SSIM_K1 * DATA_RANGE) ** 2, (SSIM_K2 * DATA_RANGE) ** 2
        mxy, mxx, myy = mu_x * mu_y, mu_x * mu_x, mu_y * mu_y
        a1, a2 = 2 * mxy + c1, 2 * (exy - mxy) + c2
        b1, b2 = mxx + myy + c1, (exx - mxx) + (eyy - myy) + c2
        den = b1 * b2
        s = a1 * a2 / den
        ctx.save_for_backward(pred, target, mu_x, mu_y, a1, a2, b1, b2, den, s)
        ctx.blur = (size, sigma)
        return 1.0 - s.mean()

    @staticmethod
    def backward(ctx, grad):
        pred, target, mu_x, mu_y, a1, a2, b1, b2, den, s = ctx.saved_tensors
        g = -grad / s.numel()
        d_mu = g * (2 * mu_y * (a2 - a1) / den - 2 * mu_x * s * (1 / b1 - 1 / b2))
        d_exx, d_exy = g * -s / b2, g * 2 * a1 / den
        b_mu, b_exx, b_exy = _blur_banded(torch.cat([d_mu, d_exx, d_exy], 1), *ctx.blur).split(pred.shape[1], 1)
        return b_mu + 2 * pred * b_exx + target * b_exy, None, None, None


def ssim_loss_fast(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """:func:`ssim_loss` for training: the same value and gradient w.r.t. ``pred`` (to float
    rounding), faster: all five moments in one stacked blur and a closed-form backward
    (:class:`_SSIMLoss`); on the CPU both in one numba call (:mod:`.ssim_native`), elsewhere the
    separable blur as two matrix products with banded filter matrices. A target that needs a
    gradient gets ssim_loss itself."""
    if pred.shape != target.shape or pred.ndim != 4:
        raise ValueError(
            f"expected two (B, C, H, W) tensors of one shape, got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    if target.requires_grad:
        return ssim_loss(pred, target)
    if pred.device.type == "cpu" and pred.dtype in (torch.float32, torch.float64):
        return _SSIMLossNative.apply(pred, target.to(pred.dtype))
    return _SSIMLoss.apply(pred, target.to(pred.dtype), SSIM_WINDOW, SSIM_SIGMA)


class _SSIMLossNative(torch.autograd.Function):
    """:class:`_SSIMLoss` on CPU tensors: value and gradient in one numba call (ssim_native.py)."""

    @staticmethod
    def forward(ctx, pred, target):
        from spc3d.evaluation.ssim_native import ssim_loss_and_grad  # numba: only where training asks

        h, w = pred.shape[-2:]
        x = pred.detach().contiguous().reshape(-1, h, w).numpy()
        grad = np.empty_like(x)
        taps = gaussian_window(SSIM_WINDOW, SSIM_SIGMA, pred.dtype).numpy()
        consts = np.array([(SSIM_K1 * DATA_RANGE) ** 2, (SSIM_K2 * DATA_RANGE) ** 2, -1.0 / x.size], x.dtype)
        loss = ssim_loss_and_grad(x, target.contiguous().reshape(-1, h, w).numpy(), taps, consts, grad)
        ctx.grad = torch.from_numpy(grad).reshape(pred.shape)
        return torch.tensor(loss, dtype=pred.dtype)

    @staticmethod
    def backward(ctx, grad):
        return grad * ctx.grad, None


# ---------------------------------------------------------------------------------------------
# LPIPS
# ---------------------------------------------------------------------------------------------
def lpips_batch(
    pred: torch.Tensor,
    target: torch.Tensor,
    net: str = "alex",
    weights_path: str | os.PathLike | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> torch.Tensor:
    """LPIPS v0.1 distances (B,) of (B, 3, H, W) tensors in [0, 1]; differentiable in the inputs.

    Weights resolve as in ``spc3d.evaluation.lpips_weights.lpips_weights``; the network is cached per process.
    """
    if min(pred.shape[-2:]) < LPIPS_MIN_SIZE:
        raise ValueError(
            f"LPIPS needs images of at least {LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE} pixels (AlexNet's "
            f"strided layers and pools leave nothing of smaller ones), got {tuple(pred.shape[-2:])}"
        )
    model = get_lpips_net(net, weights_path, cache_dir)
    if model.shift.device != pred.device:
        model.to(pred.device)
    return model(pred * 2.0 - 1.0, target * 2.0 - 1.0)

"""The reported image metrics (PSNR, SSIM, LPIPS) of one image pair, in numpy.

Scoring a render needs no torch: the ``evaluate``, ``score_images`` and figure jobs import only
this module, and a process that imports torch pays ~2.5 s of CPU for it (more than such a job's
own work). The conventions are pinned in :mod:`spc3d.evaluation.metrics`, which re-exports these
functions beside its torch training losses; the tests hold both implementations to each other.

- ``psnr``: float64, data range 1, ``inf`` for identical arrays.
- ``ssim``: Wang et al. 'valid' SSIM in float64 (scikit-image's Gaussian-weighted form).
- ``lpips``: LPIPS v0.1 net-lin (AlexNet or VGG16 backbone) in float32, as the torch network
  (:mod:`.lpips_net`) computes it; convolutions as one matrix product over image patches.

Inputs may be numpy arrays or CPU/GPU torch tensors (read through ``.detach().cpu()`` without
importing torch).
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np

from spc3d.evaluation.lpips_specs import SCALE, SHIFT, SPECS, canonical_net
from spc3d.evaluation.lpips_weights import check_weights, lpips_weights
from spc3d.pixels import DATA_RANGE, as_array, psnr  # noqa: F401  (PSNR's one home, re-exported here)

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
LPIPS_MIN_SIZE = 32  # AlexNet: stride-4 conv + two 3x3/2 pools before conv3 need >= 32 px per side
NORM_EPS = 1e-10  # LPIPS's unit normalisation over channels: x / (||x|| + eps)


def _pair_hwc(pred, target, dtype) -> tuple[np.ndarray, np.ndarray]:
    a, b = as_array(pred, dtype), as_array(target, dtype)
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"expected two (H, W, C) images of one shape, got {a.shape} and {b.shape}")
    return a, b


def gaussian_taps(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """Normalised 1-D Gaussian taps (size,), float64, centred on the middle tap."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def _valid_blur(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Separable Gaussian filter of (H, W, C) ``x`` over the windows fully inside it:
    (H - k + 1, W - k + 1, C)."""
    k = len(taps)
    h, w = x.shape[0] - k + 1, x.shape[1] - k + 1
    rows = sum(t * x[:, i : i + w] for i, t in enumerate(taps))
    return sum(t * rows[i : i + h] for i, t in enumerate(taps))


def ssim_index(mu_x, mu_y, var_x, var_y, cov):
    """Wang et al.'s SSIM from local means, variances and covariance (population), data range 1:
    plain arithmetic, so numpy arrays and torch tensors alike (the torch map in :mod:`.metrics`)."""
    c1, c2 = (SSIM_K1 * DATA_RANGE) ** 2, (SSIM_K2 * DATA_RANGE) ** 2
    return (2 * mu_x * mu_y + c1) * (2 * cov + c2) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))


def ssim(pred, target) -> float:
    """SSIM (Wang et al., 'valid', float64) between two (H, W, C) images in [0, 1].

    Matches skimage ``structural_similarity(..., gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1)``.
    """
    a, b = _pair_hwc(pred, target, np.float64)
    if min(a.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"'valid' SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {a.shape[:2]}")
    taps = gaussian_taps()
    mu_x, mu_y = _valid_blur(a, taps), _valid_blur(b, taps)
    var_x = _valid_blur(a * a, taps) - mu_x**2
    var_y = _valid_blur(b * b, taps) - mu_y**2
    cov = _valid_blur(a * b, taps) - mu_x * mu_y
    return float(np.mean(ssim_index(mu_x, mu_y, var_x, var_y, cov)))


# ---------------------------------------------------------------------------------------------
# LPIPS
# ---------------------------------------------------------------------------------------------
def _windows(x: np.ndarray, k: int, stride: int) -> list[np.ndarray]:
    """The k x k strided views of (H, W, C) ``x``, one per window offset (dy, dx) in row order:
    each (H', W', C) with H' = (H - k) // stride + 1 (no padding, floor mode)."""
    h, w = (x.shape[0] - k) // stride + 1, (x.shape[1] - k) // stride + 1
    return [x[dy : dy + stride * h : stride, dx : dx + stride * w : stride] for dy in range(k) for dx in range(k)]


def _conv_relu(x: np.ndarray, kernels: np.ndarray, bias: np.ndarray, k: int, stride: int, pad: int) -> np.ndarray:
    """ReLU(conv2d) of (H, W, C) ``x``: its window views side by side, a (H' W', k k C) patch
    matrix, times ``kernels`` (O, k k C; taps ordered dy, dx, c) -> (H', W', O). Channels last
    keeps every view a run of contiguous channel vectors."""
    shifts = _windows(np.pad(x, ((pad, pad), (pad, pad), (0, 0))), k, stride)
    h, w = shifts[0].shape[:2]
    out = np.concatenate(shifts, axis=-1).reshape(h * w, -1) @ kernels.T
    out += bias
    return np.maximum(out, 0.0, out=out).reshape(h, w, -1)


def _max_pool(x: np.ndarray, k: int, stride: int) -> np.ndarray:
    """Max over k x k windows every ``stride`` pixels of (H, W, C), no padding (floor mode)."""
    first, *rest = _windows(x, k, stride)
    out = first.copy()
    for view in rest:
        np.maximum(out, view, out=out)
    return out


class LPIPS:
    """LPIPS v0.1 (net-lin) with an AlexNet or VGG16 backbone, float32 numpy, channels last; the
    layers of :class:`spc3d.evaluation.lpips_net.LPIPSNet`."""

    def __init__(self, net: str, weights: dict[str, np.ndarray]):
        self.net = canonical_net(net)
        check_weights(weights, self.net)
        self.spec = SPECS[self.net]
        self.convs = []  # (kernels (O, k k C), bias (O,), k, stride, padding) per conv
        for layer in (layer for layer in self.spec if layer[0] == "conv"):
            i, (_, out_ch, k, stride, pad) = len(self.convs), layer
            kernels = np.asarray(weights[f"conv{i}.weight"], np.float32).transpose(0, 2, 3, 1).reshape(out_ch, -1)
            bias = np.asarray(weights[f"conv{i}.bias"], np.float32)
            self.convs.append((np.ascontiguousarray(kernels), bias, k, stride, pad))
        n_taps = sum(layer[0] == "tap" for layer in self.spec)
        self.heads = [np.asarray(weights[f"lin{j}.weight"], np.float32).reshape(-1) for j in range(n_taps)]
        self.shift, self.scale = np.array(SHIFT, np.float32), np.array(SCALE, np.float32)

    def features(self, x: np.ndarray) -> list[np.ndarray]:
        """(H, W, 3) in [-1, 1] -> the five unit-normalised tap feature maps (H_k, W_k, C_k)."""
        x = (x - self.shift) / self.scale
        taps, convs = [], iter(self.convs)
        for layer in self.spec:
            if layer[0] == "conv":
                x = _conv_relu(x, *next(convs))
            elif layer[0] == "pool":
                x = _max_pool(x, layer[1], layer[2])
            else:
                taps.append(x / (np.sqrt(np.sum(x * x, axis=-1, keepdims=True)) + np.float32(NORM_EPS)))
        return taps

    def distance(self, x0: np.ndarray, x1: np.ndarray) -> float:
        """The distance between two (H, W, 3) images in [-1, 1]."""
        total = 0.0
        for head, f0, f1 in zip(self.heads, self.features(x0), self.features(x1)):
            total += float(np.mean(((f0 - f1) ** 2) @ head))
        return total


_NETS: dict[tuple, LPIPS] = {}
_NETS_LOCK = threading.Lock()


def cached_net(nets: dict, build, net: str, weights_path=None, cache_dir=None):
    """``nets[(backbone, weights file)]``, built once per process as ``build(backbone, weights)`` with
    the weights resolved by :func:`spc3d.evaluation.lpips_weights.lpips_weights`."""
    net = canonical_net(net)
    key = (net, None if weights_path is None else str(Path(weights_path).resolve()))
    with _NETS_LOCK:
        if key not in nets:
            nets[key] = build(net, lpips_weights(net, weights_path, cache_dir))
        return nets[key]


def get_lpips(
    net: str = "alex", weights_path: str | os.PathLike | None = None, cache_dir: str | os.PathLike | None = None
) -> LPIPS:
    """Process-wide cached :class:`LPIPS` (one per backbone and explicit weights file)."""
    return cached_net(_NETS, LPIPS, net, weights_path, cache_dir)


def lpips(
    pred,
    target,
    net: str = "alex",
    weights_path: str | os.PathLike | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> float:
    """LPIPS v0.1 (``net`` = 'alex' | 'vgg') between two (H, W, 3) sRGB images in [0, 1]."""
    a, b = _pair_hwc(pred, target, np.float32)
    if a.shape[2] != 3:
        raise ValueError(f"LPIPS needs RGB images (H, W, 3), got {a.shape[2]} channels")
    if min(a.shape[:2]) < LPIPS_MIN_SIZE:
        raise ValueError(
            f"LPIPS needs images of at least {LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE} pixels (AlexNet's "
            f"strided layers and pools leave nothing of smaller ones), got {a.shape[:2]}"
        )
    model = get_lpips(net, weights_path, cache_dir)
    return model.distance(a * np.float32(2) - 1, b * np.float32(2) - 1)

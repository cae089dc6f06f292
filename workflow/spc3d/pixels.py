"""What every stage computes on pixel values, numpy arrays and torch tensors alike: the sRGB
transfer functions (IEC 61966-2-1) and PSNR. One home for both: the simulator and the scene jobs
(numpy, no torch), stage 1 and stage 2 (tensors, with gradients) and the scores call these.

The module imports no torch: a tensor argument brings its own (``hasattr(x, "detach")``).
"""

from __future__ import annotations

import math

import numpy as np

DATA_RANGE = 1.0  # images in [0, 1]


def is_tensor(x: object) -> bool:
    """A torch tensor (read without importing torch)."""
    return hasattr(x, "detach")


def as_array(img, dtype) -> np.ndarray:
    """numpy array or torch tensor (any device, gradient or not) -> numpy array of ``dtype``."""
    if is_tensor(img):
        img = img.detach().cpu().numpy()
    return np.asarray(img, dtype=dtype)


def _as_float(x: object) -> np.ndarray:
    x = np.asarray(x)
    return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float64)


def srgb_to_linear(x):
    """IEC 61966-2-1 sRGB decoding of an array or tensor (any shape, clipped to [0, 1]; same shape;
    an array keeps a float dtype, an integer one becomes float64)."""
    if is_tensor(x):
        import torch

        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    x = np.clip(_as_float(x), 0.0, 1.0)
    lin = np.add(x, 0.055, out=np.empty_like(x))  # an array even for scalar input (out= below)
    lin /= 1.055
    np.power(lin, 2.4, out=lin)
    np.divide(x, 12.92, out=lin, where=x <= 0.04045)  # linear toe
    return lin


def linear_to_srgb(x):
    """IEC 61966-2-1 sRGB encoding of an array or tensor (any shape, clipped to [0, 1]; same shape).
    On a tensor the power is guarded at the knee, so its gradient at 0 stays finite."""
    if is_tensor(x):
        import torch

        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)
    x = np.clip(_as_float(x), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055)


def psnr(pred, target) -> float:
    """PSNR in dB (data range 1) between two arrays of one shape (images (H, W, C), ray batches
    (R, 3), ...); ``inf`` when they are identical. Two torch tensors (a training step's render and
    target) are compared on their own device in float64: only the scalar leaves it."""
    if is_tensor(pred) and is_tensor(target):
        a, b = pred.detach().double(), target.detach().to(pred.device).double()
    else:
        a, b = as_array(pred, np.float64), as_array(target, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"expected two arrays of one shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    mse = float(((a - b) ** 2).mean())
    if mse == 0.0:
        return float("inf")
    return 10.0 * math.log10(DATA_RANGE**2 / mse)

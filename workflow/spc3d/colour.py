"""sRGB transfer functions on torch tensors (IEC 61966-2-1), shared by stage 1 and stage 2.

The numpy versions used by the simulator live in :mod:`spc3d.physics.spc`.
"""

from __future__ import annotations

import torch
from torch import Tensor


def srgb_to_linear(x: Tensor) -> Tensor:
    """IEC 61966-2-1 sRGB decoding (torch; input clamped to [0, 1])."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: Tensor) -> Tensor:
    """IEC 61966-2-1 sRGB encoding (torch; input clamped to [0, 1], power guarded at 0)."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)

"""A physics prior for the stage-1 networks: the image a photon-rate estimate alone gives.

From one binary frame (or the mean of K), each pixel's detection probability is estimated by a
Gaussian-weighted local mean p (standard deviation ``sigma`` pixels), the photon rate per frame by
its maximum-likelihood inverse λ = −log(1 − p) (the exact MLE of the Bernoulli detection model
with the dead time longer than the frame; dark counts, 0.01 per frame at the default, are left in),
the linear intensity by a per-channel gain g and the display by the sRGB transfer:

    prior(b) = sRGB(clamp(g ⊙ −log1p(−min(blur_σ(b), 1 − ε)), 0, 1))

g is not read from any evaluation scene: :meth:`PhysicsPrior.fit` sets it once, before training,
by matching the mean linear intensity of the training scenes' images to the mean rate of their
binary inputs (marginal means only, so it also serves unpaired training). It is a buffer of the
network, saved with it.

A translator built with ``prior_sigma > 0`` predicts a *residual* over this image (its network's
output is added to the prior, in the network's value range), so training starts from the
blurred-MLE estimate and the network learns what it lacks: edges and texture. The residual has no
mean (per image and channel) and the training targets are re-levelled to the prior's mean
(:meth:`PhysicsPrior.relevel`): every scene is exposed to the same mean detection rate, so the
frames carry no absolute brightness, and the level and colour balance are the prior's. This is a
deviation from the published networks (``prior_sigma: 0`` restores them, as every ``PAPER``
preset does); it exists because on a CPU budget of a few hundred steps the plain networks stay
below this estimate (measured in docs/stage1.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.pixels import linear_to_srgb, srgb_to_linear

# The MLE diverges at p = 1 (every bit in the window set); 1 - 1e-3 caps λ at 6.9 photons per frame,
# which any gain fitted on scenes calibrated to a mean detection of 0.5 (λ ~ 0.7) displays as white.
P_MAX = 1.0 - 1e-3


def gaussian_kernel(sigma: float) -> Tensor:
    """1-D normalised Gaussian of standard deviation ``sigma`` pixels, radius ceil(3 sigma)."""
    radius = max(1, math.ceil(3.0 * sigma))
    x = torch.arange(-radius, radius + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


class PhysicsPrior(nn.Module):
    """(B, 3, H, W) binary image in [0, 1] -> (B, 3, H, W) blurred-MLE sRGB estimate in [0, 1]."""

    def __init__(self, sigma: float):
        super().__init__()
        if not sigma > 0:
            raise ValueError(f"prior_sigma = {sigma}: the physics prior needs a blur > 0 pixels (0 = no prior)")
        self.sigma = float(sigma)
        self.register_buffer("kernel", gaussian_kernel(self.sigma))
        self.register_buffer("gain", torch.ones(3))  # linear intensity per photon per frame; set by fit()

    def blur(self, x: Tensor) -> Tensor:
        """Separable Gaussian with reflected borders (replicated where the image is thinner than the kernel)."""
        r = self.kernel.numel() // 2
        c = x.shape[1]
        mode = "reflect" if min(x.shape[-2:]) > r else "replicate"
        kx = self.kernel.view(1, 1, 1, -1).expand(c, 1, 1, -1)
        ky = self.kernel.view(1, 1, -1, 1).expand(c, 1, -1, 1)
        x = F.conv2d(F.pad(x, (r, r, 0, 0), mode=mode), kx, groups=c)
        return F.conv2d(F.pad(x, (0, 0, r, r), mode=mode), ky, groups=c)

    def rate(self, binary: Tensor) -> Tensor:
        """Photons per frame, λ = −log(1 − p) of the blurred detection probability p (≥ 0, finite)."""
        p = self.blur(binary).clamp(0.0, P_MAX)
        return -torch.log1p(-p)

    def forward(self, binary: Tensor) -> Tensor:
        return linear_to_srgb(self.rate(binary) * self.gain.view(1, -1, 1, 1))

    @torch.no_grad()
    def relevel(self, binary: Tensor, rgb: Tensor) -> Tensor:
        """Training targets (B, 3, h, w) shifted per image and channel to the mean of the prior of
        their inputs: the level the frames cannot tell is the prior's, so the loss sees structure
        only (an unremovable offset would otherwise dominate L1's gradient signs)."""
        dims = (-2, -1)
        return rgb - rgb.mean(dim=dims, keepdim=True) + self(binary).mean(dim=dims, keepdim=True)

    @torch.no_grad()
    def fit(self, pairs: Iterable[tuple[Tensor, Tensor]]) -> Tensor:
        """Set the gain per channel so the mean linear intensity of the sRGB images equals the gain
        times the mean rate of the binary images: ``pairs`` of (3, H, W) or (B, 3, H, W) tensors
        (binary, sRGB), the training data; the two need not show the same pixels. Returns the gain."""
        rate_sum, linear_sum = torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
        rate_n = linear_n = 0
        for binary, rgb in pairs:
            binary, rgb = (t if t.ndim == 4 else t[None] for t in (binary, rgb))
            rate = self.rate(binary.to(self.kernel))
            rate_sum += rate.double().sum((0, 2, 3)).cpu()
            linear_sum += srgb_to_linear(rgb.double()).sum((0, 2, 3)).cpu()
            rate_n, linear_n = rate_n + rate[:, 0].numel(), linear_n + rgb[:, 0].numel()
        if rate_n == 0 or linear_n == 0:
            raise ValueError("PhysicsPrior.fit: no training images were given")
        mean_rate = rate_sum / rate_n
        if bool((mean_rate <= 0).any()):
            raise ValueError(
                f"PhysicsPrior.fit: the training inputs have no detections in some channel "
                f"(mean rate {mean_rate.tolist()}); the gain would be infinite"
            )
        self.gain.copy_((linear_sum / linear_n / mean_rate).to(self.gain))
        return self.gain.clone()

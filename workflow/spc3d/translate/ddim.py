"""The diffusion restorer's noise schedule and DDIM sampler, independent of the network (tested with an oracle).

make_betas       linear (Ho et al.) or cosine (Nichol & Dhariwal) betas, float64
NoiseSchedule    alpha-bar, q_sample, the v / eps targets and their inversions
ddim_sample      deterministic (eta = 0) or stochastic DDIM from x_T with a predictor
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor


def make_betas(schedule: str, timesteps: int) -> Tensor:
    """(T,) float64 betas. Linear: Ho et al.'s 1e-4..0.02 rescaled to T; cosine: Nichol & Dhariwal."""
    if schedule == "linear":
        scale = 1000.0 / timesteps
        return torch.linspace(1e-4 * scale, 0.02 * scale, timesteps, dtype=torch.float64)
    if schedule == "cosine":
        s = 0.008
        steps = torch.arange(timesteps + 1, dtype=torch.float64) / timesteps
        f = torch.cos((steps + s) / (1 + s) * math.pi / 2) ** 2
        return (1 - f[1:] / f[:-1]).clamp(max=0.999)  # clamp: avoid a singular final step
    raise ValueError(f"beta_schedule must be 'linear' or 'cosine', got {schedule!r}")


class NoiseSchedule:
    """alpha_bar_t and the conversions between (x_t, network output) and (x0, eps)."""

    def __init__(self, betas: Tensor):
        self.betas = betas.to(torch.float64)
        self.alphas_cumprod = torch.cumprod(1.0 - self.betas, dim=0)  # float64, decreasing in (0, 1)
        self.timesteps = len(betas)

    def coefs(self, t: Tensor, like: Tensor) -> tuple[Tensor, Tensor]:
        """sqrt(a_t), sqrt(1 - a_t) as (B, 1, 1, 1) tensors of like's dtype/device; t: (B,) ints."""
        ab = self.alphas_cumprod[t.cpu()]
        shape = (-1,) + (1,) * (like.ndim - 1)
        cast = {"dtype": like.dtype, "device": like.device}
        return ab.sqrt().to(**cast).reshape(shape), (1 - ab).sqrt().to(**cast).reshape(shape)

    def q_sample(self, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
        """x_t = sqrt(a) x0 + sqrt(1 - a) eps."""
        a, s = self.coefs(t, x0)
        return a * x0 + s * noise

    def target(self, x0: Tensor, noise: Tensor, t: Tensor, prediction: str) -> Tensor:
        """What the network regresses: eps, or v = sqrt(a) eps - sqrt(1 - a) x0."""
        if prediction == "eps":
            return noise
        a, s = self.coefs(t, x0)
        return a * noise - s * x0

    def to_x0_eps(self, x_t: Tensor, t: Tensor, out: Tensor, prediction: str) -> tuple[Tensor, Tensor]:
        """Invert the parameterisation: network output -> (x0, eps)."""
        a, s = self.coefs(t, x_t)
        if prediction == "eps":
            return (x_t - s * out) / a, out
        if prediction == "v":
            return a * x_t - s * out, s * x_t + a * out
        raise ValueError(f"prediction must be 'v' or 'eps', got {prediction!r}")


def ddim_timesteps(timesteps: int, steps: int) -> list[int]:
    """``steps`` descending timesteps from T-1 to 0, evenly spaced (duplicates dropped)."""
    ts = torch.linspace(timesteps - 1, 0, max(1, min(steps, timesteps)), dtype=torch.float64).round().long()
    return list(dict.fromkeys(ts.tolist()))


def ddim_sample(
    predict: Callable[[Tensor, Tensor], Tensor],
    x_T: Tensor,
    schedule: NoiseSchedule,
    steps: int,
    prediction: str,
    eta: float = 0.0,
    generator: torch.Generator | None = None,
    clip: bool = True,
) -> Tensor:
    """DDIM (Song et al. 2021) from x_T to x0; predict(x_t (B, C, H, W), t (B,) long) -> network output.

    x_prev = sqrt(a') x0 + sqrt(1 - a' - sigma^2) eps + sigma z, with a' = 1 after the last step,
    so the result is the final x0 estimate.
    """
    x = x_T
    ts = ddim_timesteps(schedule.timesteps, steps)
    ab = schedule.alphas_cumprod
    for i, t in enumerate(ts):
        t_batch = torch.full((x.shape[0],), t, dtype=torch.long, device=x.device)
        x0, eps = schedule.to_x0_eps(x, t_batch, predict(x, t_batch), prediction)
        a_t = float(ab[t])
        if clip:
            x0 = x0.clamp(-1.0, 1.0)
            eps = (x - math.sqrt(a_t) * x0) / math.sqrt(1.0 - a_t)
        a_prev = float(ab[ts[i + 1]]) if i + 1 < len(ts) else 1.0
        sigma = eta * math.sqrt((1 - a_prev) / (1 - a_t) * (1 - a_t / a_prev))
        x = math.sqrt(a_prev) * x0 + math.sqrt(max(1 - a_prev - sigma**2, 0.0)) * eps
        if sigma > 0:
            x = x + sigma * torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)
    return x

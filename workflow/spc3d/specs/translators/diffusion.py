"""The diffusion restorer's settings (:mod:`spc3d.translate.diffusion`) and the sizes DiffBIR gives.
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    base_channels: int = 32  # UNet width at full resolution
    channel_mults: tuple[int, ...] = (1, 1, 2)  # width multipliers per resolution level (one 2x down each)
    num_res_blocks: int = 1  # residual blocks per level (encoder and decoder)
    attention: bool = True  # self-attention in the middle (lowest resolution) of the UNet
    attn_window: int = 16  # that attention works in tiles of this many positions per side (0 = global)
    groups: int = 8  # GroupNorm groups (reduced to a divisor of the width when needed)
    cleaned_condition: bool = True  # also condition on a box-blurred binary image (DiffBIR's stage 1)
    clean_kernel: int = 5  # box size of that cleaner (odd)
    timesteps: int = 1000  # DDPM diffusion steps T
    beta_schedule: str = "cosine"  # "cosine" (Nichol & Dhariwal 2021) or "linear" (Ho et al. 2020)
    prediction: str = "v"  # network target: "v" (recommended, see module docstring) or "eps"
    lr: float = 2e-4  # Adam learning rate
    adam_betas: tuple[float, float] = (0.9, 0.999)  # Adam betas
    grad_clip: float = 1.0  # max global grad norm; 0 = off
    ema_decay: float = 0.999  # EMA decay of the sampling weights
    ema_warmup: bool = True  # effective decay min(decay, (1+n)/(10+n)) so early EMA is not stale
    use_ema: bool = True  # sample with the EMA weights (else the raw ones)
    sample_steps: int = 10  # DDIM steps at inference. Fewer steps drift from a sampler towards a regression to
    #                         the mean: on the training scenes' held-out views (4-flip ensemble, stage1.ensemble)
    #                         of 20 / 10 / 5 / 2 / 1 steps, fewer never scored lower PSNR, so PSNR alone would
    #                         pick one step; 10 keeps a sampler at half the cost of 20
    eta: float = 0.0  # DDIM stochasticity (0 = deterministic ODE sampler)
    sample_seed: int = 0  # seed of the generator that draws x_T (and eta > 0 noise)
    samples: int = 1  # outputs averaged per image, each from its own x_T: > 1 moves one posterior sample towards
    #                   the posterior mean (lower squared error, less detail), a deviation; DiffBIR 1
    prior_sigma: float = 2.0  # > 0: the cleaner is the blurred-MLE prior of sigma px (prior.py), not the box blur,
    #                           and the model generates the residual over it; 0: box blur, whole image
    residual_scale: float = 6.0  # the residual is generated multiplied by this: its spread (~0.15 in [-1, 1]) then
    #                              meets the unit scale the noise schedule assumes (as latent diffusion scales
    #                              its latents); 6 is the best of 1 / 3 / 6 on the training scenes' held-out
    #                              views (val PSNR 15.86 / 17.32 / 17.72 after 300 steps on the default data)


# DiffBIR publishes no sizes for a pixel-space model: only sample_steps (50) and T (1000) come from
# it; the widths are a GPU-sized version of this UNet, not Stable Diffusion's 865M-parameter UNet.
PAPER: dict = {
    "timesteps": 1000,
    "sample_steps": 50,
    "base_channels": 128,
    "channel_mults": (1, 2, 2, 4),
    "num_res_blocks": 2,
    "ema_decay": 0.9999,
    "prior_sigma": 0.0,
}

"""Restormer's settings (:mod:`spc3d.translate.restormer`) and the published sizes.
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    dim: int = 16  # channels at level 1 (level k has dim * 2**(k-1)); paper 48
    num_blocks: tuple[int, int, int, int] = (1, 1, 1, 1)  # transformer blocks per level; paper 4,6,6,8
    num_refinement_blocks: int = 0  # blocks after decoder level 1 (0 keeps a CPU step ~0.2 s); paper 4
    heads: tuple[int, int, int, int] = (1, 1, 2, 2)  # MDTA heads per level; paper 1,2,4,8
    ffn_expansion_factor: float = 2.66  # GDFN hidden width = int(dim * factor); paper 2.66
    bias: bool = False  # biases in the block convs; paper False
    layernorm_type: str = "BiasFree"  # "BiasFree" (denoising) or "WithBias" (deraining etc.)
    lr: float = 3e-4  # AdamW learning rate; paper 3e-4 (cosine-annealed to 1e-6 by the loop)
    weight_decay: float = 1e-4  # AdamW weight decay; paper 1e-4
    betas: tuple[float, float] = (0.9, 0.999)  # AdamW betas; paper (0.9, 0.999)
    grad_clip: float = 0.01  # max global grad norm (official training: use_grad_clip, 0.01); 0 = off
    prior_sigma: float = 2.0  # > 0: the global residual is over the blurred-MLE prior of sigma px (prior.py),
    #                           not over the binary input; paper 0


# Published sizes (Restormer, Gaussian/real denoising configuration).
PAPER: dict = {
    "dim": 48,
    "num_blocks": (4, 6, 6, 8),
    "num_refinement_blocks": 4,
    "heads": (1, 2, 4, 8),
    "ffn_expansion_factor": 2.66,
    "bias": False,
    "layernorm_type": "BiasFree",
    "prior_sigma": 0.0,
}

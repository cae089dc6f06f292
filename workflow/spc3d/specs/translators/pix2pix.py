"""Pix2Pix's settings (:mod:`spc3d.translate.pix2pix`) and the published sizes.
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    ngf: int = 32  # generator width at the outermost U-Net level (capped at 8 * ngf); paper 64
    num_downs: int = 6  # U-Net halvings; inputs are padded to multiples of 2**num_downs; paper 8
    dropout: bool = True  # dropout 0.5 in the inner ngf*8 decoder levels (level >= 4); paper True
    ndf: int = 32  # discriminator width of the first conv; paper 64
    n_layers_D: int = 3  # PatchGAN stride-2 layers (3 = 70x70 receptive field); paper 3
    norm: str = "batch"  # instance / batch / none, in G and D; paper batch
    gan_mode: str = "vanilla"  # vanilla (BCE with logits) or lsgan (MSE); paper vanilla
    lambda_L1: float = 100.0  # weight of the L1 reconstruction term; paper 100
    lambda_gan: float = 1.0  # weight of the adversarial term; 0: L1 only, D not trained (a deviation); paper 1
    pool_size: int = 0  # image history shown to D (0 = current batch only); paper 0
    lr: float = 2e-4  # Adam learning rate of G and D (decayed by the training loop); paper 2e-4
    beta1: float = 0.5  # Adam beta1; paper 0.5
    beta2: float = 0.999  # Adam beta2; paper 0.999
    prior_sigma: float = 2.0  # > 0: G is a residual over the blurred-MLE prior of sigma px (prior.py); paper 0


# Published sizes: unet_256 on 256x256 crops, 70x70 PatchGAN with ndf 64.
PAPER: dict = {
    "ngf": 64,
    "num_downs": 8,
    "dropout": True,
    "ndf": 64,
    "n_layers_D": 3,
    "norm": "batch",
    "gan_mode": "vanilla",
    "lambda_L1": 100.0,
    "lambda_gan": 1.0,
    "pool_size": 0,
    "lr": 2e-4,
    "beta1": 0.5,
    "prior_sigma": 0.0,
}

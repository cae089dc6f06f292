"""CycleGAN's settings (:mod:`spc3d.translate.cyclegan`) and the published sizes.
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    ngf: int = 16  # generator width of the first conv; paper 64
    n_downsampling: int = 2  # stride-2 convs in each generator; inputs padded to multiples of 2**n; paper 2
    n_blocks: int = 2  # ResNet blocks per generator; paper 9 (resnet_9blocks)
    ndf: int = 16  # discriminator width of the first conv; paper 64
    n_layers_D: int = 3  # PatchGAN stride-2 layers (70x70 receptive field); paper 3
    norm: str = "instance"  # instance / batch / none, in G and D; paper instance
    gan_mode: str = "lsgan"  # lsgan (MSE) or vanilla (BCE with logits); paper lsgan
    lambda_A: float = 10.0  # weight of the A -> B -> A cycle loss; paper 10
    lambda_B: float = 10.0  # weight of the B -> A -> B cycle loss; paper 10
    lambda_identity: float = 0.5  # identity loss, relative to lambda_A / lambda_B; paper 0.5
    lambda_pixel: float = 0.0  # > 0: paired batches and a pixel L1 term |G(a) - b|, a deviation; paper 0
    pool_size: int = 50  # generated-image history per discriminator (0 = off); paper 50
    lr: float = 2e-4  # Adam learning rate of G and D (decayed by the training loop); paper 2e-4
    beta1: float = 0.5  # Adam beta1; paper 0.5
    beta2: float = 0.999  # Adam beta2; paper 0.999
    prior_sigma: float = 2.0  # > 0: G is a residual over the blurred-MLE prior of sigma px (prior.py); paper 0


# Published sizes: resnet_9blocks generators (ngf 64), 70x70 PatchGANs (ndf 64).
PAPER: dict = {
    "ngf": 64,
    "n_downsampling": 2,
    "n_blocks": 9,
    "ndf": 64,
    "n_layers_D": 3,
    "norm": "instance",
    "gan_mode": "lsgan",
    "lambda_A": 10.0,
    "lambda_B": 10.0,
    "lambda_identity": 0.5,
    "lambda_pixel": 0.0,
    "pool_size": 50,
    "lr": 2e-4,
    "beta1": 0.5,
    "prior_sigma": 0.0,
}

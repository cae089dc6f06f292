"""Pix2PixHD's settings (:mod:`spc3d.translate.pix2pixhd`) and the published sizes.
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    ngf: int = 32  # global generator width; local enhancer k has ngf / 2**k (reference --ngf: the outermost); paper 64
    n_downsample_global: int = 3  # halvings in the global generator; paper 4
    n_blocks_global: int = 4  # ResNet blocks at the global bottleneck; paper 9
    n_local_enhancers: int = 0  # local enhancers around the global generator (x2 resolution each); paper 1
    n_blocks_local: int = 3  # ResNet blocks per local enhancer; paper 3
    ndf: int = 32  # discriminator width of the first conv; paper 64
    n_layers_D: int = 3  # stride-2 layers per PatchGAN; paper 3
    num_D: int = 2  # discriminator scales; paper 2
    norm: str = "instance"  # instance / batch / none, in G and D; paper instance
    feat_match: bool = True  # discriminator feature-matching loss; paper True
    vgg_loss: bool = True  # VGG perceptual loss (needs vgg_weights; ~+0.3 s per CPU step at 64x64), as the paper
    lambda_feat: float = 10.0  # weight of feature matching and of the VGG loss; paper 10
    lambda_L1: float = 0.0  # > 0: a pixel L1 term beside them (pix2pix's scale: 100), a deviation; paper 0
    pool_size: int = 0  # image history shown to D (0 = current batch only); paper 0
    lr: float = 2e-4  # Adam learning rate of G and D (decayed by the training loop); paper 2e-4
    beta1: float = 0.5  # Adam beta1; paper 0.5
    beta2: float = 0.999  # Adam beta2; paper 0.999
    prior_sigma: float = 2.0  # > 0: G is a residual over the blurred-MLE prior of sigma px (prior.py); paper 0

    def __post_init__(self):
        if self.ngf % 2**self.n_local_enhancers:
            raise ValueError(
                f"pix2pixhd: ngf={self.ngf} must be divisible by 2**n_local_enhancers="
                f"{2**self.n_local_enhancers} (each local enhancer halves the width)"
            )


# Published sizes: global generator 64 / 4 / 9 wrapped in one local enhancer of width 32 (the
# reference's 1024p recipe, --netG local --ngf 32), 2 x 3-layer D, feature matching + VGG loss.
PAPER: dict = {
    "ngf": 64,
    "n_downsample_global": 4,
    "n_blocks_global": 9,
    "n_local_enhancers": 1,
    "n_blocks_local": 3,
    "ndf": 64,
    "n_layers_D": 3,
    "num_D": 2,
    "norm": "instance",
    "feat_match": True,
    "vgg_loss": True,
    "lambda_feat": 10.0,
    "lambda_L1": 0.0,
    "pool_size": 0,
    "lr": 2e-4,
    "beta1": 0.5,
    "prior_sigma": 0.0,
}

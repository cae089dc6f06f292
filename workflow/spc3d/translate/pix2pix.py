"""Pix2Pix (Isola et al., 2017): U-Net generator, conditional 70x70 PatchGAN, vanilla GAN + L1.

The generator maps the binary image (in [-1, 1]) to sRGB (tanh, [-1, 1]); the discriminator
judges concat(binary, image) patch by patch. Objective, as the reference implementation:

    D:  0.5 * (BCE(D(x, G(x)), fake) + BCE(D(x, y), real))
    G:  BCE(D(x, G(x)), real) + lambda_L1 * |G(x) - y|_1

Defaults are a CPU-sized U-Net for 64x64 crops (6 halvings: 64 -> 1 at the bottleneck, as the
paper's unet_256 reaches 1x1 from 256); ``PAPER`` is the published unet_256 / ndf 64 model.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from spc3d.translate.base import PairedGANBase, adam, to_signed
from spc3d.translate.networks import (
    GANLoss,
    ImagePool,
    NLayerDiscriminator,
    UnetGenerator,
    check_multiple,
    conditional_d_step,
    init_weights,
    set_requires_grad,
)


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


class Translator(PairedGANBase):
    """Pix2Pix as a stage-1 model; ``G`` binary -> sRGB, ``D`` conditional PatchGAN."""

    paired = True

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # pix2pix has no perceptual loss
        self.cfg = cfg
        self.device = torch.device(device)
        self.multiple = 2**cfg.num_downs
        self.G = init_weights(UnetGenerator(3, 3, cfg.num_downs, cfg.ngf, cfg.norm, cfg.dropout)).to(self.device)
        self.make_prior(cfg.prior_sigma, self.G)
        self.D = init_weights(NLayerDiscriminator(6, cfg.ndf, cfg.n_layers_D, cfg.norm)).to(self.device)
        self.gan = GANLoss(cfg.gan_mode)
        self.pool = ImagePool(cfg.pool_size)
        betas = (cfg.beta1, cfg.beta2)
        self.opt_G = adam(self.G.parameters(), self.device, lr=cfg.lr, betas=betas)
        self.opt_D = adam(self.D.parameters(), self.device, lr=cfg.lr, betas=betas)

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One D step then one G step on a paired batch; binary, rgb: (B, 3, h, w) in [0, 1],
        h, w multiples of ``multiple``. ``loss`` is the generator objective."""
        self.train(True)
        check_multiple(binary, self.multiple, "pix2pix")
        x, y = to_signed(binary.to(self.device)), to_signed(rgb.to(self.device))
        fake = self.generate(x)  # (B, 3, h, w) in [-1, 1]
        adversarial = self.cfg.lambda_gan > 0
        d_terms = conditional_d_step(self.D, self.opt_D, self.gan, self.pool, x, y, fake) if adversarial else {}
        set_requires_grad([self.D], False)
        g_gan = self.gan(self.D(torch.cat([x, fake], 1)), True) if adversarial else fake.new_zeros(())
        g_l1 = F.l1_loss(fake, y)
        loss_g = self.cfg.lambda_gan * g_gan + self.cfg.lambda_L1 * g_l1
        self.opt_G.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_G.step()
        set_requires_grad([self.D], True)
        return {"loss": float(loss_g.detach()), "G_GAN": float(g_gan.detach()), "G_L1": float(g_l1.detach()), **d_terms}

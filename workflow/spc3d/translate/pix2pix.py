"""Pix2Pix (Isola et al., 2017): U-Net generator, conditional 70x70 PatchGAN, vanilla GAN + L1.

The generator maps the binary image (in [-1, 1]) to sRGB (tanh, [-1, 1]); the discriminator
judges concat(binary, image) patch by patch. Objective, as the reference implementation:

    D:  0.5 * (BCE(D(x, G(x)), fake) + BCE(D(x, y), real))
    G:  BCE(D(x, G(x)), real) + lambda_L1 * |G(x) - y|_1

Defaults are a CPU-sized U-Net for 64x64 crops (6 halvings: 64 -> 1 at the bottleneck, as the
paper's unet_256 reaches 1x1 from 256); ``PAPER`` is the published unet_256 / ndf 64 model.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from spc3d.specs.translators.pix2pix import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
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

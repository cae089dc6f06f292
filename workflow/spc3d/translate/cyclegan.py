"""CycleGAN (Zhu et al., 2017) for binary -> sRGB, trained on unpaired batches.

Domain A is the binary image, domain B sRGB. Two ResNet generators, ``G``: A -> B (used at test
time) and ``F``: B -> A, and two PatchGANs, ``D_B`` judging sRGB images and ``D_A`` binary ones
(unconditional: the data is unpaired). Objective, as the reference implementation:

    G, F:  LSGAN(D_B(G(a)), real) + LSGAN(D_A(F(b)), real)
           + lambda_A * |F(G(a)) - a|_1 + lambda_B * |G(F(b)) - b|_1                 (cycle)
           + lambda_identity * (lambda_B * |G(b) - b|_1 + lambda_A * |F(a) - a|_1)  (identity)
    D_A:   0.5 * (LSGAN(D_A(a), real) + LSGAN(D_A(pool_A(F(b))), fake)), D_B likewise

One Adam optimiser steps both generators, one both discriminators (as the reference).

``lambda_pixel > 0`` (a deviation, off by default) trains on aligned pairs and adds
``lambda_pixel * |G(a) - b|_1``: the paired pixel term the published CycleGAN cannot have, so that
its learning curve can be told apart from the lack of a target (docs/stage1.md).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.specs.translators.cyclegan import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
from spc3d.translate.base import TranslatorBase, adam, from_signed, to_signed
from spc3d.translate.networks import (
    GANLoss,
    ImagePool,
    NLayerDiscriminator,
    ResnetGenerator,
    check_multiple,
    init_weights,
    set_requires_grad,
)


def _generator(cfg: Config) -> ResnetGenerator:
    """A ResNet generator (3 -> 3 channels, no dropout), N(0, 0.02)-initialised."""
    return init_weights(ResnetGenerator(3, 3, cfg.ngf, cfg.n_downsampling, cfg.n_blocks, cfg.norm))


def _discriminator(cfg: Config) -> NLayerDiscriminator:
    """An unconditional PatchGAN on 3-channel images, N(0, 0.02)-initialised."""
    return init_weights(NLayerDiscriminator(3, cfg.ndf, cfg.n_layers_D, cfg.norm))


class Translator(TranslatorBase):
    """CycleGAN as a stage-1 model; ``train_step`` takes unpaired binary / sRGB batches (aligned
    pairs when ``lambda_pixel > 0``: then ``paired`` is True for this instance)."""

    paired = False

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # CycleGAN has no perceptual loss
        self.cfg = cfg
        self.paired = cfg.lambda_pixel > 0  # the sampler then draws the same pixels of both images
        self.device = torch.device(device)
        self.multiple = 2**cfg.n_downsampling
        self.G, self.F = _generator(cfg).to(self.device), _generator(cfg).to(self.device)
        self.make_prior(cfg.prior_sigma, self.G)
        self.D_A, self.D_B = _discriminator(cfg).to(self.device), _discriminator(cfg).to(self.device)
        self.gan = GANLoss(cfg.gan_mode)
        self.pool_A, self.pool_B = ImagePool(cfg.pool_size), ImagePool(cfg.pool_size)
        betas = (cfg.beta1, cfg.beta2)
        self.opt_G = adam([*self.G.parameters(), *self.F.parameters()], self.device, lr=cfg.lr, betas=betas)
        self.opt_D = adam([*self.D_A.parameters(), *self.D_B.parameters()], self.device, lr=cfg.lr, betas=betas)

    def modules(self) -> dict[str, nn.Module]:
        return self.with_prior({"G": self.G, "F": self.F, "D_A": self.D_A, "D_B": self.D_B})

    def g(self, x: Tensor) -> Tensor:
        """The binary -> sRGB generator on signed images: ``G``, a residual over the prior when there is one."""
        return self.plus_prior(self.G(x), x, signed=True)

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"G": self.opt_G, "D": self.opt_D}

    def forward_image(self, binary: Tensor) -> Tensor:
        """(B, 3, H', W') padded binary in [0, 1] -> (B, 3, H', W') sRGB in [0, 1] through ``G``."""
        return from_signed(self.g(to_signed(binary.to(self.device))))

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One generator step then one discriminator step; ``binary`` and ``rgb``: (B, 3, h, w) in
        [0, 1], unrelated batches (aligned with ``lambda_pixel``), h, w multiples of ``multiple``.
        ``loss`` is the G objective."""
        self.train(True)
        check_multiple(binary, self.multiple, "cyclegan")
        check_multiple(rgb, self.multiple, "cyclegan")
        a, b = to_signed(binary.to(self.device)), to_signed(rgb.to(self.device))
        if self.cfg.lambda_identity > 0 and self._batchable(a, b):  # G(b) and F(a) ride along in one pass
            (fake_b, idt_b), (fake_a, idt_a) = self._each(self.g, a, b), self._each(self.F, b, a)
        else:
            fake_b, fake_a, idt_b, idt_a = self.g(a), self.F(b), None, None  # (B, 3, h, w) each
        terms = self._generator_terms(a, b, fake_a, fake_b, idt_a, idt_b)
        loss_g = sum(terms.values())
        self.opt_G.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_G.step()
        d_terms = self._step_D(a, b, fake_a.detach(), fake_b.detach())
        return {"loss": float(loss_g.detach()), **{k: float(v.detach()) for k, v in terms.items()}, **d_terms}

    def _batchable(self, *batches: Tensor) -> bool:
        """Whether the networks may take these batches in one pass, with the same outputs: they treat
        every sample on its own (instance norm or none; batch norm pools its statistics, and its
        running statistics depend on the order of the calls) and the image sizes agree."""
        return self.cfg.norm != "batch" and len({t.shape[1:] for t in batches}) == 1

    def _each(self, net: Callable[[Tensor], Tensor], *batches: Tensor) -> list[Tensor]:
        """``[net(t) for t in batches]``, as one pass over their concatenation when
        :meth:`_batchable`: fewer, larger convolutions."""
        if not self._batchable(*batches):
            return [net(t) for t in batches]
        return list(net(torch.cat(batches)).split([t.shape[0] for t in batches]))

    def _generator_terms(
        self, a: Tensor, b: Tensor, fake_a: Tensor, fake_b: Tensor, idt_a: Tensor | None, idt_b: Tensor | None
    ) -> dict[str, Tensor]:
        """Adversarial, cycle and identity terms of the joint generator objective (D frozen);
        ``idt_a`` / ``idt_b``: F(a) / G(b) when already computed, else computed here, last."""
        cfg = self.cfg
        set_requires_grad([self.D_A, self.D_B], False)
        terms = {
            "G_GAN": self.gan(self.D_B(fake_b), True),
            "F_GAN": self.gan(self.D_A(fake_a), True),
            "cycle_A": cfg.lambda_A * F.l1_loss(self.F(fake_b), a),
            "cycle_B": cfg.lambda_B * F.l1_loss(self.g(fake_a), b),
        }
        if cfg.lambda_identity > 0:
            idt_b = self.g(b) if idt_b is None else idt_b
            idt_a = self.F(a) if idt_a is None else idt_a
            terms["idt_G"] = cfg.lambda_identity * cfg.lambda_B * F.l1_loss(idt_b, b)
            terms["idt_F"] = cfg.lambda_identity * cfg.lambda_A * F.l1_loss(idt_a, a)
        if cfg.lambda_pixel > 0:  # a and b are aligned pairs here (self.paired)
            terms["G_pixel"] = cfg.lambda_pixel * F.l1_loss(fake_b, b)
        set_requires_grad([self.D_A, self.D_B], True)
        return terms

    def _step_D(self, a: Tensor, b: Tensor, fake_a: Tensor, fake_b: Tensor) -> dict[str, float]:
        """Update D_A and D_B on real images and pooled generated ones; returns their losses."""
        real_a, pooled_a = self._each(self.D_A, a, self.pool_A.query(fake_a))
        real_b, pooled_b = self._each(self.D_B, b, self.pool_B.query(fake_b))
        loss_a = 0.5 * (self.gan(real_a, True) + self.gan(pooled_a, False))
        loss_b = 0.5 * (self.gan(real_b, True) + self.gan(pooled_b, False))
        self.opt_D.zero_grad(set_to_none=True)
        (loss_a + loss_b).backward()
        self.opt_D.step()
        return {"D_A": float(loss_a.detach()), "D_B": float(loss_b.detach())}

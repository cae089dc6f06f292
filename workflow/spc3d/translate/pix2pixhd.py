"""Pix2PixHD (Wang et al., 2018) for binary -> sRGB, with label_nc 0 and no instance maps.

Generator: the global ResNet generator (``n_downsample_global`` halvings, ``n_blocks_global``
blocks), optionally wrapped by ``n_local_enhancers`` local enhancers that each work at twice the
resolution of the network inside them. Discriminator: ``num_D`` conditional PatchGANs on an image
pyramid, judging concat(binary, image). Objective, as the reference implementation:

    D:  0.5 * (LSGAN(D(x, G(x)), fake) + LSGAN(D(x, y), real))             summed over scales
    G:  LSGAN(D(x, G(x)), real)
        + lambda_feat * 4/(n_layers_D+1) * 1/num_D * sum_scales sum_layers L1(D_l(x, G(x)), D_l(x, y))
        + lambda_feat * VGG(G(x), y)       (layer weights 1/32 .. 1; only with ``vgg_loss``)

The VGG loss uses VGG16 (the LPIPS backbone) instead of the reference's VGG19; see
``vgg.VGGFeatures``. The reference's schedule of training the global generator alone first
(``niter_fix_global``) is not reproduced: all generator parts train together.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.specs.translators.pix2pixhd import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
from spc3d.translate.base import PairedGANBase, adam, to_signed
from spc3d.translate.networks import (
    GANLoss,
    ImagePool,
    MultiscaleDiscriminator,
    ResnetBlock,
    ResnetGenerator,
    check_multiple,
    init_weights,
    norm_layer,
)
from spc3d.translate.vgg import VGGLoss


class LocalEnhancer(nn.Module):
    """One pix2pixHD local enhancer around ``inner`` (a global generator body or another enhancer).

    ``inner`` sees the input average-pooled to half resolution and returns 2 * ``ngf`` feature
    channels at that half resolution; the enhancer adds them to its own stride-2 features of
    the full-resolution input, refines with ResNet blocks and upsamples back to ``ngf`` channels
    (``Generator.head`` turns the outermost enhancer's features into an image).
    """

    def __init__(self, inner: nn.Module, in_ch: int, ngf: int, n_blocks: int, norm: str):
        super().__init__()
        make_norm = norm_layer(norm)
        self.inner = inner
        self.down = nn.Sequential(
            nn.ReflectionPad2d(3),
            nn.Conv2d(in_ch, ngf, 7),
            make_norm(ngf),
            nn.ReLU(True),
            nn.Conv2d(ngf, 2 * ngf, 3, stride=2, padding=1),
            make_norm(2 * ngf),
            nn.ReLU(True),
        )
        self.up = nn.Sequential(
            *[ResnetBlock(2 * ngf, norm) for _ in range(n_blocks)],
            nn.ConvTranspose2d(2 * ngf, ngf, 3, stride=2, padding=1, output_padding=1),
            make_norm(ngf),
            nn.ReLU(True),
        )

    def forward(self, x: Tensor) -> Tensor:
        half = F.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False)  # (B, C, H/2, W/2)
        return self.up(self.down(x) + self.inner(half))  # (B, ngf, H, W)


class Generator(nn.Module):
    """Global generator, wrapped in ``n_local_enhancers`` local enhancers when > 0."""

    def __init__(self, cfg: Config, in_ch: int = 3, out_ch: int = 3):
        super().__init__()
        glob = ResnetGenerator(in_ch, out_ch, cfg.ngf, cfg.n_downsample_global, cfg.n_blocks_global, cfg.norm)
        if cfg.n_local_enhancers == 0:
            self.body, self.head = glob.body, glob.head
            return
        body = glob.body  # (B, ngf, h, w) features; the global image head is dropped
        for k in range(1, cfg.n_local_enhancers + 1):  # the k-th enhancer (from the inside) has ngf / 2**k
            body = LocalEnhancer(body, in_ch, cfg.ngf // 2**k, cfg.n_blocks_local, cfg.norm)
        self.body = body
        width = cfg.ngf // 2**cfg.n_local_enhancers
        self.head = nn.Sequential(nn.ReflectionPad2d(3), nn.Conv2d(width, out_ch, 7), nn.Tanh())

    def forward(self, x: Tensor) -> Tensor:
        return self.head(self.body(x))  # (B, 3, H, W) in [-1, 1] -> same shape in [-1, 1]


class Translator(PairedGANBase):
    """Pix2PixHD as a stage-1 model; ``G`` binary -> sRGB, ``D`` multiscale conditional PatchGAN.

    ``vgg_weights``: ``spc3d.evaluation.lpips_weights.lpips_weights("vgg")``, required when ``cfg.vgg_loss``.
    """

    paired = True

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        self.cfg = cfg
        self.device = torch.device(device)
        self.multiple = 2 ** (cfg.n_downsample_global + cfg.n_local_enhancers)
        self.G = init_weights(Generator(cfg)).to(self.device)
        self.make_prior(cfg.prior_sigma, self.G)
        self.D = init_weights(MultiscaleDiscriminator(6, cfg.ndf, cfg.n_layers_D, cfg.norm, cfg.num_D, padding=2)).to(
            self.device
        )
        self.vgg = self._vgg_loss(cfg, vgg_weights)
        self.gan = GANLoss("lsgan")
        self.pool = ImagePool(cfg.pool_size)
        betas = (cfg.beta1, cfg.beta2)
        self.opt_G = adam(self.G.parameters(), self.device, lr=cfg.lr, betas=betas)
        self.opt_D = adam(self.D.parameters(), self.device, lr=cfg.lr, betas=betas)

    def _vgg_loss(self, cfg: Config, vgg_weights: dict | None) -> VGGLoss | None:
        if not cfg.vgg_loss:
            return None
        if vgg_weights is None:
            raise ValueError(
                "pix2pixhd: vgg_loss is True but no vgg_weights were given; pass the VGG16 "
                "weights from spc3d.evaluation.lpips_weights.lpips_weights('vgg') or set vgg_loss: false"
            )
        return VGGLoss(vgg_weights).to(self.device)

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One G step then one D step on a paired batch (reference order); binary, rgb:
        (B, 3, h, w) in [0, 1], h, w multiples of ``multiple``. ``loss`` is the G objective.

        D is not updated between the two steps, so each of its passes serves both: the real pass
        (feature-matching targets for G, as in the reference) and, without an image pool, the fake
        pass (G's adversarial and feature-matching terms, D's fake loss). Each backward names the
        parameters it is for, so G's leaves D's gradients alone and D's does not enter G. Same
        losses and updates as separate passes with D frozen for G, bit for bit; two D passes
        instead of four (~10 % of a CPU step). With ``norm: batch`` D's running statistics see
        two batches per step instead of four (D never runs in eval mode; G's are unaffected).
        """
        self.train(True)
        check_multiple(binary, self.multiple, "pix2pixhd")
        x, y = to_signed(binary.to(self.device)), to_signed(rgb.to(self.device))
        fake = self.generate(x)  # (B, 3, h, w) in [-1, 1]
        pred_real = self.D(torch.cat([x, y], 1), features=True)  # num_D lists of n_layers+2 maps
        pred_fake = self.D(torch.cat([x, fake], 1), features=True)
        terms = self._generator_terms(y, fake, pred_fake, pred_real)
        loss_g = sum(terms.values())
        shared = self.cfg.pool_size == 0  # D's fake loss reuses pred_fake (kept through G's backward)
        self.opt_G.zero_grad(set_to_none=True)
        loss_g.backward(inputs=list(self.G.parameters()), retain_graph=shared)
        self.opt_G.step()
        if not shared:
            pred_fake = self.D(self.pool.query(torch.cat([x, fake.detach()], 1)), features=True)
        d_terms = self._step_D(pred_fake, pred_real)
        return {"loss": float(loss_g.detach()), **{k: float(v.detach()) for k, v in terms.items()}, **d_terms}

    def _generator_terms(self, y: Tensor, fake: Tensor, pred_fake: list, pred_real: list) -> dict[str, Tensor]:
        """GAN, feature-matching, VGG (and pixel L1) terms of the generator objective; ``pred_fake`` / ``pred_real``:
        D's stage outputs on (x, fake) and (x, y), the latter only as constant targets."""
        terms = {"G_GAN": self.gan(pred_fake, True)}
        if self.cfg.feat_match:
            weight = self.cfg.lambda_feat * 4.0 / (self.cfg.n_layers_D + 1) / self.cfg.num_D
            terms["G_feat"] = weight * sum(
                F.l1_loss(f, r.detach()) for pf, pr in zip(pred_fake, pred_real) for f, r in zip(pf[:-1], pr[:-1])
            )
        if self.vgg is not None:
            terms["G_VGG"] = self.cfg.lambda_feat * self.vgg(fake, y)
        if self.cfg.lambda_L1 > 0:
            terms["G_L1"] = self.cfg.lambda_L1 * F.l1_loss(fake, y)
        return terms

    def _step_D(self, pred_fake: list, pred_real: list) -> dict[str, float]:
        """0.5 * (LSGAN(D(x, fake), fake) + LSGAN(D(x, y), real)) from D's outputs; one Adam step of D."""
        loss_fake, loss_real = self.gan(pred_fake, False), self.gan(pred_real, True)
        loss = 0.5 * (loss_fake + loss_real)
        self.opt_D.zero_grad(set_to_none=True)
        loss.backward(inputs=list(self.D.parameters()))
        self.opt_D.step()
        return {"D": float(loss.detach()), "D_real": float(loss_real.detach()), "D_fake": float(loss_fake.detach())}

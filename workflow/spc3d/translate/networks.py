"""Building blocks shared by the GAN translators (pix2pixHD, pix2pix, CycleGAN).

Own implementations of the architectures of Isola et al. (pix2pix), Zhu et al. (CycleGAN) and
Wang et al. (pix2pixHD), following the public reference defaults (junyanz/pytorch-CycleGAN-and-pix2pix,
NVIDIA/pix2pixHD):

    norm_layer / init_weights      normalisation factory; N(0, 0.02) initialisation
    ResnetBlock, ResnetGenerator   7x7 conv, stride-2 downsamplings, ResNet blocks, transposed-conv
                                   upsampling, tanh (CycleGAN generator, pix2pixHD global generator)
    UnetGenerator                  pix2pix U-Net with skip connections and inner dropout
    NLayerDiscriminator            PatchGAN; optionally returns every stage for feature matching
    MultiscaleDiscriminator        num_D PatchGANs on an average-pooled image pyramid (pix2pixHD)
    GANLoss                        lsgan (MSE) or vanilla (BCE with logits) against real/fake targets
    ImagePool                      history of generated images for the discriminator (CycleGAN)

Every network works on images in [-1, 1]; the model files convert from/to [0, 1].
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

NORMS = ("instance", "batch", "none")


# ---------------------------------------------------------------------------------------------
# Normalisation and initialisation
# ---------------------------------------------------------------------------------------------
def norm_layer(kind: str) -> Callable[[int], nn.Module]:
    """Factory ``channels -> norm module`` for ``kind`` in instance / batch / none.

    Instance norm has no affine parameters and no running statistics (as pix2pixHD and CycleGAN);
    batch norm is affine and tracks running statistics (used in eval mode by ``translate``).
    """
    if kind == "instance":
        return functools.partial(nn.InstanceNorm2d, affine=False, track_running_stats=False)
    if kind == "batch":
        return functools.partial(nn.BatchNorm2d, affine=True, track_running_stats=True)
    if kind == "none":
        return lambda channels: nn.Identity()
    raise ValueError(f"norm {kind!r} is not one of {NORMS}")


def conv_bias(kind: str) -> bool:
    """Convolutions before a batch norm need no bias (the norm's beta replaces it)."""
    return kind != "batch"


def init_weights(net: nn.Module, gain: float = 0.02) -> nn.Module:
    """Initialise conv / linear weights ~ N(0, gain), biases 0, batch-norm gamma ~ N(1, gain)."""
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, gain)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d) and m.affine:
            nn.init.normal_(m.weight, 1.0, gain)
            nn.init.zeros_(m.bias)
    return net


def check_multiple(x: Tensor, multiple: int, method: str) -> None:
    """Raise ValueError unless the sides of training batch ``x`` (B, C, h, w) are multiples of
    ``multiple``: the networks' skips / residuals only line up then (``translate`` pads itself)."""
    h, w = x.shape[-2:]
    if h % multiple or w % multiple:
        raise ValueError(
            f"{method}: training crops of {h}x{w} px are not multiples of {multiple}; "
            f"set stage1.train.crop to a multiple of {multiple} (or shrink the network)"
        )


def set_requires_grad(nets: list[nn.Module], flag: bool) -> None:
    """Freeze (False) or unfreeze the discriminators around the generator update, so its
    backward pass does not accumulate gradients in parameters it does not step."""
    for net in nets:
        for p in net.parameters():
            p.requires_grad_(flag)


# ---------------------------------------------------------------------------------------------
# Generators
# ---------------------------------------------------------------------------------------------
class ResnetBlock(nn.Module):
    """x + conv3(relu(norm(conv3(x)))) with reflection padding; keeps (B, C, H, W)."""

    def __init__(self, channels: int, norm: str = "instance", dropout: float = 0.0):
        super().__init__()
        make_norm, bias = norm_layer(norm), conv_bias(norm)
        layers = [
            nn.ReflectionPad2d(1),
            nn.Conv2d(channels, channels, 3, bias=bias),
            make_norm(channels),
            nn.ReLU(True),
        ]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        layers += [nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3, bias=bias), make_norm(channels)]
        self.block = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        return x + self.block(x)  # (B, C, H, W)


class ResnetGenerator(nn.Module):
    """Encoder / ResNet bottleneck / decoder generator (CycleGAN; pix2pixHD's global generator).

    ``body``: reflect-pad 7x7 conv to ``ngf``, ``n_down`` stride-2 convs doubling the width (the
    width at the bottleneck is ngf * 2**n_down, uncapped as in both references), ``n_blocks``
    ResNet blocks, ``n_down`` transposed convs back to ``ngf`` channels at full resolution.
    ``head``: reflect-pad 7x7 conv to ``out_ch`` and tanh. pix2pixHD's local enhancer reuses
    ``body`` alone. Sides must be multiples of 2**n_down.
    """

    def __init__(
        self,
        in_ch: int = 3,
        out_ch: int = 3,
        ngf: int = 64,
        n_down: int = 2,
        n_blocks: int = 9,
        norm: str = "instance",
        dropout: float = 0.0,
    ):
        super().__init__()
        make_norm, bias = norm_layer(norm), conv_bias(norm)
        layers = [nn.ReflectionPad2d(3), nn.Conv2d(in_ch, ngf, 7, bias=bias), make_norm(ngf), nn.ReLU(True)]
        for i in range(n_down):  # (B, ngf*2^i, H/2^i, W/2^i) -> (B, ngf*2^(i+1), H/2^(i+1), ...)
            c = ngf * 2**i
            layers += [nn.Conv2d(c, 2 * c, 3, stride=2, padding=1, bias=bias), make_norm(2 * c), nn.ReLU(True)]
        width = ngf * 2**n_down
        layers += [ResnetBlock(width, norm, dropout) for _ in range(n_blocks)]
        for i in reversed(range(n_down)):  # (B, 2c, h, w) -> (B, c, 2h, 2w)
            c = ngf * 2**i
            layers += [
                nn.ConvTranspose2d(2 * c, c, 3, stride=2, padding=1, output_padding=1, bias=bias),
                make_norm(c),
                nn.ReLU(True),
            ]
        self.body = nn.Sequential(*layers)
        self.head = nn.Sequential(nn.ReflectionPad2d(3), nn.Conv2d(ngf, out_ch, 7), nn.Tanh())

    def forward(self, x: Tensor) -> Tensor:
        return self.head(self.body(x))  # (B, in_ch, H, W) -> (B, out_ch, H, W) in [-1, 1]


class UnetBlock(nn.Module):
    """One U-Net level: down (4x4 stride 2), the inner levels, up (4x4 transposed), skip concat.

    ``inner`` is None at the innermost level. The outermost level has no norm on the way down,
    ends in tanh and returns no skip; every other level returns concat(x, up(...)).
    """

    def __init__(
        self,
        outer_ch: int,
        inner_ch: int,
        inner: UnetBlock | None,
        in_ch: int | None = None,
        outermost: bool = False,
        norm: str = "batch",
        dropout: float = 0.0,
    ):
        super().__init__()
        make_norm, bias = norm_layer(norm), conv_bias(norm)
        in_ch = outer_ch if in_ch is None else in_ch
        down_conv = nn.Conv2d(in_ch, inner_ch, 4, stride=2, padding=1, bias=bias)
        up_in = inner_ch if inner is None else 2 * inner_ch  # inner levels return a skip concat
        self.outermost = outermost
        if outermost:
            down = [down_conv]
            up = [nn.ReLU(True), nn.ConvTranspose2d(up_in, outer_ch, 4, stride=2, padding=1), nn.Tanh()]
        else:
            down = [nn.LeakyReLU(0.2, True), down_conv] + ([make_norm(inner_ch)] if inner is not None else [])
            up = [
                nn.ReLU(True),
                nn.ConvTranspose2d(up_in, outer_ch, 4, stride=2, padding=1, bias=bias),
                make_norm(outer_ch),
            ] + ([nn.Dropout(dropout)] if dropout > 0 else [])
        self.model = nn.Sequential(*down, *([inner] if inner is not None else []), *up)

    def forward(self, x: Tensor) -> Tensor:
        y = self.model(x)  # (B, outer_ch, H, W)
        return y if self.outermost else torch.cat([x, y], dim=1)  # (B, 2*outer_ch, H, W)


class UnetGenerator(nn.Module):
    """pix2pix U-Net: ``num_downs`` halvings (sides must be multiples of 2**num_downs).

    Level i (0 = outermost) has width ngf * min(2**i, 8); as in pix2pix's unet_256 (num_downs 8)
    the ngf*8 levels between level 4 and the innermost use dropout 0.5 when ``dropout`` is set.
    The innermost level has no norm on its way down (its output is 1x1 at the training size).
    """

    def __init__(
        self,
        in_ch: int = 3,
        out_ch: int = 3,
        num_downs: int = 8,
        ngf: int = 64,
        norm: str = "batch",
        dropout: bool = True,
    ):
        super().__init__()
        if num_downs < 2:
            raise ValueError(f"UnetGenerator num_downs must be >= 2, got {num_downs}")
        width = [ngf * min(2**i, 8) for i in range(num_downs)]
        block = UnetBlock(width[-2], width[-1], None, norm=norm)  # innermost
        for i in reversed(range(1, num_downs - 1)):  # level i: width[i-1] -> width[i] channels
            p = 0.5 if dropout and i >= 4 else 0.0
            block = UnetBlock(width[i - 1], width[i], block, norm=norm, dropout=p)
        self.model = UnetBlock(out_ch, ngf, block, in_ch=in_ch, outermost=True, norm=norm)

    def forward(self, x: Tensor) -> Tensor:
        return self.model(x)  # (B, in_ch, H, W) -> (B, out_ch, H, W) in [-1, 1]


# ---------------------------------------------------------------------------------------------
# Discriminators
# ---------------------------------------------------------------------------------------------
class NLayerDiscriminator(nn.Module):
    """PatchGAN: ``n_layers`` stride-2 4x4 convs, one stride-1 conv, a 1-channel logit map.

    With n_layers 3 each logit sees a 70x70 patch. ``padding`` is 1 in pix2pix / CycleGAN and 2
    in pix2pixHD. ``forward(x, features=True)`` returns the n_layers + 2 stage outputs (the last
    is the logit map) for pix2pixHD's feature-matching loss; otherwise the logits alone.
    """

    def __init__(self, in_ch: int, ndf: int = 64, n_layers: int = 3, norm: str = "batch", padding: int = 1):
        super().__init__()
        make_norm, bias = norm_layer(norm), conv_bias(norm)
        stages = [nn.Sequential(nn.Conv2d(in_ch, ndf, 4, 2, padding), nn.LeakyReLU(0.2, True))]
        c = ndf
        for i in range(1, n_layers + 1):  # stride 2 for the first n_layers - 1, then stride 1
            c_next = ndf * min(2**i, 8)
            stride = 2 if i < n_layers else 1
            stages.append(
                nn.Sequential(
                    nn.Conv2d(c, c_next, 4, stride, padding, bias=bias), make_norm(c_next), nn.LeakyReLU(0.2, True)
                )
            )
            c = c_next
        stages.append(nn.Sequential(nn.Conv2d(c, 1, 4, 1, padding)))
        self.stages = nn.ModuleList(stages)

    def forward(self, x: Tensor, features: bool = False) -> Tensor | list[Tensor]:
        outs = []
        for stage in self.stages:
            x = stage(x)
            outs.append(x)
        return outs if features else x  # logits (B, 1, h, w)


class MultiscaleDiscriminator(nn.Module):
    """``num_D`` PatchGANs; D_k sees the input average-pooled k times (3x3, stride 2).

    ``forward`` returns one entry per scale (finest first): a logit map, or with
    ``features=True`` the list of that discriminator's stage outputs.
    """

    def __init__(
        self, in_ch: int, ndf: int = 64, n_layers: int = 3, norm: str = "instance", num_D: int = 2, padding: int = 2
    ):
        super().__init__()
        self.discriminators = nn.ModuleList(
            NLayerDiscriminator(in_ch, ndf, n_layers, norm, padding) for _ in range(num_D)
        )

    def forward(self, x: Tensor, features: bool = False) -> list:
        outs = []
        for k, d in enumerate(self.discriminators):
            if k:
                x = F.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False)  # (B, C, H/2, W/2)
            outs.append(d(x, features))
        return outs


# ---------------------------------------------------------------------------------------------
# Losses and the image pool
# ---------------------------------------------------------------------------------------------
class GANLoss(nn.Module):
    """Adversarial loss against a constant real (1) or fake (0) target.

    ``mode`` lsgan: mean squared error on raw outputs; vanilla: BCE with logits. ``pred`` may be a
    tensor or a list of them (one per discriminator scale; a nested list's last entry is the
    logit map), in which case the per-scale losses are summed as in pix2pixHD.
    """

    def __init__(self, mode: str = "lsgan"):
        super().__init__()
        if mode not in ("lsgan", "vanilla"):
            raise ValueError(f"gan mode {mode!r} is not 'lsgan' or 'vanilla'")
        self.mode = mode

    def forward(self, pred: Tensor | list, target_is_real: bool) -> Tensor:
        if isinstance(pred, (list, tuple)):
            return sum(self(p[-1] if isinstance(p, (list, tuple)) else p, target_is_real) for p in pred)
        target = torch.full_like(pred, 1.0 if target_is_real else 0.0)
        if self.mode == "lsgan":
            return F.mse_loss(pred, target)
        return F.binary_cross_entropy_with_logits(pred, target)


class ImagePool:
    """History of generated images shown to the discriminator (Shrivastava et al.; CycleGAN).

    Until ``size`` images are stored each query image is stored and returned; afterwards each is,
    with probability 1/2, swapped for a random stored one (the old one is returned), else returned
    as is. ``size`` 0 returns the batch unchanged. The random draws come from a private
    generator seeded from torch's global RNG at construction, so runs repeat under
    ``torch.manual_seed`` and the pool does not perturb the global stream later on.
    """

    def __init__(self, size: int = 50):
        self.size = int(size)
        self.images: list[Tensor] = []
        seed = int(torch.randint(0, 2**62, (1,)).item())
        self.generator = torch.Generator().manual_seed(seed)

    def query(self, images: Tensor) -> Tensor:
        """(B, C, H, W) generated images -> (B, C, H, W) mix of these and stored older ones."""
        if self.size == 0:
            return images
        out = []
        for image in images.detach():
            image = image.unsqueeze(0)  # (1, C, H, W)
            if len(self.images) < self.size:
                self.images.append(image.clone())
                out.append(image)
            elif torch.rand(1, generator=self.generator).item() < 0.5:
                k = int(torch.randint(0, self.size, (1,), generator=self.generator).item())
                out.append(self.images[k].clone())
                self.images[k] = image.clone()
            else:
                out.append(image)
        return torch.cat(out, dim=0)


def conditional_d_step(
    D: nn.Module, opt: torch.optim.Optimizer, gan: GANLoss, pool: ImagePool, x: Tensor, y: Tensor, fake: Tensor
) -> dict[str, float]:
    """One update of a conditional discriminator on real pairs (x, y) and pooled fake pairs
    (x, fake) with the 0.5-weighted objective of pix2pix / pix2pixHD; returns its losses."""
    fake_pair = pool.query(torch.cat([x, fake.detach()], 1))  # (B, 6, h, w)
    loss_fake = gan(D(fake_pair), False)
    loss_real = gan(D(torch.cat([x, y], 1)), True)
    loss = 0.5 * (loss_fake + loss_real)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return {"D": float(loss.detach()), "D_real": float(loss_real.detach()), "D_fake": float(loss_fake.detach())}

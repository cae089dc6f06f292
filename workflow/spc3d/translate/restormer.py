"""Restormer (Zamir et al., CVPR 2022) as a stage-1 denoiser: binary SPC image -> sRGB.

Architecture (written from the paper; only the *attribute names* follow the official repository
``swz30/Restormer`` so that its ``.pth`` checkpoints load with ``load_state_dict(strict=True)``):

    patch_embed      3x3 conv, 3 -> dim ("overlapped patch embedding")
    encoder_level1   blocks at dim,   full resolution
    down1_2          3x3 conv (C -> C/2) + PixelUnshuffle(2)       -> 2C channels at 1/2
    encoder_level2   blocks at 2dim,  1/2
    encoder_level3   blocks at 4dim,  1/4
    latent           blocks at 8dim,  1/8
    up4_3            3x3 conv (C -> 2C) + PixelShuffle(2)           -> C/2 channels at 2x
    reduce_chan_*    1x1 conv after each skip concatenation (levels 3 and 2; not at level 1)
    decoder_level1   blocks at 2dim (level 1 keeps the concatenated width)
    refinement       blocks at 2dim
    output           3x3 conv 2dim -> 3, plus the input image (global residual)

Each transformer block is ``x + MDTA(LN(x))`` then ``x + GDFN(LN(x))``. MDTA attends across
*channels* (a C/h x C/h attention map per head), so its cost is linear in the number of pixels,
which is what makes Restormer usable on full-resolution images.

Here it is trained from scratch on (binary, RGB) pairs with L1, exactly like a denoiser: the net
predicts the residual ``rgb - binary`` (with ``prior_sigma`` > 0, the default here, ``rgb - prior``:
the residual over the blurred-MLE image of :mod:`.prior`). The public checkpoints (SIDD real
denoising, Gaussian sigma 15/25/50) were not trained on Bernoulli noise (Zamir et al. 2022, swz30/Restormer), but
``load_official_checkpoint`` loads them, e.g. as an initialisation or a zero-shot baseline.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d import io
from spc3d.specs.translators.restormer import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
from spc3d.translate.base import TranslatorBase, adam, pad_to_multiple

# ----------------------------------------------------------------------------------------------
# Building blocks
# ----------------------------------------------------------------------------------------------


def channel_variance(x: Tensor) -> Tensor:
    """(B, C, H, W) -> (B, 1, H, W) population variance over channels (two-pass: stable, and
    faster on CPU than ``Tensor.var`` over the strided channel axis)."""
    xc = x - x.mean(dim=1, keepdim=True)
    return (xc * xc).mean(dim=1, keepdim=True)


class BiasFreeNorm(nn.Module):
    """Per-pixel LayerNorm over channels *without* mean subtraction: x / sqrt(var + eps) * w.

    The paper uses it for denoising: not re-centring keeps the features' absolute level, which
    matters when the network must preserve the mean intensity of the image.
    """

    def __init__(self, channels: int, eps: float = 1e-5):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.eps = eps

    def forward(self, x: Tensor) -> Tensor:  # (B, C, H, W) -> (B, C, H, W)
        return x * torch.rsqrt(channel_variance(x) + self.eps) * self.weight[:, None, None]


class WithBiasNorm(nn.Module):
    """Standard per-pixel LayerNorm over channels with learnable scale and shift."""

    def __init__(self, channels: int, eps: float = 1e-5):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.eps = eps

    def forward(self, x: Tensor) -> Tensor:  # (B, C, H, W) -> (B, C, H, W)
        xc = x - x.mean(dim=1, keepdim=True)
        var = (xc * xc).mean(dim=1, keepdim=True)
        return xc * torch.rsqrt(var + self.eps) * self.weight[:, None, None] + self.bias[:, None, None]


class ChannelLayerNorm(nn.Module):
    """Holder so parameter names read ``norm1.body.weight`` as in the official checkpoints."""

    def __init__(self, channels: int, kind: str):
        super().__init__()
        if kind not in ("BiasFree", "WithBias"):
            raise ValueError(f"layernorm_type must be 'BiasFree' or 'WithBias', got {kind!r}")
        self.body = BiasFreeNorm(channels) if kind == "BiasFree" else WithBiasNorm(channels)

    def forward(self, x: Tensor) -> Tensor:
        return self.body(x)


class MDTA(nn.Module):
    """Multi-Dconv head Transposed Attention.

    q, k, v come from a 1x1 conv (pixel-wise channel mixing) followed by a 3x3 depthwise conv
    (local spatial context). Attention is computed between channels: per head, q and k are
    (C/h, HW) matrices, L2-normalised along HW, so q k^T is a (C/h, C/h) matrix of cosine
    similarities, scaled by a learnable per-head temperature before the softmax.
    """

    def __init__(self, dim: int, num_heads: int, bias: bool):
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"MDTA: {dim} channels do not split into {num_heads} heads")
        self.num_heads = num_heads
        self.temperature = nn.Parameter(torch.ones(num_heads, 1, 1))
        self.qkv = nn.Conv2d(dim, dim * 3, 1, bias=bias)
        self.qkv_dwconv = nn.Conv2d(dim * 3, dim * 3, 3, padding=1, groups=dim * 3, bias=bias)
        self.project_out = nn.Conv2d(dim, dim, 1, bias=bias)

    def _heads(self, t: Tensor) -> Tensor:  # (B, C, H, W) -> (B, heads, C/heads, HW)
        b, c, h, w = t.shape
        return t.reshape(b, self.num_heads, c // self.num_heads, h * w)

    def attention(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(B, C, H, W) -> (attention (B, heads, C/h, C/h) with rows summing to 1, v (B, heads, C/h, HW))."""
        q, k, v = self.qkv_dwconv(self.qkv(x)).chunk(3, dim=1)
        q = F.normalize(self._heads(q), dim=-1)
        k = F.normalize(self._heads(k), dim=-1)
        attn = (q @ k.transpose(-2, -1)) * self.temperature  # (B, heads, C/h, C/h)
        return attn.softmax(dim=-1), self._heads(v)

    def forward(self, x: Tensor) -> Tensor:  # (B, C, H, W) -> (B, C, H, W)
        attn, v = self.attention(x)
        out = (attn @ v).reshape(x.shape)  # (B, heads, C/h, HW) -> (B, C, H, W)
        return self.project_out(out)


class GDFN(nn.Module):
    """Gated-Dconv Feed-forward Network: 1x1 expand to 2 hidden, 3x3 depthwise, GELU(x1) * x2, 1x1 back.

    The gate lets each position decide which features pass to the next level of the hierarchy.
    """

    def __init__(self, dim: int, ffn_expansion_factor: float, bias: bool):
        super().__init__()
        hidden = int(dim * ffn_expansion_factor)
        self.project_in = nn.Conv2d(dim, hidden * 2, 1, bias=bias)
        self.dwconv = nn.Conv2d(hidden * 2, hidden * 2, 3, padding=1, groups=hidden * 2, bias=bias)
        self.project_out = nn.Conv2d(hidden, dim, 1, bias=bias)

    def forward(self, x: Tensor) -> Tensor:  # (B, C, H, W) -> (B, C, H, W)
        x1, x2 = self.dwconv(self.project_in(x)).chunk(2, dim=1)
        return self.project_out(F.gelu(x1) * x2)


class TransformerBlock(nn.Module):
    """x + MDTA(LN(x)), then x + GDFN(LN(x))."""

    def __init__(self, dim: int, heads: int, ffn: float, bias: bool, norm: str):
        super().__init__()
        self.norm1 = ChannelLayerNorm(dim, norm)
        self.attn = MDTA(dim, heads, bias)
        self.norm2 = ChannelLayerNorm(dim, norm)
        self.ffn = GDFN(dim, ffn, bias)

    def forward(self, x: Tensor) -> Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.ffn(self.norm2(x))


class PatchEmbed(nn.Module):
    """Overlapped patch embedding: a 3x3 conv (bias-free, as in the official model)."""

    def __init__(self, in_ch: int, dim: int):
        super().__init__()
        self.proj = nn.Conv2d(in_ch, dim, 3, padding=1, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        return self.proj(x)


class Downsample(nn.Module):
    """(B, C, H, W) -> (B, 2C, H/2, W/2): 3x3 conv to C/2, then PixelUnshuffle(2)."""

    def __init__(self, ch: int):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(ch, ch // 2, 3, padding=1, bias=False), nn.PixelUnshuffle(2))

    def forward(self, x: Tensor) -> Tensor:
        return self.body(x)


class Upsample(nn.Module):
    """(B, C, H, W) -> (B, C/2, 2H, 2W): 3x3 conv to 2C, then PixelShuffle(2)."""

    def __init__(self, ch: int):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(ch, ch * 2, 3, padding=1, bias=False), nn.PixelShuffle(2))

    def forward(self, x: Tensor) -> Tensor:
        return self.body(x)


class Restormer(nn.Module):
    """The 4-level Restormer; ``forward`` returns input (or ``base``) + predicted residual (no clamping)."""

    def __init__(self, cfg: Config, in_ch: int = 3, out_ch: int = 3):
        super().__init__()
        d, nb, hd = cfg.dim, cfg.num_blocks, cfg.heads
        if d % 2 or len(nb) != 4 or len(hd) != 4:
            raise ValueError("Restormer needs an even dim and 4 entries in num_blocks and heads")

        def stage(width: int, heads: int, n: int) -> nn.Sequential:
            return nn.Sequential(
                *[
                    TransformerBlock(width, heads, cfg.ffn_expansion_factor, cfg.bias, cfg.layernorm_type)
                    for _ in range(n)
                ]
            )

        self.patch_embed = PatchEmbed(in_ch, d)
        self.encoder_level1 = stage(d, hd[0], nb[0])
        self.down1_2 = Downsample(d)
        self.encoder_level2 = stage(2 * d, hd[1], nb[1])
        self.down2_3 = Downsample(2 * d)
        self.encoder_level3 = stage(4 * d, hd[2], nb[2])
        self.down3_4 = Downsample(4 * d)
        self.latent = stage(8 * d, hd[3], nb[3])
        self.up4_3 = Upsample(8 * d)
        self.reduce_chan_level3 = nn.Conv2d(8 * d, 4 * d, 1, bias=cfg.bias)
        self.decoder_level3 = stage(4 * d, hd[2], nb[2])
        self.up3_2 = Upsample(4 * d)
        self.reduce_chan_level2 = nn.Conv2d(4 * d, 2 * d, 1, bias=cfg.bias)
        self.decoder_level2 = stage(2 * d, hd[1], nb[1])
        self.up2_1 = Upsample(2 * d)  # no channel reduction at level 1: it stays at 2d
        self.decoder_level1 = stage(2 * d, hd[0], nb[0])
        self.refinement = stage(2 * d, hd[0], cfg.num_refinement_blocks)
        self.output = nn.Conv2d(2 * d, out_ch, 3, padding=1, bias=cfg.bias)

    def forward(self, img: Tensor, base: Tensor | None = None) -> Tensor:  # (B, 3, H, W), H and W multiples of 8
        e1 = self.encoder_level1(self.patch_embed(img))  # (B, d, H, W)
        e2 = self.encoder_level2(self.down1_2(e1))  # (B, 2d, H/2, W/2)
        e3 = self.encoder_level3(self.down2_3(e2))  # (B, 4d, H/4, W/4)
        lat = self.latent(self.down3_4(e3))  # (B, 8d, H/8, W/8)
        d3 = self.decoder_level3(self.reduce_chan_level3(torch.cat([self.up4_3(lat), e3], 1)))
        d2 = self.decoder_level2(self.reduce_chan_level2(torch.cat([self.up3_2(d3), e2], 1)))
        d1 = self.decoder_level1(torch.cat([self.up2_1(d2), e1], 1))  # (B, 2d, H, W)
        return self.output(self.refinement(d1)) + (img if base is None else base)  # global residual


# ----------------------------------------------------------------------------------------------
# The stage-1 translator
# ----------------------------------------------------------------------------------------------


class Translator(TranslatorBase):
    """Restormer trained as a binary -> RGB denoiser with L1 (output = input + net(input))."""

    paired = True
    multiple = 8  # three 2x downsamplings

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # pixel loss only
        self.cfg = cfg
        self.device = torch.device(device)
        self.net = Restormer(cfg).to(self.device)
        self.make_prior(cfg.prior_sigma, self.net)
        self.opt = adam(
            self.net.parameters(),
            self.device,
            adamw=True,
            lr=cfg.lr,
            betas=tuple(cfg.betas),
            weight_decay=cfg.weight_decay,
        )

    def modules(self) -> dict[str, nn.Module]:
        return self.with_prior({"net": self.net})

    def run(self, binary: Tensor) -> Tensor:
        """The network on a padded binary image in [0, 1]: the residual over the prior when there is one."""
        if self.prior is None:
            return self.net(binary)
        return self.plus_prior(self.net(binary, torch.zeros_like(binary)), binary, signed=False)

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"net": self.opt}

    def load_pretrained(self, path) -> None:
        """Load an official Restormer ``.pth`` into the network (the Config must match its architecture)."""
        if self.prior is not None:
            raise ValueError(
                f"restormer: published weights ({path}) predict a residual over the input image, "
                "not over the physics prior; set stage1.restormer.prior_sigma: 0 to load them"
            )
        sd = _official_state_dict(Path(path))
        check_state_dict(self.net, sd, str(path))
        self.net.load_state_dict(sd, strict=True)

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One AdamW step on L1(net(binary), rgb); binary, rgb: (B, 3, h, w) in [0, 1]."""
        self.net.train()
        padded, (h, w) = pad_to_multiple(binary.to(self.device), self.multiple)  # crops need not divide by 8
        out = self.run(padded)[..., :h, :w]
        loss = F.l1_loss(out, rgb.to(self.device))
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.grad_clip > 0:
            nn.utils.clip_grad_norm_(self.net.parameters(), self.cfg.grad_clip)
        self.opt.step()
        return {"loss": float(loss.detach())}  # the L1 loss

    def forward_image(self, binary: Tensor) -> Tensor:
        """(B, 3, H', W') padded binary image -> (B, 3, H', W') in [0, 1]."""
        return self.run(binary.to(self.device)).clamp(0.0, 1.0)


# ----------------------------------------------------------------------------------------------
# Official checkpoints
# ----------------------------------------------------------------------------------------------


def _official_state_dict(path: Path) -> dict[str, Tensor]:
    """Read the state_dict of an official Restormer ``.pth`` ({"params": sd}; also "params_ema" or a bare sd)."""
    blob = io.load_torch(path, "Restormer checkpoint")
    if not isinstance(blob, dict):
        raise TypeError(f"{path}: expected a dict with key 'params', got {type(blob).__name__}")
    for key in ("params", "params_ema", "state_dict"):
        if key in blob and isinstance(blob[key], dict):
            return blob[key]
    if all(isinstance(v, Tensor) for v in blob.values()):
        return blob
    raise ValueError(f"{path}: no 'params' state_dict in checkpoint (keys: {sorted(blob)[:10]})")


def check_state_dict(module: nn.Module, sd: dict[str, Tensor], source: str) -> None:
    """Raise ValueError naming ``source`` and every missing, unexpected or mis-shaped key."""
    own = module.state_dict()
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    shapes = sorted(
        f"{k}: checkpoint {tuple(sd[k].shape)} vs model {tuple(own[k].shape)}"
        for k in set(own) & set(sd)
        if sd[k].shape != own[k].shape
    )
    if missing or unexpected or shapes:
        raise ValueError(
            f"{source}: checkpoint does not match Restormer with this Config "
            f"(dim, num_blocks, heads, bias, layernorm_type?); missing keys {missing}; "
            f"unexpected keys {unexpected}; shape mismatches {shapes}"
        )


def load_official_checkpoint(
    path: str | Path, cfg: Config | None = None, device: torch.device | str = "cpu"
) -> Translator:
    """A Translator whose network holds the weights of an official Restormer checkpoint.

    ``cfg`` must describe the checkpoint's architecture (default: ``Config(**PAPER)``, the
    published denoising model). The optimiser is fresh, so the result can be fine-tuned.
    """
    cfg = cfg if cfg is not None else replace(Config(), **PAPER)
    translator = Translator(cfg, torch.device(device))
    translator.load_pretrained(path)
    return translator

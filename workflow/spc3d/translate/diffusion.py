"""Diffusion (DiffBIR stand-in): a compact conditional DDPM restorer, sampled with DDIM.

NOT DiffBIR. DiffBIR (Lin et al. 2024) restores images with a stage-1 cleaner (SwinIR / BSRNet /
SCUNet) followed by Stable Diffusion 2.1 steered by an IRControlNet; those weights are not
reachable offline (they are hosted on model hubs only). This module keeps DiffBIR's *structure* at a size we can
train on our own (binary, RGB) pairs:

    stage-1 cleaner   the physics prior (:mod:`.prior`: a blurred-MLE image at a gain fitted on the
                      training scenes), whose residual the generator produces; with
                      ``prior_sigma: 0`` a 5x5 box blur of the binary image, and the whole image
    generator         a small pixel-space UNet (GroupNorm + SiLU residual blocks, sinusoidal
                      timestep embedding added in every block, self-attention in 16 x 16 tiles
                      at the lowest level) conditioned by concatenating [binary, cleaned] to
                      the noisy image

Training is DDPM (T steps, cosine schedule by default) on images in [-1, 1] with an MSE loss on
the **v-prediction** target v = sqrt(a) eps - sqrt(1 - a) x0 (a = alpha_bar_t). v is chosen over
epsilon because x0 = sqrt(a) x_t - sqrt(1 - a) v stays well conditioned at the noisiest steps,
where the epsilon parameterisation divides by sqrt(a) ~ 0 (cosine schedules reach a ~ 1e-8);
``prediction="eps"`` remains selectable. An EMA copy of the weights is used for sampling.

Sampling (inside ``forward_image``) is DDIM with ``sample_steps`` steps (eta = 0: deterministic)
from noise drawn with a ``torch.Generator`` seeded from ``sample_seed``, so the same binary image
always gives the same output. Predicted x0 is clamped to [-1, 1] at every step and epsilon is
re-derived from the clamped x0 (as guided-diffusion does). Schedules are computed in float64.
"""

from __future__ import annotations

import copy
import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.specs.translators.diffusion import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
from spc3d.translate.base import TranslatorBase, adam, from_signed, pad_to_multiple, to_signed
from spc3d.translate.ddim import NoiseSchedule, ddim_sample, make_betas

# ----------------------------------------------------------------------------------------------
# The UNet
# ----------------------------------------------------------------------------------------------


def timestep_embedding(t: Tensor, dim: int) -> Tensor:
    """(B,) timesteps -> (B, dim) sinusoidal features (Transformer positional encoding)."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs[None]
    return torch.cat([torch.cos(args), torch.sin(args)], dim=1)


def group_norm(ch: int, groups: int) -> nn.GroupNorm:
    return nn.GroupNorm(math.gcd(groups, ch), ch)


def zero_init(module: nn.Module) -> nn.Module:
    """Zero a layer so residual branches start as the identity (stabilises early training)."""
    for p in module.parameters():
        nn.init.zeros_(p)
    return module


class ResBlock(nn.Module):
    """GN-SiLU-conv, + projected timestep embedding, GN-SiLU-conv; skip 1x1 when widths differ."""

    def __init__(self, cin: int, cout: int, temb_dim: int, groups: int):
        super().__init__()
        self.norm1, self.conv1 = group_norm(cin, groups), nn.Conv2d(cin, cout, 3, padding=1)
        self.temb = nn.Linear(temb_dim, cout)
        self.norm2, self.conv2 = group_norm(cout, groups), zero_init(nn.Conv2d(cout, cout, 3, padding=1))
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: Tensor, temb: Tensor) -> Tensor:  # (B, cin, H, W), (B, temb) -> (B, cout, H, W)
        h = self.conv1(F.silu(self.norm1(x)))
        h = h + self.temb(F.silu(temb))[:, :, None, None]
        return self.skip(x) + self.conv2(F.silu(self.norm2(h)))


def window_attention(q: Tensor, k: Tensor, v: Tensor, window: int) -> Tensor:
    """Attention within non-overlapping window x window tiles; q, k, v, result: (B, C, H, W).

    Sides are zero-padded to a multiple of the window and padded keys are masked out (every tile
    holds at least one real position, since padding only extends the bottom/right tiles).
    """
    b, c, h, w = q.shape
    ph, pw = (-h) % window, (-w) % window
    nh, nw = (h + ph) // window, (w + pw) // window

    def tiles(x: Tensor) -> Tensor:  # (B, C', H, W) -> (B * nh * nw, window**2, C')
        x = F.pad(x, (0, pw, 0, ph)).reshape(x.shape[0], x.shape[1], nh, window, nw, window)
        return x.permute(0, 2, 4, 3, 5, 1).reshape(-1, window * window, x.shape[1])

    valid = tiles(torch.ones(1, 1, h, w, dtype=torch.bool, device=q.device))  # (nh*nw, L, 1)
    mask = valid.transpose(1, 2).repeat(b, 1, 1)  # (B*nh*nw, 1, L): which keys are real
    out = F.scaled_dot_product_attention(tiles(q), tiles(k), tiles(v), attn_mask=mask)  # (B*n, L, C)
    out = out.reshape(b, nh, nw, window, window, c).permute(0, 5, 1, 3, 2, 4)
    return out.reshape(b, c, h + ph, w + pw)[..., :h, :w]


class SelfAttention(nn.Module):
    """Single-head spatial self-attention, residual; global, or within tiles of ``window`` positions.

    Tiles keep the cost linear in the image size at inference and match what the network saw in
    training (a 64-px crop is one 16 x 16 tile at the lowest level of a 3-level UNet).
    """

    def __init__(self, ch: int, groups: int, window: int = 0):
        super().__init__()
        self.norm, self.qkv = group_norm(ch, groups), nn.Conv2d(ch, 3 * ch, 1)
        self.proj = zero_init(nn.Conv2d(ch, ch, 1))
        self.window = window

    def forward(self, x: Tensor) -> Tensor:  # (B, C, H, W)
        b, c, h, w = x.shape
        q, k, v = self.qkv(self.norm(x)).chunk(3, dim=1)  # (B, C, H, W) each
        if self.window and max(h, w) > self.window:
            out = window_attention(q, k, v, self.window)
        else:
            tokens = [t.reshape(b, c, h * w).transpose(1, 2) for t in (q, k, v)]  # (B, HW, C)
            out = F.scaled_dot_product_attention(*tokens).transpose(1, 2).reshape(b, c, h, w)
        return x + self.proj(out)


class UNet(nn.Module):
    """Conditional UNet: (B, 3 + cond, H, W), t (B,) -> (B, 3, H, W); H, W divisible by 2**(levels-1)."""

    def __init__(self, cfg: Config, in_ch: int, out_ch: int = 3):
        super().__init__()
        widths = [cfg.base_channels * m for m in cfg.channel_mults]
        tdim, g, n = 4 * cfg.base_channels, cfg.groups, cfg.num_res_blocks
        self.base = cfg.base_channels
        self.time_mlp = nn.Sequential(nn.Linear(cfg.base_channels, tdim), nn.SiLU(), nn.Linear(tdim, tdim))
        self.conv_in = nn.Conv2d(in_ch, widths[0], 3, padding=1)
        self.down, self.downsample = nn.ModuleList(), nn.ModuleList()
        prev = widths[0]
        for i, w in enumerate(widths):
            self.down.append(nn.ModuleList([ResBlock(prev if j == 0 else w, w, tdim, g) for j in range(n)]))
            if i < len(widths) - 1:
                self.downsample.append(nn.Conv2d(w, w, 3, stride=2, padding=1))
            prev = w
        self.mid1 = ResBlock(prev, prev, tdim, g)
        self.mid_attn = SelfAttention(prev, g, cfg.attn_window) if cfg.attention else nn.Identity()
        self.mid2 = ResBlock(prev, prev, tdim, g)
        self.up, self.upsample = nn.ModuleList(), nn.ModuleList()
        for i in reversed(range(len(widths))):  # stored deepest first
            w = widths[i]
            self.up.append(nn.ModuleList([ResBlock(prev + w if j == 0 else w, w, tdim, g) for j in range(n)]))
            if i > 0:
                self.upsample.append(nn.Conv2d(w, w, 3, padding=1))
            prev = w
        self.norm_out = group_norm(prev, g)
        self.conv_out = zero_init(nn.Conv2d(prev, out_ch, 3, padding=1))

    def forward(self, x: Tensor, t: Tensor) -> Tensor:
        temb = self.time_mlp(timestep_embedding(t, self.base))  # (B, 4 base)
        h, skips = self.conv_in(x), []
        for i, blocks in enumerate(self.down):
            for block in blocks:
                h = block(h, temb)
            skips.append(h)  # (B, w_i, H / 2**i, W / 2**i)
            if i < len(self.downsample):
                h = self.downsample[i](h)
        h = self.mid2(self.mid_attn(self.mid1(h, temb)), temb)
        for j, blocks in enumerate(self.up):
            h = torch.cat([h, skips.pop()], dim=1)
            for block in blocks:
                h = block(h, temb)
            if j < len(self.upsample):
                h = self.upsample[j](F.interpolate(h, scale_factor=2.0, mode="nearest"))
        return self.conv_out(F.silu(self.norm_out(h)))


class EMA(nn.Module):
    """Exponential moving average of a model's weights; ``num_updates`` is saved with the state."""

    def __init__(self, model: nn.Module, decay: float, warmup: bool):
        super().__init__()
        self.model = copy.deepcopy(model).requires_grad_(False)
        self.decay, self.warmup = decay, warmup
        self.register_buffer("num_updates", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        self.num_updates += 1
        n = int(self.num_updates)
        decay = min(self.decay, (1 + n) / (10 + n)) if self.warmup else self.decay
        for e, p in zip(self.model.parameters(), model.parameters()):
            e.lerp_(p.detach(), 1.0 - decay)
        for e, b in zip(self.model.buffers(), model.buffers()):
            e.copy_(b)


# ----------------------------------------------------------------------------------------------
# The stage-1 translator
# ----------------------------------------------------------------------------------------------


def box_blur(x: Tensor, k: int) -> Tensor:
    """(B, C, H, W) -> k x k mean filter with replicated borders (the cheap stage-1 cleaner)."""
    r = k // 2
    return F.avg_pool2d(F.pad(x, (r, r, r, r), mode="replicate"), k, stride=1)


class Translator(TranslatorBase):
    """Conditional diffusion restorer (DiffBIR stand-in): train with DDPM, translate with DDIM."""

    paired = True

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # diffusion loss only
        if cfg.prediction not in ("v", "eps"):
            raise ValueError(f"prediction must be 'v' or 'eps', got {cfg.prediction!r}")
        if not cfg.residual_scale > 0:
            raise ValueError(f"residual_scale must be > 0, got {cfg.residual_scale}")
        if cfg.clean_kernel < 1 or cfg.clean_kernel % 2 == 0:
            raise ValueError(f"clean_kernel must be odd and >= 1, got {cfg.clean_kernel}")
        self.cfg = cfg
        self.device = torch.device(device)
        self.multiple = 2 ** (len(cfg.channel_mults) - 1)
        self.schedule = NoiseSchedule(make_betas(cfg.beta_schedule, cfg.timesteps))
        cond_ch = 6 if cfg.cleaned_condition else 3
        self.net = UNet(cfg, in_ch=3 + cond_ch).to(self.device)
        self.make_prior(cfg.prior_sigma)
        self.ema = EMA(self.net, cfg.ema_decay, cfg.ema_warmup).to(self.device)
        self.opt = adam(self.net.parameters(), self.device, lr=cfg.lr, betas=tuple(cfg.adam_betas))

    def modules(self) -> dict[str, nn.Module]:
        return self.with_prior({"net": self.net, "ema": self.ema})

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"net": self.opt}

    def condition(self, binary: Tensor) -> Tensor:
        """(B, 3, H, W) in [0, 1] -> (B, 3 or 6, H, W) in [-1, 1]: binary [, cleaned: the prior, else box blur]."""
        parts = [to_signed(binary)]
        if self.cfg.cleaned_condition:
            cleaned = self.prior(binary) if self.prior is not None else box_blur(binary, self.cfg.clean_kernel)
            parts.append(to_signed(cleaned))
        return torch.cat(parts, dim=1)

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One DDPM step: random t, noised target, MSE on the v (or eps) target; then the EMA update."""
        self.net.train()
        binary, (h, w) = pad_to_multiple(binary.to(self.device), self.multiple)  # any crop size
        x0, _ = pad_to_multiple(to_signed(rgb.to(self.device)), self.multiple)
        if self.prior is not None:  # the residual over the prior, less its mean (TranslatorBase.plus_prior)
            x0 = x0 - to_signed(self.prior(binary))
            x0 = (x0 - x0.mean(dim=(-2, -1), keepdim=True)) * self.cfg.residual_scale
        t = torch.randint(0, self.cfg.timesteps, (x0.shape[0],), device=self.device)
        noise = torch.randn_like(x0)
        x_t = self.schedule.q_sample(x0, t, noise)
        out = self.net(torch.cat([x_t, self.condition(binary)], dim=1), t)
        target = self.schedule.target(x0, noise, t, self.cfg.prediction)
        loss = F.mse_loss(out[..., :h, :w], target[..., :h, :w])  # the loss ignores the padding
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.grad_clip > 0:
            nn.utils.clip_grad_norm_(self.net.parameters(), self.cfg.grad_clip)
        self.opt.step()
        self.ema.update(self.net)
        return {"loss": float(loss.detach())}  # the MSE on the v (or eps) target

    @torch.no_grad()
    def forward_image(self, binary: Tensor) -> Tensor:
        """(B, 3, H', W') padded binary image -> (B, 3, H', W') in [0, 1] by seeded DDIM sampling."""
        binary = binary.to(self.device)
        cond = self.condition(binary)
        net = self.ema.model if self.cfg.use_ema else self.net
        gen = torch.Generator(device=self.device).manual_seed(self.cfg.sample_seed)

        def predict(x: Tensor, t: Tensor) -> Tensor:
            return net(torch.cat([x, cond], dim=1), t)

        total = torch.zeros_like(binary)
        for _ in range(max(1, self.cfg.samples)):
            x_T = torch.randn(binary.shape, generator=gen, device=self.device, dtype=binary.dtype)
            x0 = ddim_sample(
                predict, x_T, self.schedule, self.cfg.sample_steps, self.cfg.prediction, eta=self.cfg.eta, generator=gen
            )
            if self.prior is not None:
                x0 = self.plus_prior(x0 / self.cfg.residual_scale, to_signed(binary), signed=True)
            total += from_signed(x0).clamp(0.0, 1.0)
        return total / max(1, self.cfg.samples)

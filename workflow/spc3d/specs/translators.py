"""The settings of stage 1, torch-free: every built-in translator's settings and published sizes,
and the settings of their training data, training and validation.

One frozen dataclass per model, ``<Model>Config``, with the CPU-budget defaults, and one dict
``<MODEL>_PAPER``, the sizes of the paper or of the method's reference implementation
(``preset: paper``). The model modules of :mod:`spc3d.translate` import them as their ``Config``
and ``PAPER``; they live here so that the workflow can build and check every job's settings when it
parses the configuration, without importing torch (:func:`model_config`, ``spc3d.config``).
Each field's comment gives its meaning and the paper's value; the modules' docstrings the design.

Then the blocks every translator shares (``augment``, ``stage1.data``, ``stage1.train``,
``stage1.validation``): the augmentation (:mod:`spc3d.inputs.augment`), the training loop
(:mod:`spc3d.translate.train`) and its validator (:mod:`spc3d.translate.validate`) run with them.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass

from spc3d import specs
from spc3d.specs.build import build_config


def model_config(method: str, settings: dict, frames: int | None = None):
    """The method's Config: ``preset: paper`` starts from the published sizes; other keys override.
    A Config with a ``frames`` field (a method that must know K: ``classical``) takes ``frames``, the
    job's stage1.frames (a sweep point's K), never its own settings block's: one K per run."""
    if method not in specs.TRANSLATORS:
        raise ValueError(f"unknown stage-1 method {method!r}; choose one of {sorted(specs.TRANSLATORS)}")
    config, paper = specs.settings_classes(method)
    settings = dict(settings)
    preset = settings.pop("preset", None)
    settings.pop("checkpoint", None)
    if preset not in (None, "paper"):
        raise ValueError(f"stage1.{method}.preset={preset!r}: use 'paper' or leave it out (CPU default)")
    has_frames = any(f.name == "frames" for f in dataclasses.fields(config))
    if has_frames and "frames" in settings:
        raise ValueError(
            f"stage1.{method}.frames: the frames per input are stage1.frames for every method; set K there"
        )
    if has_frames and frames is not None:
        settings["frames"] = frames
    base = (
        config(**{k: tuple(v) if isinstance(v, list) else v for k, v in paper.items()}) if preset == "paper" else None
    )
    return build_config(config, settings, f"stage1.{method}", base)


# --- pix2pixhd ---


@dataclass(frozen=True)
class Pix2PixHDConfig:
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
PIX2PIXHD_PAPER: dict = {
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


# --- pix2pix ---


@dataclass(frozen=True)
class Pix2PixConfig:
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
PIX2PIX_PAPER: dict = {
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


# --- cyclegan ---


@dataclass(frozen=True)
class CycleGANConfig:
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
CYCLEGAN_PAPER: dict = {
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


# --- restormer ---


@dataclass(frozen=True)
class RestormerConfig:
    dim: int = 16  # channels at level 1 (level k has dim * 2**(k-1)); paper 48
    num_blocks: tuple[int, int, int, int] = (1, 1, 1, 1)  # transformer blocks per level; paper 4,6,6,8
    num_refinement_blocks: int = 0  # blocks after decoder level 1 (0 keeps a CPU step ~0.2 s); paper 4
    heads: tuple[int, int, int, int] = (1, 1, 2, 2)  # MDTA heads per level; paper 1,2,4,8
    ffn_expansion_factor: float = 2.66  # GDFN hidden width = int(dim * factor); paper 2.66
    bias: bool = False  # biases in the block convs; paper False
    layernorm_type: str = "BiasFree"  # "BiasFree" (denoising) or "WithBias" (deraining etc.)
    lr: float = 3e-4  # AdamW learning rate; paper 3e-4 (cosine-annealed to 1e-6 by the loop)
    weight_decay: float = 1e-4  # AdamW weight decay; paper 1e-4
    betas: tuple[float, float] = (0.9, 0.999)  # AdamW betas; paper (0.9, 0.999)
    grad_clip: float = 0.01  # max global grad norm (official training: use_grad_clip, 0.01); 0 = off
    prior_sigma: float = 2.0  # > 0: the global residual is over the blurred-MLE prior of sigma px (prior.py),
    #                           not over the binary input; paper 0


# Published sizes (Restormer, Gaussian/real denoising configuration).
RESTORMER_PAPER: dict = {
    "dim": 48,
    "num_blocks": (4, 6, 6, 8),
    "num_refinement_blocks": 4,
    "heads": (1, 2, 4, 8),
    "ffn_expansion_factor": 2.66,
    "bias": False,
    "layernorm_type": "BiasFree",
    "prior_sigma": 0.0,
}


# --- diffusion ---


@dataclass(frozen=True)
class DiffusionConfig:
    base_channels: int = 32  # UNet width at full resolution
    channel_mults: tuple[int, ...] = (1, 1, 2)  # width multipliers per resolution level (one 2x down each)
    num_res_blocks: int = 1  # residual blocks per level (encoder and decoder)
    attention: bool = True  # self-attention in the middle (lowest resolution) of the UNet
    attn_window: int = 16  # that attention works in tiles of this many positions per side (0 = global)
    groups: int = 8  # GroupNorm groups (reduced to a divisor of the width when needed)
    cleaned_condition: bool = True  # also condition on a box-blurred binary image (DiffBIR's stage 1)
    clean_kernel: int = 5  # box size of that cleaner (odd)
    timesteps: int = 1000  # DDPM diffusion steps T
    beta_schedule: str = "cosine"  # "cosine" (Nichol & Dhariwal 2021) or "linear" (Ho et al. 2020)
    prediction: str = "v"  # network target: "v" (recommended, see module docstring) or "eps"
    lr: float = 2e-4  # Adam learning rate
    adam_betas: tuple[float, float] = (0.9, 0.999)  # Adam betas
    grad_clip: float = 1.0  # max global grad norm; 0 = off
    ema_decay: float = 0.999  # EMA decay of the sampling weights
    ema_warmup: bool = True  # effective decay min(decay, (1+n)/(10+n)) so early EMA is not stale
    use_ema: bool = True  # sample with the EMA weights (else the raw ones)
    sample_steps: int = 10  # DDIM steps at inference. Fewer steps drift from a sampler towards a regression to
    #                         the mean: on the training scenes' held-out views (4-flip ensemble, stage1.ensemble)
    #                         of 20 / 10 / 5 / 2 / 1 steps, fewer never scored lower PSNR, so PSNR alone would
    #                         pick one step; 10 keeps a sampler at half the cost of 20
    eta: float = 0.0  # DDIM stochasticity (0 = deterministic ODE sampler)
    sample_seed: int = 0  # seed of the generator that draws x_T (and eta > 0 noise)
    samples: int = 1  # outputs averaged per image, each from its own x_T: > 1 moves one posterior sample towards
    #                   the posterior mean (lower squared error, less detail), a deviation; DiffBIR 1
    prior_sigma: float = 2.0  # > 0: the cleaner is the blurred-MLE prior of sigma px (prior.py), not the box blur,
    #                           and the model generates the residual over it; 0: box blur, whole image
    residual_scale: float = 6.0  # the residual is generated multiplied by this: its spread (~0.15 in [-1, 1]) then
    #                              meets the unit scale the noise schedule assumes (as latent diffusion scales
    #                              its latents); 6 is the best of 1 / 3 / 6 on the training scenes' held-out
    #                              views (val PSNR 15.86 / 17.32 / 17.72 after 300 steps on the default data)


# DiffBIR publishes no sizes for a pixel-space model: only sample_steps (50) and T (1000) come from
# it; the widths are a GPU-sized version of this UNet, not Stable Diffusion's 865M-parameter UNet.
DIFFUSION_PAPER: dict = {
    "timesteps": 1000,
    "sample_steps": 50,
    "base_channels": 128,
    "channel_mults": (1, 2, 2, 4),
    "num_res_blocks": 2,
    "ema_decay": 0.9999,
    "prior_sigma": 0.0,
}


# --- blurred_mle ---


@dataclass(frozen=True)
class PriorConfig:
    prior_sigma: float = 2.0  # blur of the prior in pixels (the translators' default; must be > 0)


PRIOR_PAPER: dict = {}  # the paper has no such method: its preset is the default


# --- classical ---

# The candidates: (family, params); NLM's h, TV's weight are in units of the VST's noise σ.
CLASSICAL_GRID: tuple[tuple[str, dict], ...] = (
    *(("gaussian", {"sigma": s}) for s in (1.0, 1.5, 2.0, 2.5, 3.0)),
    ("nlm", {"patch_size": 3, "patch_distance": 3, "h": 1.0, "subtract": True}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 1.0, "subtract": True}),
    ("nlm", {"patch_size": 3, "patch_distance": 3, "h": 1.0, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 0.8, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 1.2, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 6, "h": 1.0, "subtract": False}),
    ("wavelet", {"wavelet": "db2", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "sym4", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "db1", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "db2", "method": "VisuShrink", "levels": 4}),
    *(("tv", {"weight": w}) for w in (0.5, 0.75, 1.0, 1.5)),
    ("bm3d", {"stage": "all"}),
    ("bm3d", {"stage": "hard"}),
)
CLASSICAL_GRID_DIGEST = zlib.crc32(repr(CLASSICAL_GRID).encode())  # saved with a model: its choice indexes this grid


def classical_label(index: int) -> str:
    """``CLASSICAL_GRID[index]`` as text, e.g. ``tv(weight=0.75)``."""
    name, params = CLASSICAL_GRID[index]
    return f"{name}({', '.join(f'{k}={v}' for k, v in params.items())})"


CLASSICAL_FAMILIES = tuple(dict.fromkeys(name for name, _ in CLASSICAL_GRID))  # in the grid's order


def classical_pinned_index(choice: str, params: dict | None) -> int:
    """The CLASSICAL_GRID index of family ``choice`` at ``params`` (None: the family's only candidate)."""
    found = [i for i, (n, p) in enumerate(CLASSICAL_GRID) if n == choice and (params is None or p == dict(params))]
    if len(found) != 1:
        options = [classical_label(i) for i, (n, _) in enumerate(CLASSICAL_GRID) if n == choice]
        raise ValueError(f"choice = {choice!r}, params = {params}: not one candidate of the grid; pin one of {options}")
    return found[0]


@dataclass(frozen=True)
class ClassicalConfig:
    denoisers: tuple[str, ...] = ("gaussian", "nlm", "wavelet", "tv", "bm3d")  # families searched (if installed)
    choice: str | None = None  # pin one family (skips the search), at `params`; None: search
    params: dict | None = None  # the pinned candidate's GRID params, e.g. {sigma: 2.0} (None: its only one)
    calibration_every: int = 4  # the search fits each candidate's gain on every n-th training pair
    frames: int = 1  # K frames per input: set by the training job from stage1.frames, not here

    def __post_init__(self):
        unknown = [n for n in (*self.denoisers, self.choice) if n is not None and n not in CLASSICAL_FAMILIES]
        if unknown or not self.denoisers:
            raise ValueError(
                f"denoisers = {list(self.denoisers)}, choice = {self.choice!r}: unknown denoiser {unknown} "
                f"(or none listed); choose from {list(CLASSICAL_FAMILIES)}"
            )
        if self.frames < 1 or self.calibration_every < 1:
            raise ValueError(f"frames = {self.frames}, calibration_every = {self.calibration_every}: must be >= 1")
        if self.choice is not None:
            classical_pinned_index(self.choice, self.params)


CLASSICAL_PAPER: dict = {}  # the paper has no such method: its preset is the default


# --- training data, training and validation (every translator) ------------------------------------


@dataclass(frozen=True)
class TrainSettings:
    """How long and on what a stage-1 model trains (the config's ``stage1.train``)."""

    iterations: int = 400  # optimisation steps (paper: 100 + 100 epochs over ~15k pairs)
    batch_size: int = 4  # pairs per step (pix2pix/pix2pixHD: 1)
    crop: int = 64  # random square crop side in pixels (pix2pix: 256 from 286)
    decay_from: float = 0.5  # fraction of the iterations after which lr decays linearly to 0
    log_every: int = 10  # iterations between curve points

    def __post_init__(self):
        if self.iterations < 0 or self.batch_size < 1 or self.crop < 8 or self.log_every < 1:
            raise ValueError(
                f"stage1.train: need iterations >= 0, batch_size >= 1, crop >= 8, log_every >= 1; got {self}"
            )
        if not 0.0 <= self.decay_from <= 1.0:
            raise ValueError(f"stage1.train.decay_from={self.decay_from}: must be in [0, 1]")


def train_settings(train: dict, method: str, pretrained: str | None = None) -> TrainSettings:
    """``stage1.train`` (with the method's own ``train`` block) as TrainSettings; 0 iterations only
    when the method starts from published weights (an untrained network is not a result)."""
    s = build_config(TrainSettings, train, f"stage1.{method}.train")
    if s.iterations == 0 and not pretrained:
        raise ValueError(
            f"stage1.train.iterations = 0 for {method}: an untrained network is not a result; use "
            f"iterations >= 1 (0 only with published weights, stage1.{method}.checkpoint)"
        )
    return s


DATA_MODES = ("fixed", "online")


def data_mode(mode: str) -> str:
    """``stage1.data``, checked."""
    if mode not in DATA_MODES:
        raise ValueError(
            f"stage1.data = {mode!r}: use one of {list(DATA_MODES)} (fixed: the augmented pairs of "
            f"results/augment; online: fresh augmentations and SPC photons every step)"
        )
    return mode


@dataclass(frozen=True)
class ValidationSettings:
    """When a translator is validated and when it stops (the config's ``stage1.validation``)."""

    # every and patience: config.yaml's stage1.validation (their home; tests/test_defaults.py checks they agree)
    every: int = 50  # steps between validations, plus one at the last step (0: none, the last model is kept)
    patience: int = 4  # validations without a better PSNR before training stops (0: never stop early)
    hold_out: int = 0  # the last N training scenes: not trained on, every view validated (0: held-out views)

    def __post_init__(self):
        if min(self.every, self.patience, self.hold_out) < 0:
            raise ValueError(
                f"need every, patience and hold_out >= 0, got every = {self.every}, patience = {self.patience}, "
                f"hold_out = {self.hold_out}"
            )


def validation_settings(values: dict | None, where: str = "stage1.validation") -> ValidationSettings:
    """``stage1.validation`` (with a method's own block) as ValidationSettings; None: no validation."""
    if values is None:
        return ValidationSettings(every=0)
    return build_config(ValidationSettings, dict(values), where)


@dataclass(frozen=True)
class AugmentSettings:
    """Ranges of the random affine maps."""

    zoom: tuple[float, float] = (0.8, 1.25)  # zoom factor range, sampled log-uniformly
    rotation_deg: float = 15.0  # max |rotation|
    shear_deg: float = 10.0  # max |shear|
    flip_prob: float = 0.5  # probability of a horizontal flip

    def __post_init__(self):
        lo, hi = self.zoom
        if not 0 < lo <= hi:
            raise ValueError(f"augment.zoom={list(self.zoom)}: need 0 < min <= max")
        if not 0 <= self.flip_prob <= 1:
            raise ValueError(f"augment.flip_prob={self.flip_prob}: must be in [0, 1]")
        if self.rotation_deg < 0 or self.shear_deg < 0:
            raise ValueError("augment.rotation_deg and augment.shear_deg must be >= 0")


def split_count(total: int, n_scenes: int, index: int) -> int:
    """Samples for scene ``index`` of ``n_scenes`` when ``total`` are split as evenly as possible."""
    return total // n_scenes + (1 if index < total % n_scenes else 0)

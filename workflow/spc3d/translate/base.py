"""The interface every stage-1 model implements, and the helpers they share.

A stage-1 model ("translator") maps a 3-channel binary SPC image (K = 1: the bits of frame 0;
K > 1: the average of K frames) to an sRGB image of the same size. Each model file defines

    Config       a frozen @dataclass of the model's settings (widths, depths, losses, lr),
                 one comment per field; the defaults fit the CPU budget, ``PAPER`` (a dict of
                 overrides) holds the published sizes.
    Translator   class Translator(TranslatorBase) with

        __init__(cfg: Config, device: torch.device, vgg_weights: dict | None = None)
        paired: bool                  False for methods trained unpaired (CycleGAN)
        multiple: int                 input sides are padded (reflect) to a multiple of this
        train_step(binary, rgb) -> dict[str, float]
                                      one optimisation step on a batch; binary, rgb: (B, 3, h, w)
                                      float32 in [0, 1]; returns named losses (at least "loss")
        forward_image(binary) -> Tensor
                                      (B, 3, H', W') padded input in [0, 1] -> output in [0, 1]
                                      (the network alone; called under torch.no_grad in eval mode)
        modules() -> dict[str, nn.Module]     every network (generators, discriminators)
        optimizers() -> dict[str, Optimizer]  every optimiser (for checkpoints)
        set_lr_scale(scale: float)    multiply every optimiser's base lr by scale (linear decay)
        device: torch.device          where the networks live (set in __init__)
        load_pretrained(path)         optional: published weights given by path (Restormer)
        prior: PhysicsPrior | None    the physics prior its output is a residual over (``prior_sigma``
                                      > 0 in its Config; :mod:`.prior`), else None
        trainable: bool               False for a method without a network (``prior``, ``classical``):
                                      training is its fit_untrained alone and takes no step
        fit_untrained(pairs, validate) -> dict | None
                                      what is fitted before any step (an untrained method's whole
                                      training): by default the prior's gain; ``classical`` selects
                                      its denoiser there. Returns a record for train.json or None

``TranslatorBase`` supplies ``translate`` (pad, run, crop back, clamp), ``state`` / ``load`` for
checkpoints, ``parameter_count``, and the physics prior (``make_prior`` builds it, ``with_prior``
lists it among the modules so its fitted gain is saved, ``plus_prior`` adds it to an output).
Models keep their outputs in [0, 1] at the interface even when their networks work in [-1, 1]
(pix2pix convention) internally.
"""

from __future__ import annotations

import abc
import copy
from collections.abc import Callable, Iterable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.translate.prior import PhysicsPrior


def pad_to_multiple(x: Tensor, multiple: int) -> tuple[Tensor, tuple[int, int]]:
    """Reflect-pad (B, C, H, W) so H and W are multiples of ``multiple``; returns (padded, (H, W))."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph == 0 and pw == 0:
        return x, (h, w)
    mode = "reflect" if ph < h and pw < w else "replicate"  # reflect needs pad < size
    return F.pad(x, (0, pw, 0, ph), mode=mode), (h, w)


def adam(params, device: torch.device, adamw: bool = False, **options) -> torch.optim.Optimizer:
    """Adam (AdamW with ``adamw``) over ``params`` with ``options`` (lr, betas, weight_decay), using
    the fused kernel where this torch has one for ``device`` (CPU since torch 2.4, CUDA): one pass
    over each tensor instead of about eight, so the optimiser step takes a fraction of the time.
    Same update within float rounding."""
    kind = torch.device(device).type
    version = tuple(int(v) for v in torch.__version__.split("+")[0].split(".")[:2] if v.isdigit())
    if kind == "cuda" or (kind == "cpu" and version >= (2, 4)):
        options["fused"] = True
    return (torch.optim.AdamW if adamw else torch.optim.Adam)(params, **options)


def to_signed(x: Tensor) -> Tensor:
    """[0, 1] -> [-1, 1]."""
    return x * 2.0 - 1.0


def from_signed(x: Tensor) -> Tensor:
    """[-1, 1] -> [0, 1]."""
    return (x + 1.0) * 0.5


def zero_last_conv(net: nn.Module) -> None:
    """Zero the weights and bias of the last convolution registered in ``net`` (its output layer):
    a residual network then starts as the identity of what it is added to."""
    convs = [m for m in net.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
    if not convs:
        raise ValueError(f"{type(net).__name__} has no convolution to zero")
    nn.init.zeros_(convs[-1].weight)
    if convs[-1].bias is not None:
        nn.init.zeros_(convs[-1].bias)


class TranslatorBase(abc.ABC):
    """Shared behaviour of the stage-1 models (see the module docstring for the contract)."""

    paired: bool = True
    multiple: int = 16
    trainable: bool = True  # False: nothing to optimise (the prior alone): training fits the prior's gain only
    device: torch.device = torch.device("cpu")
    prior: PhysicsPrior | None = None

    def make_prior(self, sigma: float, head: nn.Module | None = None) -> None:
        """The physics prior of ``sigma`` pixels (none for 0); its gain is fitted before training.
        ``head``: the network whose last convolution is zeroed, so training starts at the prior."""
        self.prior = PhysicsPrior(sigma).to(self.device) if sigma > 0 else None
        if self.prior is not None and head is not None:
            zero_last_conv(head)

    def with_prior(self, modules: dict[str, nn.Module]) -> dict[str, nn.Module]:
        """``modules`` plus the prior (when there is one): saved, loaded and copied with the networks."""
        return modules if self.prior is None else {**modules, "prior": self.prior}

    def plus_prior(self, out: Tensor, binary: Tensor, signed: bool) -> Tensor:
        """A network output made a residual over the prior of its input: prior(``binary``) + ``out``
        less its mean per image and channel, both in [-1, 1] (``signed``, ``binary`` too) or in [0, 1];
        ``out`` alone without a prior. The mean is removed because the frames carry no absolute
        brightness (every scene is exposed to the same mean detection rate): the prior's gain, fitted
        on the training scenes, sets the level and colour balance, the network adds structure."""
        if self.prior is None:
            return out
        residual = out - out.mean(dim=(-2, -1), keepdim=True)
        if signed:
            return residual + to_signed(self.prior(from_signed(binary)))
        return residual + self.prior(binary)

    def fit_untrained(
        self, pairs: Callable[[], Iterable[tuple[Tensor, Tensor]]], validate: Callable[[Callable], dict] | None
    ) -> dict | None:
        """What is fitted before any optimisation step, on the training data alone (all the training of
        a method that is not ``trainable``): by default the physics prior's gain, when there is a prior.
        ``pairs()`` gives a fresh iterable of the training (binary, sRGB) pairs on every call;
        ``validate(translate)`` scores a (B, 3, H, W) -> (B, 3, H, W) function on the training scenes'
        held-out views ({"val_psnr", "val_l1"}; None without validation). Returns a record for
        train.json (``selection``), or None."""
        del validate  # the prior's gain needs no validation
        if self.prior is not None:
            self.prior.fit(pairs())
        return None

    @abc.abstractmethod
    def modules(self) -> dict[str, nn.Module]:
        """Every network of the model by name (generators, discriminators)."""

    @abc.abstractmethod
    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """Every optimiser by name (saved in checkpoints)."""

    @abc.abstractmethod
    def forward_image(self, binary: Tensor) -> Tensor:
        """(B, 3, H', W') padded binary image in [0, 1] -> (B, 3, H', W') sRGB in [0, 1]."""

    @abc.abstractmethod
    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        """One optimisation step on a batch; returns named losses (at least "loss")."""

    def set_lr_scale(self, scale: float) -> None:
        for opt in self.optimizers().values():
            for group in opt.param_groups:
                group.setdefault("base_lr", group["lr"])
                group["lr"] = group["base_lr"] * scale

    def train(self, mode: bool = True) -> None:
        for m in self.modules().values():
            m.train(mode)

    @torch.no_grad()
    def translate(self, binary: Tensor) -> Tensor:
        """(B, 3, H, W) binary image in [0, 1] -> (B, 3, H, W) sRGB in [0, 1] at any H, W."""
        if binary.ndim != 4 or binary.shape[1] != 3:
            raise ValueError(f"translate expects (B, 3, H, W), got {tuple(binary.shape)}")
        was_training = [m.training for m in self.modules().values()]
        self.train(False)
        try:
            padded, (h, w) = pad_to_multiple(binary, self.multiple)
            out = self.forward_image(padded)[..., :h, :w]
        finally:
            for m, flag in zip(self.modules().values(), was_training):
                m.train(flag)
        return out.clamp(0.0, 1.0)

    def parameter_count(self) -> dict[str, int]:
        return {name: sum(p.numel() for p in m.parameters()) for name, m in self.modules().items()}

    def state(self) -> dict:
        return {
            "modules": {k: m.state_dict() for k, m in self.modules().items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers().items()},
        }

    def load(self, state: dict) -> None:
        for k, m in self.modules().items():
            m.load_state_dict(state["modules"][k])
        for k, o in self.optimizers().items():
            # deep copy: Optimizer.load_state_dict keeps tensors that already match (shared state)
            o.load_state_dict(copy.deepcopy(state["optimizers"][k]))


class PairedGANBase(TranslatorBase):
    """A generator ``G`` and a discriminator ``D`` with Adam optimisers ``opt_G`` / ``opt_D`` and
    networks in [-1, 1] (pix2pix, pix2pixHD): modules, optimisers and inference in one place."""

    def modules(self) -> dict[str, nn.Module]:
        return self.with_prior({"G": self.G, "D": self.D})

    def generate(self, x: Tensor) -> Tensor:
        """G on a signed image (B, 3, h, w) in [-1, 1], as a residual over the prior when there is one."""
        return self.plus_prior(self.G(x), x, signed=True)

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"G": self.opt_G, "D": self.opt_D}

    def forward_image(self, binary: Tensor) -> Tensor:
        """(B, 3, H', W') padded binary in [0, 1] -> (B, 3, H', W') sRGB in [0, 1]."""
        return from_signed(self.generate(to_signed(binary.to(self.device))))

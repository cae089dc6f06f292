"""What a reconstructor is fitted to: sRGB images, or raw binary frames through the SPAD likelihood.

``RGBObjective`` — the model renders sRGB and is compared with target images (ground truth, a
stage-1 translation, the MLE image, or the raw binary frame as a 0/1 image for the paper's
single-stage baselines). 3DGS uses 0.8·L1 + 0.2·(1 − SSIM) as Kerbl et al.; NeRF uses MSE.

``BernoulliObjective`` — beyond the paper (as PhotonSplat / Quanta Radiance Fields): the model
renders *linear* intensity ℓ ≥ 0, the SPAD sees flux φ = flux_scale·ℓ, a pixel fires with
p = 1 − exp(−(qφ + dcr)T), and the loss is the binary cross-entropy of the observed bits. With K
frames only the fraction f = S/K of ones matters: NLL = −[f·log p + (1 − f)·log(1 − p)], where
log(1 − p) = −λT exactly and log p = log(−expm1(−λT)) (stable for tiny λT; λT is clamped at
1e-12 from below because log p → −∞ as λT → 0, and the gradient with it). The rendered linear
intensity is shown as sRGB for evaluation.

``JointObjective`` — the paper's future work, one fit for both stages: the SPAD likelihood of the
bits plus ``w(t)`` times a prior term that pulls the render (shown as sRGB) towards a stage-1
method's output for that view, with the two-stage row's own image loss (3DGS: 0.8 L1 + 0.2 D-SSIM,
L1 being the robust part; NeRF: MSE, or L1 with ``penalty: l1``). ``w`` decays linearly from
``weight`` to ``weight_final`` over the first ``decay_until`` of the run: the translation sets shape
and colour early, the photons decide detail late. Its target is the likelihood's target with the
stage-1 image appended as the last three channels. With ``w = 0`` it is the likelihood row's
objective, with ``likelihood: false`` the two-stage row's (on the sRGB of the render).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import torch
from torch import Tensor

from spc3d.pixels import linear_to_srgb
from spc3d.specs.reconstructors import JointConfig

LN2 = 0.6931471805599453


@dataclass(frozen=True)
class RGBObjective:
    """Image loss on sRGB renders. ``ssim_weight`` 0.2 is 3DGS's λ; 0 gives plain L1/MSE."""

    kind: str = "l1"  # "l1" (3DGS) or "mse" (NeRF)
    ssim_weight: float = 0.0
    name: str = "rgb"
    stops_on_plateau = True  # its floor is 0: a relative gain of the loss measures the fit

    def __post_init__(self):
        if self.kind not in ("l1", "mse"):  # any other kind would be fitted as MSE without a word
            raise ValueError(f"RGBObjective kind {self.kind!r}: use 'l1' or 'mse'")

    def loss(self, pred: Tensor, target: Tensor) -> Tensor:
        """pred, target: (..., H, W, 3) for SSIM, any (..., 3) without it."""
        err = (pred - target).abs().mean() if self.kind == "l1" else (pred - target).square().mean()
        if self.ssim_weight == 0.0:
            return err
        from spc3d.evaluation.metrics import ssim_loss_fast  # ssim_loss's value and gradient, faster

        return (1.0 - self.ssim_weight) * err + self.ssim_weight * ssim_loss_fast(_bchw(pred), _bchw(target))

    def to_srgb(self, pred: Tensor) -> Tensor:
        return pred.clamp(0.0, 1.0)


@dataclass(frozen=True)
class BernoulliObjective:
    """SPAD likelihood of the binary frames; target = fraction of ones over the K frames."""

    flux_scale: float
    q: float
    exposure_s: float
    dark_count_rate: float
    name: str = "bernoulli"
    # The NLL's floor is the entropy of the unknown firing probabilities (at K = 1 the observed
    # fractions are 0 or 1 and tell nothing of it): most of the loss is photon noise no model
    # explains, so a relative gain of it says nothing about the fit, and a 1 % rule stopped
    # bernoulli+3dgs early, at a loss of PSNR, on the training scenes (benchmarks/plateau_rule.py).
    # Its fits train to their budget.
    stops_on_plateau = False

    def lam_t(self, linear: Tensor) -> Tensor:
        """Expected detections λT per frame for a rendered linear intensity (clamped >= 0)."""
        rate = self.q * self.flux_scale * linear.clamp_min(0.0) + self.dark_count_rate
        return (rate * self.exposure_s).clamp_min(1e-12)  # log p -> -inf as λT -> 0 (see module doc)

    def loss(self, pred: Tensor, target: Tensor) -> Tensor:
        x = self.lam_t(pred)
        # Each branch gets only the inputs where it is accurate, so the branch torch.where discards
        # stays finite too (an inf there would turn its zero gradient into NaN).
        small, large = x.clamp(max=LN2), x.clamp(min=LN2)
        log_p = torch.where(x < LN2, torch.log(-torch.expm1(-small)), torch.log1p(-torch.exp(-large)))
        return -(target * log_p - (1.0 - target) * x).mean()

    def to_srgb(self, pred: Tensor) -> Tensor:
        return linear_to_srgb(pred)


@runtime_checkable
class Scheduled(Protocol):
    """An objective that changes over the run: a trainer calls ``at(step / iterations)`` before each step."""

    def at(self, t: float) -> None: ...


@dataclass
class JointObjective:
    """SPAD likelihood + w(t) x image loss towards a stage-1 output; target (..., C + 3): the
    likelihood's C channels, then the stage-1 image (sRGB). ``image``: the two-stage loss (None
    until the model sets its own, :func:`own_objective`). A trainer calls
    :meth:`at` with its progress before each step (the schedule)."""

    likelihood: object  # BernoulliObjective or a capture's MosaicBernoulliObjective
    cfg: JointConfig = JointConfig()
    image: RGBObjective | None = None
    weight: float = field(init=False)
    name: str = "joint"
    stops_on_plateau = False  # the likelihood's floor is photon noise (see BernoulliObjective)

    def __post_init__(self):
        self.weight = self.cfg.weight_at(0.0)
        if self.cfg.penalty == "l1":
            self.image = RGBObjective("l1")

    def at(self, t: float) -> None:
        """Set the prior term's weight for the fraction ``t`` of the run done."""
        self.weight = self.cfg.weight_at(t)

    def loss(self, pred: Tensor, target: Tensor) -> Tensor:
        split = target.shape[-1] - 3
        prior = self.image.loss(linear_to_srgb(pred), target[..., split:])
        if not self.cfg.likelihood:
            return prior
        return self.likelihood.loss(pred, target[..., :split]) + self.weight * prior

    def to_srgb(self, pred: Tensor) -> Tensor:
        return linear_to_srgb(pred)


def _bchw(x: Tensor) -> Tensor:
    return (x if x.dim() == 4 else x[None]).permute(0, 3, 1, 2)


def own_objective(objective, own: RGBObjective):
    """The objective a model fits: its own RGB loss ``own`` when none is given; a joint objective
    without an image loss gets ``own`` as its prior term."""
    if objective is None:
        return own
    if isinstance(objective, JointObjective) and objective.image is None:
        objective.image = own
    return objective

"""The physics prior alone as a stage-1 method (``prior``): the translators' untrained start.

Every default translator predicts a residual over :class:`.prior.PhysicsPrior` (the MLE image of
the Gaussian-blurred frame at a gain fitted on the training scenes). This method is that prior
with no network: nothing is learnt but the gain (fitted on the same training data, the same way,
before "training" reads its validation score). As a stage-2 source (``prior+3dgs``,
``prior+nerf``) it shows what a translator's learning adds over its own starting point: a
translator that does not beat it in the tables has learnt nothing the physics did not give.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from spc3d.specs.translators.prior import (
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
)
from spc3d.translate.base import TranslatorBase


class Translator(TranslatorBase):
    """The blurred-MLE image of the input: :class:`.prior.PhysicsPrior` with its fitted gain."""

    paired = True
    multiple = 1
    trainable = False  # the training loop only fits the prior's gain (spc3d.translate.train)

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # nothing is trained, no perceptual loss
        if not cfg.prior_sigma > 0:
            raise ValueError(f"stage1.prior.prior_sigma = {cfg.prior_sigma}: the physics prior needs a blur > 0 pixels")
        self.cfg, self.device = cfg, torch.device(device)
        self.make_prior(cfg.prior_sigma)

    def modules(self) -> dict[str, nn.Module]:
        return {"prior": self.prior}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {}

    def forward_image(self, binary: Tensor) -> Tensor:
        return self.prior(binary.to(self.device))

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        raise RuntimeError("the physics prior has no network to train: its training is the gain fit alone")

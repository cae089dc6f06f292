"""The perceptual loss of pix2pixHD: a frozen VGG16 (built from the LPIPS weights) and its L1 feature loss.

VGGFeatures   relu1_1 ... relu5_1 of VGG16 on images in [-1, 1] (plain convs, weights as buffers)
VGGLoss       sum_k w_k * L1 of those features, w = (1/32, 1/16, 1/8, 1/4, 1) as pix2pixHD
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spc3d.evaluation import lpips_specs

VGG16_STAGES = ((64, 2), (128, 2), (256, 3), (512, 3), (512, 3))  # (width, convs) per stage
VGG_LOSS_WEIGHTS = (1.0 / 32, 1.0 / 16, 1.0 / 8, 1.0 / 4, 1.0)


class VGGFeatures(nn.Module):
    """Frozen VGG16 returning relu1_1, relu2_1, relu3_1, relu4_1, relu5_1 (the first conv of each
    stage); written with plain convs, weights from ``spc3d.evaluation.lpips_weights.lpips_weights("vgg")``.

    pix2pixHD uses VGG19 at these taps. VGG19 weights are not available offline here, so VGG16
    (the LPIPS backbone: same five stages and widths, but 3 instead of 4 convs in stages 3-5)
    stands in for it; the features, hence the loss values, differ from the reference. Only
    conv0..conv10 are needed. Inputs in [-1, 1]
    go through LPIPS's ScalingLayer ((x - shift) / scale), which approximates ImageNet
    normalisation. The weights are non-persistent buffers: they stay out of checkpoints.
    """

    TAP_CONVS = (0, 2, 4, 7, 10)  # index of the conv whose ReLU is each tap

    def __init__(self, weights: Mapping[str, np.ndarray | Tensor]):
        super().__init__()
        expected = lpips_specs.expected_shapes("vgg")
        for i in range(self.TAP_CONVS[-1] + 1):
            for part in ("weight", "bias"):
                key = f"conv{i}.{part}"
                if key not in weights:
                    raise ValueError(
                        f"VGG weights: key {key!r} missing; expected the layout of "
                        f"spc3d.evaluation.lpips_weights.lpips_weights('vgg')"
                    )
                value = torch.as_tensor(np.asarray(weights[key], dtype=np.float32))
                if tuple(value.shape) != expected[key]:
                    raise ValueError(f"VGG weights: {key} has shape {tuple(value.shape)}, expected {expected[key]}")
                self.register_buffer(f"conv{i}_{part}", value.clone(), persistent=False)
        self.register_buffer("shift", torch.tensor(lpips_specs.SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(lpips_specs.SCALE).view(1, 3, 1, 1), persistent=False)
        self.eval()

    def _conv(self, x: Tensor, i: int) -> Tensor:
        return F.relu(F.conv2d(x, getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"), padding=1))

    def forward(self, x: Tensor) -> list[Tensor]:
        """(B, 3, H, W) in [-1, 1] (H, W >= 16) -> five taps (B, 64|128|256|512|512, H/2^k, W/2^k)."""
        x = (x - self.shift) / self.scale
        taps, conv_i = [], 0
        for stage, (_, n_conv) in enumerate(VGG16_STAGES):
            if stage:
                x = F.max_pool2d(x, 2, 2)
            x = self._conv(x, conv_i)
            taps.append(x)
            if stage == len(VGG16_STAGES) - 1:
                break
            for j in range(1, n_conv):
                x = self._conv(x, conv_i + j)
            conv_i += n_conv
        return taps


class VGGLoss(nn.Module):
    """sum_k w_k * L1(phi_k(x), phi_k(y)) with w = (1/32, 1/16, 1/8, 1/4, 1) as pix2pixHD; the
    target's features are computed without gradient."""

    def __init__(self, weights: Mapping[str, np.ndarray | Tensor]):
        super().__init__()
        self.vgg = VGGFeatures(weights)

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        with torch.no_grad():
            fy = self.vgg(y)
        fx = self.vgg(x)
        return sum(w * F.l1_loss(a, b.detach()) for w, a, b in zip(VGG_LOSS_WEIGHTS, fx, fy))

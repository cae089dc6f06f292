"""LPIPS v0.1 networks (AlexNet, VGG16 backbones + linear heads), written with plain torch.

Import layout, acyclic: ``lpips_specs`` (architecture: names, layer specs, ScalingLayer constants,
weight shapes) <- ``lpips_weights`` (obtaining and checking the weights) <- ``scores`` (the
numpy LPIPS that scoring uses, and the per-process network cache) <- this module (the
differentiable torch network); none of them imports this module.

Networks
--------
``LPIPSNet(net, weights)`` is the "net-lin" LPIPS model of Zhang et al. (2018), v0.1, written
with plain torch convolutions. The backbones reproduce the tap layers of torchvision's
``alexnet().features`` (relu1..relu5, i.e. feature indices 1, 4, 7, 9, 11) and
``vgg16().features`` (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3, i.e. indices 3, 8, 15, 22, 29).
Per tap: unit-normalise over channels (eps 1e-10), squared difference, 1x1 linear head (no bias),
spatial mean; the five taps are summed. Inputs are (B, 3, H, W) in [-1, 1]; the ScalingLayer
(shift (-.030, -.088, -.188), scale (.458, .448, .450)) is applied inside.
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F

from spc3d.evaluation.lpips_specs import SCALE, SHIFT, SPECS, canonical_net
from spc3d.evaluation.lpips_weights import check_weights
from spc3d.evaluation.scores import cached_net

NORM_EPS = 1e-10


# ---------------------------------------------------------------------------------------------
# Network
# ---------------------------------------------------------------------------------------------
class LPIPSNet(torch.nn.Module):
    """LPIPS v0.1 (net-lin) with a hand-written AlexNet or VGG16 backbone; parameters frozen.

    ``forward(x0, x1)``: two (B, 3, H, W) tensors in [-1, 1] -> (B,) distances.
    """

    def __init__(self, net: str, weights: dict[str, np.ndarray]):
        super().__init__()
        self.net = canonical_net(net)
        check_weights(weights, self.net)
        self.spec = SPECS[self.net]
        for key, value in weights.items():
            self.register_buffer(key.replace(".", "_"), torch.from_numpy(np.array(value, np.float32)))
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))
        self.eval()

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) in [-1, 1] -> the five unit-normalised tap feature maps (B, C_k, H_k, W_k)."""
        x = (x - self.shift) / self.scale
        taps, conv_i = [], 0
        for layer in self.spec:
            if layer[0] == "conv":
                _, _, _, stride, pad = layer
                weight, bias = getattr(self, f"conv{conv_i}_weight"), getattr(self, f"conv{conv_i}_bias")
                x = F.relu(F.conv2d(x, weight, bias, stride=stride, padding=pad))
                conv_i += 1
            elif layer[0] == "pool":
                x = F.max_pool2d(x, kernel_size=layer[1], stride=layer[2])
            else:
                norm = torch.sqrt(torch.sum(x * x, dim=1, keepdim=True))
                taps.append(x / (norm + NORM_EPS))
        return taps

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """Distances (B,) between (B, 3, H, W) images in [-1, 1]."""
        if x0.shape != x1.shape or x0.ndim != 4 or x0.shape[1] != 3:
            raise ValueError(
                f"LPIPS expects two (B, 3, H, W) tensors of one shape, got {tuple(x0.shape)} and {tuple(x1.shape)}"
            )
        dtype = self.shift.dtype
        total = 0.0
        f0s, f1s = self.features(x0.to(dtype)), self.features(x1.to(dtype))
        for j, (f0, f1) in enumerate(zip(f0s, f1s)):
            head = getattr(self, f"lin{j}_weight")
            total = total + F.conv2d((f0 - f1) ** 2, head).mean(dim=(1, 2, 3))
        return total


_NETS: dict[tuple, LPIPSNet] = {}


def get_lpips_net(
    net: str = "alex", weights_path: str | os.PathLike | None = None, cache_dir: str | os.PathLike | None = None
) -> LPIPSNet:
    """Process-wide cached ``LPIPSNet`` (one per backbone and explicit weights file)."""
    return cached_net(_NETS, LPIPSNet, net, weights_path, cache_dir)

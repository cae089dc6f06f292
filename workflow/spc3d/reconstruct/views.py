"""The training views a stage-2 trainer fits (the loop itself is :func:`spc3d.training.run`)."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from spc3d.cameras import Cameras


@dataclass
class Views:
    """Training views of one scene: targets (N, H, W, 3) float32 aligned with ``cameras``."""

    targets: Tensor
    cameras: Cameras
    names: list[str]

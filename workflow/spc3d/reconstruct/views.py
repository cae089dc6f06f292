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

    def subset(self, idx) -> Views:
        """The views at positions ``idx`` (in that order)."""
        idx = [int(i) for i in idx]
        return Views(self.targets[idx], self.cameras.subset(idx), [self.names[i] for i in idx])


def hold_out(views: Views, count: int) -> tuple[Views, Views | None]:
    """(views to fit, views held out of the fit) with ``count`` views held out, spread evenly
    over the list (positions ``floor((j + 1/2) n / count)``: inside the camera set, never its
    ends), but never more than a quarter of the views (a row posed by COLMAP may keep few);
    none held out: None. They judge when a training stops (:class:`spc3d.training.Plateau`):
    how well the fit predicts training views it never saw."""
    if count < 0:
        raise ValueError(f"plateau_views = {count}: the number of training views to hold out must be >= 0")
    n = len(views.names)
    count = min(count, n // 4)
    if not count:
        return views, None
    out = sorted({int((j + 0.5) * n / count) for j in range(count)})
    return views.subset([i for i in range(n) if i not in out]), views.subset(out)

"""The translators' image domain: the scene as the camera's exposure shows it.

Every scene is exposed so that its frames fire at about the same mean rate (the camera's auto
exposure, ``spc.target_detection``), so the frames alone cannot tell a dark scene from a bright
one: what they determine is the photon rate per frame, λ = H ℓ at scene linear intensity ℓ, where
H is the exposure the camera reports (``spc.json``'s ``exposure``: photons per pixel and frame at
ℓ = 1, :func:`spc3d.physics.record.camera_exposure`). The translators therefore learn, and
output, the *camera image*

    c = sRGB(clip(H ℓ / Λ, 0, 1))        Λ = CAMERA_WHITE photons per frame shown as white

and the display turns it back into the scene with the known exposure, ℓ = Λ lin(c) / H
(:func:`from_camera`). Training targets are the training scenes' images taken to this domain with
their own exposures (:func:`to_camera`); the translators then see the same mapping frames → image
on every scene, and a dark scene exposed longer displays dark. Λ is the rate at which a pixel fires
in 999 of 1000 frames, the physics prior's ceiling (:data:`spc3d.translate.prior.P_MAX`): brighter
than that, the bits carry almost nothing, and the prior itself saturates there.
"""

from __future__ import annotations

import math

from torch import Tensor

from spc3d.pixels import linear_to_srgb, srgb_to_linear
from spc3d.translate.prior import P_MAX

CAMERA_WHITE = -math.log1p(-P_MAX)  # 6.91 photons per frame: P(bit = 1) = 0.999
DOMAIN = "camera"  # recorded with every model: its outputs are camera images, not display images


def _scale(exposure: float | Tensor, like: Tensor) -> float | Tensor:
    """``exposure`` as a number or a (B,) tensor broadcast over (B, C, H, W) / (C, H, W) images."""
    if isinstance(exposure, Tensor) and exposure.ndim == 1:
        return exposure.to(like).view(-1, *([1] * (like.ndim - 1)))
    value = float(exposure)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"camera exposure must be finite and > 0 photons per frame, got {exposure!r}")
    return value


def to_camera(srgb: Tensor, exposure: float | Tensor) -> Tensor:
    """The camera image of a scene image (sRGB in [0, 1]) taken at ``exposure`` (photons per frame at ℓ = 1)."""
    return linear_to_srgb(srgb_to_linear(srgb) * (_scale(exposure, srgb) / CAMERA_WHITE))


def from_camera(camera: Tensor, exposure: float | Tensor) -> Tensor:
    """The display (sRGB in [0, 1]) of a camera image taken at ``exposure``: ℓ = Λ lin(c) / H, clipped."""
    return linear_to_srgb(srgb_to_linear(camera) * (CAMERA_WHITE / _scale(exposure, camera)))

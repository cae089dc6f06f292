"""3D Gaussian Splatting math on CPU: projection, SH colour and two interchangeable rasterizers.

    proj = project_gaussians(means, scales, quats, w2c, fx, fy, cx, cy, H, W)  # or ..._native
    rgb = eval_sh(degree, sh, means - camera_centre)
    image, alpha = rasterize(proj.means2d, proj.conics, opacities, rgb, proj.depths, proj.radii,
                             H, W, background, backend="native")

Back-ends (plain registry ``BACKENDS``): ``native`` (numba kernels, hand-written gradients; the
default) and ``reference`` (pure PyTorch "exact pixel pairs", autograd). Both run on CPU; a CUDA
back-end (gsplat) is not shipped, and asking for one says so.
``project_gaussians`` (pure PyTorch, the definition) and ``project_gaussians_native`` (numba,
hand-written gradients, faster) are interchangeable.

Densification (3DGS): call ``proj.means2d.retain_grad()`` before ``backward``; the view-space
positional gradient is then ``proj.means2d.grad`` (pixels) with either projection and back-end.
"""

from __future__ import annotations

from torch import Tensor

from spc3d.reconstruct.splat.native import rasterize_native
from spc3d.reconstruct.splat.native_project import project_gaussians_native
from spc3d.reconstruct.splat.project import Projected, eval_sh, project_gaussians, quat_to_rotmat
from spc3d.reconstruct.splat.reference import rasterize_dense, rasterize_reference

BACKENDS = {"native": rasterize_native, "reference": rasterize_reference}


def rasterize(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    depths: Tensor,
    radii: Tensor,
    height: int,
    width: int,
    background: Tensor,
    backend: str = "native",
) -> tuple[Tensor, Tensor]:
    """Composite screen-space Gaussians with the chosen back-end: image (H, W, C), alpha (H, W)."""
    if backend not in BACKENDS:
        raise ValueError(
            f"rasterize: unknown backend {backend!r}; choose one of {sorted(BACKENDS)} (both CPU; spc3d ships "
            "no CUDA back-end such as gsplat: it needs a CUDA GPU and an adapter that is not written)"
        )
    return BACKENDS[backend](means2d, conics, opacities, colors, depths, radii, height, width, background)


__all__ = [
    "BACKENDS",
    "Projected",
    "eval_sh",
    "project_gaussians",
    "project_gaussians_native",
    "quat_to_rotmat",
    "rasterize",
    "rasterize_dense",
    "rasterize_native",
    "rasterize_reference",
]

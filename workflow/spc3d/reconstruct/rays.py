"""Rays for forward-facing scenes: pixel rays, LLFF recentring and NDC, in the internal convention.

Internal convention (see :mod:`spc3d.cameras`): OpenCV camera axes (x right, y down, z forward),
``w2c = [R | t]``, pixel centres at integer + 0.5.

Recentring (LLFF NeRF ``recenter_poses`` + ``bd_factor``): the average pose has its centre at the
mean camera centre, its forward axis along the normalised sum of forward axes and its down axis
from the sum of down axes (re-orthogonalised). The world is re-expressed in that average camera's
frame, x' = s R_avg^T (x - c_avg), with s = 1 / (0.75 · min near bound), so that after recentring
the cameras look roughly down **+z** and every scene point lies beyond depth 1/0.75 > 1 = ``near``.
The original code does the same in [right, up, back] axes (cameras look down −z); only the axis
signs differ, the geometry is identical.

NDC derivation for a camera looking down +z (the original's formulas with z → −z). A pinhole with
focal lengths (fx, fy) and a W×H image sees x/z ∈ [−W/(2 fx), W/(2 fx)]; the projective map

    x_ndc = a_x · x / z,   y_ndc = a_y · y / z,   z_ndc = 1 − 2 n / z,   a_x = 2 fx / W, a_y = 2 fy / H

sends the frustum between depth n and ∞ to the box [−1, 1]³ (z = n → z_ndc = −1, z → ∞ → +1).
Projective maps keep straight lines straight, so a ray o + s·d with o on the near plane (o_z = n,
obtained by moving the origin along the ray) maps to o' + t·d' with

    o' = (a_x o_x / o_z,  a_y o_y / o_z,  1 − 2 n / o_z)
    d' = (a_x (d_x / d_z − o_x / o_z),  a_y (d_y / d_z − o_y / o_z),  2 n / o_z)

and t = 1 − o_z / z(s) ∈ [0, 1): t = 0 at the near plane, t → 1 as the depth goes to infinity. With
o_z = n the depth at parameter t is z = n / (1 − t), i.e. t is linear in disparity: uniform samples
in t are uniform in inverse depth. The NDC y axis points down, like the image; nothing downstream
depends on its sign. A principal point off the image centre only shifts the box slightly.
"""

from __future__ import annotations

import numpy as np
import torch

from spc3d.cameras import Cameras, transform_cameras

BD_FACTOR = 0.75  # LLFF NeRF: scale so the nearest bound lands at 1 / 0.75 (a margin before near = 1)
_MIN_DZ = 1e-6  # rays must point forward (d_z > 0) for NDC; clamp guards the division for grazing rays


def pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u, v), each (H*W,), row-major (v slowest)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    return u.ravel(), v.ravel()


def camera_rays(cams: Cameras, idx: int, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space rays through the pixel centres of view ``idx``.

    Returns origins (H*W, 3) and dirs (H*W, 3), row-major over the image. dirs are NOT unit length:
    their camera-frame z component is 1, so ``o + s·d`` sits at camera depth s.
    """
    u, v = pixel_grid(cams.height, cams.width)
    fx, fy, cx, cy = cams.intrinsics[idx]
    d_cam = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=1)  # (H*W, 3)
    c2w = cams.c2w[idx]
    dirs = d_cam @ c2w[:, :3].T
    origins = np.broadcast_to(c2w[:, 3], dirs.shape)
    return torch.as_tensor(origins.copy(), dtype=dtype), torch.as_tensor(dirs, dtype=dtype)


def average_pose(cams: Cameras) -> np.ndarray:
    """(3, 4) camera-to-world average pose [right, down, forward | centre] (OpenCV axes)."""
    c2w = cams.c2w
    fwd = c2w[:, :, 2].sum(0)
    fwd /= np.linalg.norm(fwd)
    down = c2w[:, :, 1].sum(0)
    right = np.cross(down, fwd)  # OpenCV: x = y × z
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)  # y = z × x, exactly orthogonal now
    return np.stack([right, down, fwd, c2w[:, :, 3].mean(0)], axis=1)


def recenter(cams: Cameras, bd_factor: float = BD_FACTOR) -> tuple[Cameras, tuple[float, np.ndarray, np.ndarray]]:
    """LLFF recentring and bound rescaling.

    Returns the new cameras and the similarity (s, R, t) with x_new = s R x_world + t (the form
    :func:`spc3d.cameras.transform_cameras` takes); bounds are scaled by s = 1/(min_near · bd_factor).
    """
    min_near = float(cams.bounds[:, 0].min())
    if not min_near > 0:
        raise ValueError(f"recenter: near bounds must be > 0, got min {min_near}")
    s = 1.0 / (min_near * bd_factor)
    avg = average_pose(cams)
    R = avg[:, :3].T
    t = -s * R @ avg[:, 3]
    return transform_cameras(cams, s, R, t), (s, R, t)


def ndc_rays(
    origins: torch.Tensor, dirs: torch.Tensor, fx: float, fy: float, W: int, H: int, near: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """Map rays (R, 3) of the recentred world (looking down +z) to NDC rays (R, 3), t ∈ [0, 1)."""
    dz = dirs[:, 2].clamp(min=_MIN_DZ)
    s = (near - origins[:, 2]) / dz
    o = origins + s[:, None] * dirs  # origin moved onto the near plane z = near
    ax, ay = 2.0 * fx / W, 2.0 * fy / H
    oz = o[:, 2]
    o_ndc = torch.stack([ax * o[:, 0] / oz, ay * o[:, 1] / oz, 1.0 - 2.0 * near / oz], dim=1)
    d_ndc = torch.stack(
        [ax * (dirs[:, 0] / dz - o[:, 0] / oz), ay * (dirs[:, 1] / dz - o[:, 1] / oz), 2.0 * near / oz], dim=1
    )
    return o_ndc, d_ndc


def view_dirs(dirs: torch.Tensor) -> torch.Tensor:
    """Unit viewing directions (R, 3) from world ray directions (R, 3)."""
    return dirs / dirs.norm(dim=-1, keepdim=True)

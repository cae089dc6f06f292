"""3D Gaussian Splatting (Kerbl et al. 2023): the Gaussians, their initialisation and rendering.

Parameters (N Gaussians), stored unconstrained and activated on use as in the reference code:
means (N, 3); log-scales (N, 3) -> exp; quaternions (N, 4) wxyz -> normalised in projection;
opacity logits (N,) -> sigmoid; SH coefficients: DC (N, 1, 3) and rest (N, 15, 3) for degree 3.

Initialisation: COLMAP's sparse points (mapped into the scene's world with the similarity of the
pose-error record) when given, else random points in the training frusta between near and far,
uniform in inverse depth (as forward-facing scenes are sampled in NDC). Initial scale = RMS
distance to the 3 nearest neighbours, opacity 0.1, colour from the points (grey when random).

Density control lives in :mod:`spc3d.reconstruct.densify`; the training loop in
:mod:`spc3d.reconstruct.views`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from spc3d.cameras import Cameras
from spc3d.reconstruct.pose_refine import quat_mul
from spc3d.reconstruct.splat import eval_sh, project_gaussians, project_gaussians_native, rasterize
from spc3d.reconstruct.splat.native_sh import eval_sh_native
from spc3d.reconstruct.splat.project import SH_C0
from spc3d.specs.reconstructors import GaussianConfig

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


class GaussianModel(nn.Module):
    """N anisotropic 3-D Gaussians with SH colour."""

    def __init__(self, means: Tensor, colors: Tensor, sh_degree: int = 3, opacity: float = 0.1):
        super().__init__()
        n = means.shape[0]
        dist = knn_rms_distance(means).clamp_min(1e-7)  # clamp: duplicate points would give log(0)
        quats = torch.zeros(n, 4)
        quats[:, 0] = 1.0
        rest = torch.zeros(n, (sh_degree + 1) ** 2 - 1, 3)
        init = {
            "means": means.float(),
            "log_scales": dist.log()[:, None].repeat(1, 3),
            "quats": quats,
            "opacity_logits": torch.full((n,), float(np.log(opacity / (1 - opacity)))),
            "sh_dc": ((colors.float() - 0.5) / SH_C0)[:, None, :],
            "sh_rest": rest,
        }
        for name in PARAM_NAMES:
            setattr(self, name, nn.Parameter(init[name].contiguous()))
        self.active_degree = 0

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def scales(self) -> Tensor:
        return self.log_scales.exp()

    @property
    def opacities(self) -> Tensor:
        return torch.sigmoid(self.opacity_logits)

    def render(self, cams: Cameras, i: int, background: Tensor, backend: str = "native", motion=None) -> dict:
        """Render view ``i``: image (H, W, 3), alpha (H, W), and the projection (for densification).
        ``motion`` (:class:`.pose_refine.SceneMotion`): render the scene moved by it (a camera
        correction, with its gradient); the SH colour is seen from the direction it had before."""
        K, w2c = cams.intrinsics[i], torch.as_tensor(cams.w2c[i], dtype=torch.float32)
        means, quats = self.means, self.quats
        if motion is not None:
            means, quats = means @ motion.R.T + motion.t, quat_mul(motion.q, quats)
        native = backend == "native"
        project = project_gaussians_native if native else project_gaussians  # same math
        proj = project(means, self.scales, quats, w2c, *map(float, K), cams.height, cams.width)
        centre = torch.as_tensor(cams.centers[i], dtype=torch.float32)
        dirs = means - centre if motion is None else (means - centre) @ motion.R  # R^T: back to the model's frame
        if native:  # same colour and gradients, without the concatenation
            rgb = eval_sh_native(self.active_degree, self.sh_dc, self.sh_rest, dirs)
        else:
            rgb = eval_sh(self.active_degree, torch.cat([self.sh_dc, self.sh_rest], 1), dirs)
        image, alpha = rasterize(
            proj.means2d,
            proj.conics,
            self.opacities,
            rgb,
            proj.depths,
            proj.radii,
            cams.height,
            cams.width,
            background,
            backend,
        )
        return {"image": image, "alpha": alpha, "proj": proj}

    def capacity(self) -> dict:
        return {
            "gaussians": len(self),
            "sh_degree": self.active_degree,
            "parameters": int(sum(p.numel() for p in self.parameters())),
        }


def knn_rms_distance(points: Tensor, k: int = 3, chunk: int = 2048) -> Tensor:
    """(N,) RMS distance of each point to its k nearest neighbours (3DGS's initial scale)."""
    points = points.float()
    k = min(k, max(points.shape[0] - 1, 1))
    out = []
    for start in range(0, points.shape[0], chunk):
        d2 = torch.cdist(points[start : start + chunk], points).square()
        d2[torch.arange(d2.shape[0]), torch.arange(start, start + d2.shape[0])] = float("inf")  # not itself
        nearest = d2.topk(k, largest=False).values
        out.append(torch.where(torch.isfinite(nearest), nearest, torch.zeros_like(nearest)).mean(1).sqrt())
    return torch.cat(out)


def random_points(cams: Cameras, n: int, seed: int) -> Tensor:
    """(n, 3) points in the training frusta, uniform in pixels and in inverse depth [1/far, 1/near]."""
    rng = np.random.default_rng(seed)
    view = rng.integers(len(cams), size=n)
    u, v = rng.uniform(0, cams.width, n), rng.uniform(0, cams.height, n)
    near, far = cams.bounds[view, 0], cams.bounds[view, 1]
    depth = 1.0 / rng.uniform(1.0 / far, 1.0 / near)
    fx, fy, cx, cy = cams.intrinsics[view].T
    p_cam = np.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], 1)
    c2w = cams.c2w[view]
    return torch.as_tensor(np.einsum("nij,nj->ni", c2w[:, :, :3], p_cam) + c2w[:, :, 3], dtype=torch.float32)


def initial_model(
    cams: Cameras, cfg: GaussianConfig, seed: int, points: np.ndarray | None = None, colors: np.ndarray | None = None
) -> GaussianModel:
    """A model from sparse points (N, 3) with colours (N, 3) in [0, 1], or random when none."""
    torch.manual_seed(seed)
    if points is None or len(points) < 4:
        xyz = random_points(cams, cfg.init_points, seed)
        rgb = torch.full_like(xyz, 0.5)
    else:
        xyz, rgb = torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(colors, dtype=torch.float32)
    return GaussianModel(xyz, rgb, cfg.sh_degree)


def scene_extent(cams: Cameras) -> float:
    """3DGS's scene scale: 1.1 x the largest distance of a camera centre from their mean."""
    c = cams.centers
    return float(1.1 * np.linalg.norm(c - c.mean(0), axis=1).max()) or 1.0

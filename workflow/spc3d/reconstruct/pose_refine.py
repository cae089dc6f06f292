"""Camera refinement while 3DGS trains: a learnt correction of every training view's pose.

Poses COLMAP estimated from a few noisy images (``source+model@poses``) are off by a fraction of a
degree, and a 3DGS fitted to them blurs what the views disagree on. As pose-free 3DGS / NeRF methods
do (BARF, Lin et al. 2021; CF-3DGS, Fu et al. 2024), each training view ``i`` gets a correction
``D_i = [dR_i | dt_i]`` in its own camera frame, ``w2c_i' = D_i w2c_i``: ``dR_i`` from an axis-angle
vector, ``dt_i`` in scene units. The native rasterizer has no gradient to the camera, so the view is
rendered through the equivalent motion of the scene, ``T_i = w2c_i^-1 D_i w2c_i``, applied to the
Gaussians (means, rotations, and the direction their SH colour is seen from); the gradient reaches
``D_i`` through them. The corrections start at zero and move only after ``pose_from`` iterations,
once the Gaussians roughly fit.

The world a refined model lives in drifts with its cameras (any common motion of scene and cameras
renders the same), so held-out views are rendered at their reference cameras mapped by the
similarity that aligns the refined training cameras with their reference ones
(:func:`heldout_cameras`), the protocol of pose-free novel-view synthesis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor, nn

from spc3d.cameras import Cameras, transform_cameras


@dataclass
class SceneMotion:
    """A rigid motion of the scene: x -> R x + t; ``q`` is R as a wxyz quaternion."""

    R: Tensor
    t: Tensor
    q: Tensor


def skew(w: Tensor) -> Tensor:
    zero = w.new_zeros(())
    return torch.stack(
        [torch.stack([zero, -w[2], w[1]]), torch.stack([w[2], zero, -w[0]]), torch.stack([-w[1], w[0], zero])]
    )


def axis_angle_matrix(w: Tensor) -> Tensor:
    """Rodrigues: (3,) axis-angle -> (3, 3), with the series of sin(x)/x and (1 - cos x)/x^2 near 0
    (exact to float precision below 1e-4 rad; differentiable at 0)."""
    theta2 = (w * w).sum()
    small = theta2 < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))  # no sqrt(0): its gradient is inf
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / (theta * theta))
    k = skew(w)
    return torch.eye(3, dtype=w.dtype) + a * k + b * (k @ k)


def axis_angle_quat(w: Tensor) -> Tensor:
    """(3,) axis-angle -> (4,) wxyz unit quaternion (series of sin(x/2)/x near 0)."""
    theta2 = (w * w).sum()
    small = theta2 < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    half = torch.where(small, 0.5 - theta2 / 48.0, torch.sin(theta / 2) / theta)
    return torch.cat([torch.where(small, 1.0 - theta2 / 8.0, torch.cos(theta / 2)).reshape(1), half * w])


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of wxyz quaternions (broadcasting: a (4,) with b (N, 4))."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def matrix_quat(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> wxyz quaternion."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


class PoseCorrections(nn.Module):
    """One camera-frame correction per training view: (N, 6) = axis-angle (rad), translation in
    units of ``scale`` (the scene extent: one learning rate suits both halves)."""

    def __init__(self, cams: Cameras, scale: float = 1.0):
        super().__init__()
        self.scale = float(scale)
        self.delta = nn.Parameter(torch.zeros(len(cams), 6))
        w2c = torch.as_tensor(cams.w2c, dtype=torch.float32)
        self.register_buffer("rot", w2c[:, :, :3].clone())  # R_w of every view
        self.register_buffer("trans", w2c[:, :, 3].clone())  # t_w
        self.register_buffer("qrot", torch.as_tensor(np.stack([matrix_quat(r) for r in cams.w2c[:, :, :3]])).float())

    def motion(self, i: int) -> SceneMotion:
        """T_i = w2c_i^-1 D_i w2c_i as a scene motion: x -> R_w^T dR R_w x + R_w^T (dR t_w + dt - t_w)."""
        w, dt = self.delta[i, :3], self.scale * self.delta[i, 3:]
        rw, tw = self.rot[i], self.trans[i]
        dr = axis_angle_matrix(w)
        R = rw.T @ dr @ rw
        t = rw.T @ (dr @ tw + dt - tw)
        qw = self.qrot[i]
        q = quat_mul(quat_mul(qw * torch.tensor([1.0, -1.0, -1.0, -1.0]), axis_angle_quat(w)), qw)  # q_w^-1 dq q_w
        return SceneMotion(R, t, q)

    @torch.no_grad()
    def refined(self, cams: Cameras) -> Cameras:
        """The corrected cameras D_i w2c_i (numpy, the views of ``cams`` in order)."""
        w2c = []
        for i in range(len(cams)):
            dr = axis_angle_matrix(self.delta[i, :3].double()).numpy()
            D = np.concatenate([dr, self.scale * self.delta[i, 3:].double().numpy()[:, None]], 1)
            w2c.append(D[:, :3] @ cams.w2c[i] + np.concatenate([np.zeros((3, 3)), D[:, 3:]], 1))
        return Cameras(np.stack(w2c), cams.intrinsics, cams.height, cams.width, cams.bounds)

    def magnitude(self) -> dict:
        """Median / max correction: rotation (degrees) and translation (scene units)."""
        d = self.delta.detach().double()
        rot, shift = torch.rad2deg(d[:, :3].norm(dim=1)), self.scale * d[:, 3:].norm(dim=1)
        return {
            "rotation_deg_median": float(rot.median()),
            "rotation_deg_max": float(rot.max()),
            "translation_median": float(shift.median()),
            "translation_max": float(shift.max()),
        }


class RowAdam:
    """Adam on the rows of an (N, D) parameter that steps only the row given (the view just rendered).

    Each training step renders one view, so only its correction has a gradient. ``torch.optim.Adam``
    on the whole tensor would still move every other row on the momentum of its last visit (zero
    gradients decay m faster than sqrt(v)): on pure-noise gradients over 18 views that was 4x the
    random-walk drift of this one. Here a row's moments and step count advance only when it is
    visited, as in lazy (sparse) Adam."""

    def __init__(self, param: nn.Parameter, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param, self.betas, self.eps = param, betas, eps
        self.m, self.v = torch.zeros_like(param), torch.zeros_like(param)
        self.t = torch.zeros(len(param), dtype=torch.int64)

    def zero_grad(self) -> None:
        self.param.grad = None

    @torch.no_grad()
    def step(self, i: int, lr: float) -> None:
        b1, b2 = self.betas
        g = self.param.grad[i]
        self.t[i] += 1
        self.m[i] = b1 * self.m[i] + (1 - b1) * g
        self.v[i] = b2 * self.v[i] + (1 - b2) * g * g
        t = int(self.t[i])
        m_hat, v_hat = self.m[i] / (1 - b1**t), self.v[i] / (1 - b2**t)
        self.param[i] -= lr * m_hat / (v_hat.sqrt() + self.eps)

    def state_dict(self) -> dict:
        return {"m": self.m.clone(), "v": self.v.clone(), "t": self.t.clone()}

    def load_state_dict(self, state: dict) -> None:
        if set(state) != {"m", "v", "t"}:
            raise ValueError(
                f"camera-correction optimizer state has keys {sorted(state)}, expected m, v, t: a checkpoint "
                "written before per-view Adam (delete it to retrain this row)"
            )
        self.m, self.v, self.t = state["m"].clone(), state["v"].clone(), state["t"].clone()


def heldout_cameras(refined_train: Cameras, reference_train: Cameras, reference_test: Cameras) -> Cameras:
    """The held-out views' reference cameras in the refined model's world: mapped by the inverse of
    the similarity that aligns the refined training cameras with their reference ones."""
    from spc3d.poses.alignment import fit_similarity

    s, R, t = fit_similarity(reference_train, refined_train)  # x_ref = s R x_model + t
    return transform_cameras(reference_test, 1.0 / s, R.T, -R.T @ t / s)

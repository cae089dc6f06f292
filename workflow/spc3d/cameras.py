"""Cameras: the one internal convention, and conversions at the edges.

Internal convention (as OpenCV and COLMAP): a camera is a pinhole with intrinsics
``(fx, fy, cx, cy)`` in pixels and a **world-to-camera** rigid transform ``w2c = [R | t]``
(``x_cam = R @ x_world + t``). Camera axes: x right, y down, z forward (looking direction).
Pixel centres sit at integer + 0.5 coordinates, so the image centre of a W-wide image is W / 2.

LLFF ``poses_bounds.npy`` stores per view a 3x5 matrix ``[c2w rotation | c2w translation | hwf]``
whose rotation columns are the camera axes [down, right, back] in world coordinates, then the
near / far depth bounds: N x 17 floats. Conversions:

    LLFF columns (down, right, back)  ->  OpenCV columns (right, down, forward)
    right = llff[:, 1],  down = llff[:, 0],  forward = -llff[:, 2]

COLMAP stores ``cam_from_world`` exactly as our w2c; quaternions are avoided on purpose (pycolmap
exposes 3x4 matrices), so no quaternion-order convention can slip in.

Held-out test views: every 8th view (``llffhold = 8``), as NeRF, 3DGS, gsplat and nerfstudio.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LLFF_HOLD = 8


@dataclass(frozen=True)
class Cameras:
    """N pinhole cameras in the internal convention.

    w2c: (N, 3, 4) world-to-camera [R | t], OpenCV axes.
    intrinsics: (N, 4) fx, fy, cx, cy in pixels.
    height, width: image size in pixels (shared by all views).
    bounds: (N, 2) near / far scene depth along the camera z axis.
    """

    w2c: np.ndarray
    intrinsics: np.ndarray
    height: int
    width: int
    bounds: np.ndarray

    def __len__(self) -> int:
        return self.w2c.shape[0]

    @property
    def c2w(self) -> np.ndarray:
        """(N, 3, 4) camera-to-world [R | centre]."""
        return invert_rigid(self.w2c)

    @property
    def centers(self) -> np.ndarray:
        """(N, 3) camera centres in world coordinates."""
        return self.c2w[:, :, 3]

    def K(self) -> np.ndarray:
        """(N, 3, 3) intrinsic matrices."""
        fx, fy, cx, cy = self.intrinsics.T
        K = np.zeros((len(self), 3, 3))
        K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, cx, cy, 1.0
        return K

    def subset(self, idx) -> Cameras:
        idx = np.asarray(idx)
        return Cameras(self.w2c[idx], self.intrinsics[idx], self.height, self.width, self.bounds[idx])

    def rescaled(self, height: int, width: int) -> Cameras:
        """The same cameras for images resized to (height, width)."""
        sx, sy = width / self.width, height / self.height
        intr = self.intrinsics * np.array([sx, sy, sx, sy])
        return Cameras(self.w2c.copy(), intr, height, width, self.bounds.copy())


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Invert rigid transforms (..., 3, 4) -> (..., 3, 4)."""
    R, t = T[..., :3, :3], T[..., :3, 3:]
    Rt = np.swapaxes(R, -1, -2)
    return np.concatenate([Rt, -Rt @ t], axis=-1)


def llff_to_cameras(poses_bounds: np.ndarray, height: int | None = None, width: int | None = None) -> Cameras:
    """Convert an LLFF ``poses_bounds`` array (N, 17) to internal cameras.

    ``hwf`` in the file refers to the images the poses were computed for (often full size);
    pass the (height, width) of the images actually loaded to rescale the focal length.
    """
    pb = np.asarray(poses_bounds, dtype=np.float64)
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise ValueError(f"poses_bounds must have shape (N, 17), got {pb.shape}")
    poses = pb[:, :15].reshape(-1, 3, 5)
    h0, w0, f0 = poses[0, :, 4]
    height = int(round(h0)) if height is None else height
    width = int(round(w0)) if width is None else width
    c2w = np.concatenate([poses[:, :, 1:2], poses[:, :, 0:1], -poses[:, :, 2:3], poses[:, :, 3:4]], axis=2)
    f = poses[:, 2, 4] * (width / poses[:, 1, 4])
    fy = poses[:, 2, 4] * (height / poses[:, 0, 4])
    intr = np.stack([f, fy, np.full_like(f, width / 2), np.full_like(f, height / 2)], axis=1)
    return Cameras(invert_rigid(c2w), intr, height, width, pb[:, 15:17].copy())


def cameras_to_llff(cams: Cameras) -> np.ndarray:
    """Convert internal cameras to an LLFF ``poses_bounds`` array (N, 17).

    LLFF has one focal length per view and a centred principal point; fx is written.
    """
    c2w = cams.c2w
    llff = np.concatenate([c2w[:, :, 1:2], c2w[:, :, 0:1], -c2w[:, :, 2:3], c2w[:, :, 3:4]], axis=2)
    hwf = np.stack([np.full(len(cams), cams.height), np.full(len(cams), cams.width), cams.intrinsics[:, 0]], 1)
    poses = np.concatenate([llff, hwf[:, :, None]], axis=2)  # (N, 3, 5)
    return np.concatenate([poses.reshape(-1, 15), cams.bounds], axis=1)


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """World-to-camera (3, 4) of a camera at ``center`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (image y points down);
    default ``(0, -1, 0)``.
    """
    if up is None:
        up = np.array([0.0, -1.0, 0.0])
    fwd = np.asarray(target, float) - np.asarray(center, float)
    if not np.linalg.norm(fwd) > 1e-12:
        raise ValueError(f"look_at: centre == target ({center}); no viewing direction")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)  # OpenCV: right = down x forward = forward x up
    norm = np.linalg.norm(right)
    if not norm > 1e-9:
        raise ValueError(f"look_at: viewing direction {fwd} is parallel to up {up}")
    right /= norm
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])  # rows: camera axes in world coordinates
    return np.concatenate([R, -R @ np.asarray(center, float)[:, None]], axis=1)


def split_views(n: int, hold: int = LLFF_HOLD) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) view indices: every ``hold``-th view is held out for testing."""
    if n < 2:
        raise ValueError(f"need at least 2 views to split train/test, got {n}")
    test = np.arange(n)[::hold]
    return np.setdiff1d(np.arange(n), test), test


def project(cams: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (M, 3) into every camera.

    Returns pixel coordinates (N, M, 2) and depths (N, M) (z in the camera frame).
    """
    X = np.einsum("nij,mj->nmi", cams.w2c[:, :, :3], points) + cams.w2c[:, None, :, 3]
    z = X[..., 2]
    safe_z = np.where(np.abs(z) < 1e-12, 1e-12, z)  # points on the camera plane: avoid 0-division
    fx, fy, cx, cy = (cams.intrinsics[:, i : i + 1] for i in range(4))
    uv = np.stack([fx * X[..., 0] / safe_z + cx, fy * X[..., 1] / safe_z + cy], axis=-1)
    return uv, z


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising ||dst - (s R src + t)||² (Umeyama 1991).

    src, dst: (M, 3) corresponding points, M >= 3 and not collinear.
    """
    if src.shape != dst.shape or src.shape[0] < 3:
        raise ValueError(f"umeyama needs two (M>=3, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs**2).sum() / len(src)
    if var_s < 1e-20:
        raise ValueError("umeyama: source points coincide; cannot estimate a similarity")
    U, D, Vt = np.linalg.svd(xd.T @ xs / len(src))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s)
    return s, R, mu_d - s * R @ mu_s


def transform_cameras(cams: Cameras, s: float, R: np.ndarray, t: np.ndarray) -> Cameras:
    """Cameras expressed in a world mapped by x' = s R x + t (bounds scale with s)."""
    c2w = cams.c2w
    new_c2w = np.concatenate([R @ c2w[:, :, :3], (s * (R @ c2w[:, :, 3].T)).T[:, :, None] + t[:, None]], axis=2)
    return Cameras(invert_rigid(new_c2w), cams.intrinsics.copy(), cams.height, cams.width, cams.bounds * s)


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle in degrees between rotations (..., 3, 3)."""
    cos = (np.trace(np.swapaxes(Ra, -1, -2) @ Rb, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))  # clip: rounding can push |cos| past 1

"""Similarity alignment of estimated cameras onto reference cameras, and their pose and reprojection errors.

Pure numpy (no pycolmap); the internal camera convention of :mod:`spc3d.cameras`. Used by
:mod:`spc3d.poses.colmap` to score COLMAP poses against the reference (LLFF) cameras.

- **pose error**: a similarity maps the estimated world onto the reference world: its rotation
  from the camera orientations (chordal mean), its scale and translation from the camera centres
  (or, with ``align="centers"``, all three from the centres by Umeyama; ill-conditioned for
  forward-facing captures, whose centres are nearly coplanar: see :func:`fit_similarity`).
  Per view the rotation error is the geodesic angle between the aligned and reference rotations,
  and the centre error is the distance between aligned and reference centres divided by the
  *camera spread* = RMS distance of all reference centres from their mean;
- **reprojection error**: 3-D points, mapped into the reference world by that similarity, are
  projected with the reference cameras into the views where they were observed and compared with
  the observed keypoints. COLMAP keypoints put the centre of the top-left pixel at (0.5, 0.5), as
  our cameras do (principal point W / 2), so no offset is applied; the mean signed residual is
  reported so that a half-pixel slip would show.
"""

from __future__ import annotations

import numpy as np

from spc3d.cameras import Cameras, project, rotation_angle_deg, transform_cameras, umeyama

SPREAD_DEFINITION = "RMS distance of all reference camera centres from their mean"
Similarity = tuple[float, np.ndarray, np.ndarray]  # (s, R, t): x_ref = s R x_est + t


def summary(values: np.ndarray) -> dict:
    """mean / median / max of a non-empty array as plain floats."""
    return {"mean": float(np.mean(values)), "median": float(np.median(values)), "max": float(np.max(values))}


def camera_spread(cams: Cameras) -> float:
    """RMS distance of the camera centres from their mean."""
    c = cams.centers
    return float(np.sqrt(((c - c.mean(0)) ** 2).sum(1).mean()))


ALIGNMENTS = ("rotations", "centers")


def world_rotation(est: Cameras, ref: Cameras) -> np.ndarray:
    """Rotation R (estimated world -> reference world) best matching the camera orientations.

    Minimises sum_i ||R_est_i R^T - R_ref_i||_F (chordal L2 mean, closed form by SVD).
    """
    M = np.einsum("nji,njk->ik", est.w2c[:, :, :3], ref.w2c[:, :, :3])  # sum_i R_est_i^T R_ref_i
    U, _, Vt = np.linalg.svd(M)
    Rt = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return Rt.T


def scale_translation(src: np.ndarray, dst: np.ndarray, R: np.ndarray) -> Similarity:
    """Least-squares s, t of dst ≈ s R src + t for a given rotation R."""
    xs, xd = src - src.mean(0), dst - dst.mean(0)
    var = float((xs**2).sum())
    if var < 1e-20:
        raise ValueError("estimated camera centres coincide; cannot estimate a scale")
    s = float((xd * (xs @ R.T)).sum() / var)
    return s, R, dst.mean(0) - s * R @ src.mean(0)


def fit_similarity(ref: Cameras, est: Cameras, align: str = "rotations") -> Similarity:
    """Similarity (s, R, t) with x_ref = s R x_est + t for corresponding cameras ``est`` / ``ref``.

    ``"centers"``: Umeyama on the camera centres alone. ``"rotations"`` (default): R from the
    camera orientations, then s, t from the centres. Forward-facing centres are nearly coplanar
    (fern: singular values 14.8 / 5.0 / 0.85), so a centre-only fit tilts the world by the
    centres' depth noise (2.7° on fern at 252 px, every view then reads ~2.7° off and the points
    reproject ~10 px off); the orientations fix R to ~0.2°.
    """
    if align == "centers":
        return umeyama(est.centers, ref.centers)
    if align == "rotations":
        return scale_translation(est.centers, ref.centers, world_rotation(est, ref))
    raise ValueError(f"unknown alignment {align!r}; choose one of {ALIGNMENTS}")


def pose_error(ref: Cameras, est: Cameras, est_idx, align: str = "rotations") -> dict:
    """Pose error of ``est`` (views ``est_idx`` of ``ref``) after a similarity alignment.

    The similarity (s, R, t) maps the estimated world onto the reference world (see
    :func:`fit_similarity`; at least 3 registered views). Per view: rotation error in degrees
    between the aligned and reference camera rotations; centre error = |aligned centre −
    reference centre| / spread, where spread = RMS distance of all reference centres from their
    mean. JSON-ready: when no alignment is possible, statistics are null and ``reason`` says why.
    """
    est_idx = np.asarray(est_idx, dtype=int)
    spread = camera_spread(ref) if len(ref) else 0.0
    record = {
        "registered": int(len(est_idx)),
        "total": int(len(ref)),
        "aligned": False,
        "reason": None,
        "alignment": align,
        "spread": spread,
        "spread_definition": SPREAD_DEFINITION,
        "rotation_deg": None,
        "center_rel": None,
        "scale": None,
        "similarity": None,
        "per_view": None,
    }
    if len(est_idx) < 3:
        return {**record, "reason": f"{len(est_idx)} of {len(ref)} views registered; a similarity needs at least 3"}
    if spread <= 0.0:
        return {**record, "reason": "reference camera centres coincide (spread 0)"}
    try:
        s, R, t = fit_similarity(ref.subset(est_idx), est, align)
    except ValueError as e:
        return {**record, "reason": str(e)}
    aligned = transform_cameras(est, s, R, t)
    rot = rotation_angle_deg(aligned.w2c[:, :, :3], ref.w2c[est_idx, :, :3])
    cen = np.linalg.norm(aligned.centers - ref.centers[est_idx], axis=1) / spread
    per_view = {"index": est_idx.tolist(), "rotation_deg": rot.tolist(), "center_rel": cen.tolist()}
    return {
        **record,
        "aligned": True,
        "rotation_deg": summary(rot),
        "center_rel": summary(cen),
        "scale": s,
        "similarity": {"scale": s, "rotation": R.tolist(), "translation": t.tolist()},
        "per_view": per_view,
    }


def similarity_of(record: dict) -> Similarity:
    """(s, R, t) from the ``similarity`` entry of a :func:`pose_error` record."""
    sim = record["similarity"]
    return float(sim["scale"]), np.asarray(sim["rotation"], float), np.asarray(sim["translation"], float)


def reprojection_stats(view: np.ndarray, uv_obs: np.ndarray, xyz: np.ndarray, ref: Cameras, sim: Similarity) -> dict:
    """Pixel error of points ``xyz`` (K, 3), mapped by ``sim`` into the reference world and projected
    with the reference cameras of views ``view`` (K,), against the keypoints ``uv_obs`` (K, 2) they
    were observed at.

    Returns observations (count), points behind a camera (excluded), median / mean / p90 error in
    pixels, and the mean signed residual (projected − observed; ~0 unless a convention slips).
    """
    s, R, t = sim
    X = s * xyz @ R.T + t
    uv = np.empty_like(uv_obs)
    z = np.empty(len(view))
    for v in np.unique(view):
        sel = view == v
        uv_v, z_v = project(ref.subset([v]), X[sel])
        uv[sel], z[sel] = uv_v[0], z_v[0]
    front = z > 0
    err = np.linalg.norm(uv - uv_obs, axis=1)[front]
    record = {"observations": int(front.sum()), "behind_camera": int((~front).sum())}
    if not front.any():
        return {**record, "median_px": None, "mean_px": None, "p90_px": None, "mean_residual_px": None}
    return {
        **record,
        "median_px": float(np.median(err)),
        "mean_px": float(err.mean()),
        "p90_px": float(np.percentile(err, 90)),
        "mean_residual_px": (uv - uv_obs)[front].mean(0).tolist(),
    }

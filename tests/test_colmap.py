"""COLMAP poses: alignment and error maths (spc3d.poses.alignment) on synthetic cameras, the pycolmap
conversions (spc3d.poses.colmap) on a synthetic reconstruction, and one real COLMAP run on fern
(skipped without data)."""

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from spc3d import io, llff
from spc3d.cameras import Cameras, invert_rigid, look_at, rotation_angle_deg, transform_cameras
from spc3d.poses import alignment, colmap

LLFF_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "llff"


def rot(axis, deg: float) -> np.ndarray:
    """Rotation matrix about ``axis`` by ``deg`` degrees (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def grid_cameras(n_x: int = 5, n_y: int = 4, seed: int = 0) -> Cameras:
    """Forward-facing cameras on a jittered grid in the z = 0 plane, all looking at (0, 0, 8)."""
    rng = np.random.default_rng(seed)
    xy = np.stack(np.meshgrid(np.linspace(-2, 2, n_x), np.linspace(-1.5, 1.5, n_y)), -1).reshape(-1, 2)
    centres = np.concatenate([xy, np.zeros((len(xy), 1))], 1) + rng.normal(0, 0.1, (len(xy), 3))
    targets = np.array([0.0, 0.0, 8.0]) + rng.normal(0, 0.3, (len(xy), 3))
    w2c = np.stack([look_at(c, t) for c, t in zip(centres, targets)])
    n = len(w2c)
    return Cameras(w2c, np.tile([100.0, 100.0, 64.0, 48.0], (n, 1)), 96, 128, np.tile([4.0, 12.0], (n, 1)))


def estimated(ref: Cameras, idx: np.ndarray, noise: float = 0.0, seed: int = 1) -> Cameras:
    """Views ``idx`` of ``ref`` in another world frame (known similarity), centres jittered."""
    s0, R0, t0 = 0.37, rot([1, 2, 3], 40.0), np.array([3.0, -1.0, 2.0])
    est = transform_cameras(ref.subset(idx), s0, R0, t0)
    if noise:
        c2w = est.c2w
        c2w[:, :, 3] += np.random.default_rng(seed).normal(0, noise, (len(idx), 3))
        est = Cameras(invert_rigid(c2w), est.intrinsics, est.height, est.width, est.bounds)
    return est


@pytest.mark.parametrize("align", alignment.ALIGNMENTS)
def test_pose_error_recovers_known_similarity(align):
    ref = grid_cameras()
    idx = np.arange(len(ref))
    rec = alignment.pose_error(ref, estimated(ref, idx), idx, align)
    assert rec["aligned"] and rec["registered"] == rec["total"] == len(ref)
    assert rec["rotation_deg"]["max"] < 1e-5 and rec["center_rel"]["max"] < 1e-9
    assert rec["scale"] == pytest.approx(1 / 0.37)
    json.dumps(rec, allow_nan=False)  # JSON-ready, no NaN


def test_pose_error_centre_noise_and_one_rotated_view():
    ref = grid_cameras()
    idx = np.array([0, 2, 3, 5, 7, 8, 11, 12, 14, 17, 19])  # a subset registered, unordered gaps
    spread = alignment.camera_spread(ref)
    est = estimated(ref, idx, noise=1e-3 * spread * 0.37)  # noise in the estimate's units
    rec = alignment.pose_error(ref, est, idx)
    assert rec["center_rel"]["median"] == pytest.approx(1.5e-3, rel=0.7)  # |N(0, 1e-3 I3)| ≈ 1.5e-3
    assert rec["rotation_deg"]["max"] < 0.05  # the rotation comes from orientations, noise-free here
    # rotate view 4 of the estimate by 3° about its own centre (centres unchanged)
    c2w = est.c2w
    c2w[4, :, :3] = rot([0.3, 1, 0.2], 3.0) @ c2w[4, :, :3]
    bent = Cameras(invert_rigid(c2w), est.intrinsics, est.height, est.width, est.bounds)
    by_centres = np.array(alignment.pose_error(ref, bent, idx, "centers")["per_view"]["rotation_deg"])
    # (a centre-only fit picks up a ~0.02° tilt from the 1e-3 centre noise: coplanar centres)
    assert by_centres[4] == pytest.approx(3.0, abs=0.05) and np.delete(by_centres, 4).max() < 0.05
    # fitted to the orientations, the world rotation absorbs 1/11 of it: 3·10/11 on view 4, 3/11 elsewhere
    rec = alignment.pose_error(ref, bent, idx)
    per_view = np.array(rec["per_view"]["rotation_deg"])
    assert per_view[4] == pytest.approx(3.0 * 10 / 11, abs=0.02)
    np.testing.assert_allclose(np.delete(per_view, 4), 3.0 / 11, atol=0.02)
    assert rec["per_view"]["index"] == idx.tolist()


def test_pose_error_too_few_registered_is_a_result_not_a_crash():
    ref = grid_cameras()
    for idx in ([], [3], [3, 9]):
        est = estimated(ref, np.array([3, 4, 5]))
        rec = alignment.pose_error(ref, est.subset(np.arange(len(idx))), idx)
        assert not rec["aligned"] and rec["registered"] == len(idx) and rec["total"] == len(ref)
        assert "at least 3" in rec["reason"]
        assert rec["rotation_deg"] is None and rec["center_rel"] is None and rec["scale"] is None
        json.dumps(rec, allow_nan=False)


def test_centre_only_alignment_is_ill_conditioned_for_coplanar_centres():
    """Why rotations drive the alignment: depth noise on coplanar centres tilts a centre-only fit."""
    ref = grid_cameras()
    idx = np.arange(len(ref))
    est = estimated(ref, idx)
    c2w = est.c2w
    c2w[:, :, 3] += 0.37 * 0.05 * np.random.default_rng(3).normal(0, 1, (len(idx), 3))
    est = Cameras(invert_rigid(c2w), est.intrinsics, est.height, est.width, est.bounds)
    by_centres = alignment.pose_error(ref, est, idx, "centers")["rotation_deg"]["median"]
    by_rotations = alignment.pose_error(ref, est, idx, "rotations")["rotation_deg"]["median"]
    assert by_rotations < 1e-5 < 0.5 < by_centres


def synthetic_reconstruction() -> pycolmap.Reconstruction:
    """A noise-free pycolmap reconstruction: 6 PINHOLE views, 50 points, exact keypoints."""
    opts = pycolmap.SyntheticDatasetOptions(
        num_rigs=1,
        num_cameras_per_rig=1,
        num_frames_per_rig=6,
        num_points3D=50,
        camera_width=320,
        camera_height=240,
        camera_model_id=pycolmap.CameraModelId.PINHOLE,
        camera_params=[300.0, 310.0, 160.0, 120.0],
    )
    pycolmap.set_random_seed(1)
    return pycolmap.synthesize_dataset(opts)


def test_reconstruction_cameras_and_reprojection_on_a_synthetic_reconstruction():
    rec = synthetic_reconstruction()
    names = sorted(Path(im.name).stem for im in rec.images.values())[::-1]  # any order: matched by stem
    like = Cameras(np.zeros((0, 3, 4)), np.zeros((0, 4)), 240, 320, np.zeros((0, 2)))
    est, idx = colmap.reconstruction_cameras(rec, names, like)
    assert idx.tolist() == list(range(6)) and (est.height, est.width) == (240, 320)
    np.testing.assert_allclose(est.intrinsics, np.tile([300.0, 310.0, 160.0, 120.0], (6, 1)))
    for k, i in enumerate(idx):
        image = rec.find_image_with_name(f"{names[i]}.png")
        np.testing.assert_allclose(est.centers[k], image.projection_center(), atol=1e-9)
    assert np.all(est.bounds[:, 0] > 0) and np.all(est.bounds[:, 1] >= est.bounds[:, 0])
    # the reference lives in another world frame; aligning and projecting must give back the keypoints
    s0, R0, t0 = 2.5, rot([0, 1, 1], 70.0), np.array([1.0, 2.0, -3.0])
    ref = transform_cameras(est, s0, R0, t0)
    pose = alignment.pose_error(ref, est, idx)
    assert pose["rotation_deg"]["max"] < 1e-5 and pose["center_rel"]["max"] < 1e-9
    proj = colmap.reprojection_error(rec, ref, names, alignment.similarity_of(pose))
    assert proj["observations"] == rec.compute_num_observations() and proj["behind_camera"] == 0
    assert proj["p90_px"] < 1e-6
    assert rotation_angle_deg(np.asarray(pose["similarity"]["rotation"]), R0) < 1e-5


def test_reconstruction_cameras_rejects_unknown_names():
    rec = synthetic_reconstruction()
    like = Cameras(np.zeros((0, 3, 4)), np.zeros((0, 4)), 240, 320, np.zeros((0, 2)))
    with pytest.raises(ValueError, match="matches no view name"):
        colmap.reconstruction_cameras(rec, ["view_a", "view_b"], like)


@pytest.mark.skipif(not (LLFF_ROOT / "fern" / "poses_bounds.npy").is_file(), reason="real LLFF data not available")
def test_colmap_poses_on_fern_agree_with_llff_poses(tmp_path):
    """COLMAP with the LLFF intrinsics on fern at 252x189 (20 views, ~8 s on 2 cores).

    Measured (pycolmap 4.2.1, seed 0, 1 thread): 20/20 registered, rotation median 0.16°,
    centre median 2.4 % of the spread, reprojection median 0.65 px, mean residual ~0.03 px.
    Thresholds: rotation 1° and centre 5 % leave ~2x margin over the scatter of independent SfM
    runs at this resolution (LLFF's poses come from COLMAP at 4032 px with a refined focal and
    radial distortion, ours from 252 px with the focal fixed); 1.5 px is ~2x the measured median
    (LLFF's distortion is not in poses_bounds); a 0.25 px bound on the mean signed residual
    catches a half-pixel convention slip, which the median alone could hide.
    """
    scene = llff.load_llff(LLFF_ROOT / "fern", 8, width=252)
    for name, image in zip(scene.names, scene.images):
        io.write_image(tmp_path / "images" / f"{name}.png", image)
    rec = colmap.colmap_poses(tmp_path / "images", scene.cameras, tmp_path / "colmap", names=scene.names)
    assert rec["status"] == "ok"
    assert rec["registered"] >= 0.9 * rec["total"]
    assert rec["pose"]["rotation_deg"]["median"] < 1.0
    assert rec["pose"]["center_rel"]["median"] < 0.05
    assert rec["reprojection"]["median_px"] < 1.5
    assert np.abs(rec["reprojection"]["mean_residual_px"]).max() < 0.25
    assert json.loads((tmp_path / "colmap" / "pose_error.json").read_text())["status"] == "ok"
    sparse = pycolmap.Reconstruction(tmp_path / "colmap" / "sparse" / "0")
    assert sparse.num_reg_images() == rec["registered"]
    np.testing.assert_allclose(next(iter(sparse.cameras.values())).params, scene.cameras.intrinsics[0])  # fixed
    assert not (tmp_path / "colmap" / "work").exists()


def test_colmap_poses_records_a_failure_on_binary_noise(tmp_path):
    """Nothing registers on random binary frames: a 'failed' record and no sparse model, not an error.

    Also exercises the canonical-scene-folder path (reference read with ``llff.read_scene``)."""
    rng = np.random.default_rng(0)
    cams = grid_cameras(3, 2).rescaled(48, 64)
    names = [f"view{i:02d}" for i in range(len(cams))]
    llff.write_scene(tmp_path / "scene", llff.SceneData(rng.random((len(cams), 48, 64, 3)), cams, names), {})
    for name in names[:5]:  # one view without an image: left out of the total
        io.write_image(tmp_path / "frames" / f"{name}.png", (rng.random((48, 64, 1)) < 0.5).astype(np.float32))
    rec = colmap.colmap_poses(tmp_path / "frames", tmp_path / "scene", tmp_path / "out")
    assert rec["status"].startswith("failed: ") and rec["registered"] < 3 and rec["total"] == 5
    saved = json.loads((tmp_path / "out" / "pose_error.json").read_text(), parse_constant=pytest.fail)  # no NaN
    assert saved["status"] == rec["status"] and saved["reference"] == str(tmp_path / "scene")
    assert (tmp_path / "out" / "colmap.log").stat().st_size > 0
    assert not (tmp_path / "out" / "sparse").exists() and not (tmp_path / "out" / "work").exists()

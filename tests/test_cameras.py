"""Camera conventions: LLFF <-> internal round trips, projection, similarity alignment."""

import numpy as np
import pytest

from spc3d import cameras as C


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def grid_cameras(n=12, seed=0):
    rng = np.random.default_rng(seed)
    centers = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), np.zeros(n)], 1)
    w2c = np.stack([C.look_at(c, np.array([0.0, 0.0, 4.0])) for c in centers])
    intr = np.tile([100.0, 100.0, 64.0, 48.0], (n, 1))
    return C.Cameras(w2c, intr, 96, 128, np.tile([1.0, 8.0], (n, 1)))


def test_llff_round_trip():
    cams = grid_cameras()
    pb = C.cameras_to_llff(cams)
    assert pb.shape == (12, 17)
    back = C.llff_to_cameras(pb)
    np.testing.assert_allclose(back.w2c, cams.w2c, atol=1e-12)
    np.testing.assert_allclose(back.intrinsics, cams.intrinsics)
    np.testing.assert_allclose(C.cameras_to_llff(back), pb, atol=1e-12)


def test_llff_columns_are_down_right_back():
    cams = grid_cameras(1)
    pose = C.cameras_to_llff(cams)[0, :15].reshape(3, 5)
    R_c2w = cams.c2w[0, :, :3]  # columns: right, down, forward in world coordinates
    np.testing.assert_allclose(pose[:, 0], R_c2w[:, 1])  # down
    np.testing.assert_allclose(pose[:, 1], R_c2w[:, 0])  # right
    np.testing.assert_allclose(pose[:, 2], -R_c2w[:, 2])  # back
    np.testing.assert_allclose(pose[:, 4], [96, 128, 100])  # h, w, f


def test_llff_focal_rescaled_to_loaded_images():
    pb = C.cameras_to_llff(grid_cameras())  # hwf for 96 x 128
    half = C.llff_to_cameras(pb, 48, 64)
    np.testing.assert_allclose(half.intrinsics[0], [50, 50, 32, 24])


def test_look_at_points_forward_and_upright():
    w2c = C.look_at(np.zeros(3), np.array([0.0, 0.0, 5.0]))
    np.testing.assert_allclose(w2c[:, :3], np.eye(3), atol=1e-12)  # world y down == image y down
    uv, z = C.project(
        C.Cameras(w2c[None], np.array([[10.0, 10, 8, 6]]), 12, 16, np.ones((1, 2))),
        np.array([[0.0, 0.0, 5.0], [0.0, -1.0, 5.0]]),
    )
    np.testing.assert_allclose(uv[0, 0], [8, 6])  # the target lands on the image centre
    assert uv[0, 1, 1] < 6 and z[0, 1] == 5.0  # world "up" (-y) projects above the centre


def test_projection_matches_intrinsics():
    cams = grid_cameras()
    rng = np.random.default_rng(1)
    pts = rng.uniform([-1, -1, 3], [1, 1, 6], (50, 3))
    uv, z = C.project(cams, pts)
    Xc = np.einsum("nij,mj->nmi", cams.w2c[:, :, :3], pts) + cams.w2c[:, None, :, 3]
    np.testing.assert_allclose(uv[..., 0], 100 * Xc[..., 0] / Xc[..., 2] + 64)
    np.testing.assert_allclose(z, Xc[..., 2])


def test_invert_rigid():
    rng = np.random.default_rng(2)
    T = np.concatenate([random_rotation(rng), rng.normal(size=(3, 1))], 1)
    Ti = C.invert_rigid(T)
    np.testing.assert_allclose(C.invert_rigid(Ti), T, atol=1e-12)
    x = rng.normal(size=3)
    np.testing.assert_allclose(Ti[:, :3] @ (T[:, :3] @ x + T[:, 3]) + Ti[:, 3], x, atol=1e-12)


def test_umeyama_recovers_similarity_and_transform_cameras():
    rng = np.random.default_rng(3)
    cams = grid_cameras()
    s, R, t = 2.5, random_rotation(rng), rng.normal(size=3)
    moved = C.transform_cameras(cams, s, R, t)
    s2, R2, t2 = C.umeyama(cams.centers, moved.centers)
    assert s2 == pytest.approx(s) and np.allclose(R2, R) and np.allclose(t2, t)
    # The same world points project to the same pixels in the transformed world.
    pts = rng.uniform([-1, -1, 3], [1, 1, 6], (20, 3))
    uv, _ = C.project(cams, pts)
    uv2, _ = C.project(moved, (s * (R @ pts.T)).T + t)
    np.testing.assert_allclose(uv2, uv, atol=1e-9)
    # Rotation errors of the aligned cameras vanish.
    ang = C.rotation_angle_deg(moved.w2c[:, :, :3] @ R, cams.w2c[:, :, :3])
    assert ang.max() < 1e-5


def test_rotation_angle():
    def Rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    assert C.rotation_angle_deg(np.eye(3), Rz(np.radians(7.0))) == pytest.approx(7.0)
    assert C.rotation_angle_deg(np.eye(3), np.eye(3)) == 0.0


def test_split_views_every_eighth():
    train, test = C.split_views(20)
    assert list(test) == [0, 8, 16]
    assert len(train) == 17 and not set(train) & set(test)
    with pytest.raises(ValueError, match="at least 2"):
        C.split_views(1)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"\(N, 17\)"):
        C.llff_to_cameras(np.zeros((3, 15)))
    with pytest.raises(ValueError, match="coincide"):
        C.umeyama(np.zeros((4, 3)), np.ones((4, 3)))


def test_look_at_rejects_degenerate_directions():
    with pytest.raises(ValueError, match="parallel"):
        C.look_at(np.zeros(3), np.array([0.0, 5.0, 0.0]))
    with pytest.raises(ValueError, match="centre == target"):
        C.look_at(np.ones(3), np.ones(3))

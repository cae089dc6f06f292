"""LLFF reading: real folders, focal rescaling, area downscaling, bad input, canonical round trip."""

import shutil

import numpy as np
import pytest

from spc3d import cameras, llff

from conftest import LLFF_SCENES, llff_scene


def test_area_matrix_integer_factor_is_block_mean():
    A = llff.area_matrix(8, 2)
    np.testing.assert_allclose(A, np.kron(np.eye(2), np.full((1, 4), 0.25)))


def test_area_matrix_any_ratio_preserves_mean():
    A = llff.area_matrix(13, 5)
    np.testing.assert_allclose(A.sum(1), 1.0)
    x = np.random.default_rng(0).random(13)
    assert (A @ x).mean() == pytest.approx(x.mean(), rel=1e-12)  # equal-width bins: mean kept


@pytest.mark.parametrize("name", LLFF_SCENES)
def test_real_llff_scene_loads(name):
    root = llff_scene(name)
    scene = llff.load_llff(root, factor=8)
    pb = np.load(root / "poses_bounds.npy")
    n, h, w, _ = scene.images.shape
    assert n == len(pb) == len(scene.names) and scene.images.dtype == np.float32
    assert (scene.cameras.height, scene.cameras.width) == (h, w)
    f_full, w_full = pb[0, 14], pb[0, 9]
    assert scene.cameras.intrinsics[0, 0] == pytest.approx(f_full * w / w_full)
    # Forward-facing capture: every camera looks roughly the same way, scene in front.
    fwd = scene.cameras.c2w[:, :, 2]
    assert (fwd @ fwd.mean(0) / np.linalg.norm(fwd.mean(0)) > 0.9).all()
    assert (scene.cameras.bounds[:, 0] < scene.cameras.bounds[:, 1]).all()


def test_real_llff_downscaled_with_area_filter(fern):
    full = llff.load_llff(fern, factor=8)
    small = llff.load_llff(fern, factor=8, width=252)  # 504 x 378 -> 252 x 189: exactly factor 2
    assert small.images.shape[1:3] == (189, 252)
    block = full.images[0, 2:4, 6:8].mean(axis=(0, 1))
    np.testing.assert_allclose(small.images[0, 1, 3], block, atol=1e-6)
    assert small.cameras.intrinsics[0, 0] == pytest.approx(full.cameras.intrinsics[0, 0] / 2)
    np.testing.assert_allclose(small.cameras.intrinsics[0, 2:], [126.0, 94.5])


def make_llff_copy(src, dst, n_images=None):
    shutil.copytree(src / "images_8", dst / "images_8")
    shutil.copy(src / "poses_bounds.npy", dst / "poses_bounds.npy")
    if n_images is not None:
        for p in sorted((dst / "images_8").iterdir())[n_images:]:
            p.unlink()
    return dst


def test_count_mismatch_names_both_files(fern, tmp_path):
    root = make_llff_copy(fern, tmp_path / "fern", n_images=5)
    with pytest.raises(ValueError, match=r"images_8 holds 5 images but .*poses_bounds.npy has 20 poses"):
        llff.load_llff(root, 8)


def test_missing_folders_are_named(fern, tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        llff.load_llff(tmp_path / "nope", 8)
    with pytest.raises(FileNotFoundError, match=r"images_4 does not exist.*images_8"):
        llff.load_llff(fern, 4)
    root = make_llff_copy(fern, tmp_path / "f")
    (root / "poses_bounds.npy").unlink()
    with pytest.raises(FileNotFoundError, match="poses_bounds.npy"):
        llff.load_llff(root, 8)


def test_unreadable_image_is_named(fern, tmp_path):
    root = make_llff_copy(fern, tmp_path / "fern")
    (root / "images_8" / "image003.png").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="image003.png"):
        llff.load_llff(root, 8)


def test_canonical_scene_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    w2c = np.stack([cameras.look_at(np.array([x, 0.0, 0.0]), np.array([0.0, 0.0, 5.0])) for x in (-0.2, 0.0, 0.2)])
    cams = cameras.Cameras(w2c, np.tile([40.0, 40.0, 16.0, 12.0], (3, 1)), 24, 32, np.tile([1.0, 9.0], (3, 1)))
    scene = llff.SceneData(
        rng.random((3, 24, 32, 3)).astype(np.float32),
        cams,
        ["a", "b", "c"],
        rng.uniform(1, 9, (3, 24, 32)).astype(np.float32),
        {"layout": "test"},
    )
    llff.write_scene(tmp_path / "s", scene, {"seed": 3})
    back = llff.read_scene(tmp_path / "s", with_depth=True)
    assert back.names == ["a", "b", "c"] and back.meta["seed"] == 3 and back.meta["layout"] == "test"
    np.testing.assert_allclose(back.images, scene.images, atol=0.5 / 255 + 1e-6)
    np.testing.assert_array_equal(back.depths, scene.depths)
    np.testing.assert_allclose(back.cameras.w2c, cams.w2c, atol=1e-9)
    np.testing.assert_allclose(back.cameras.intrinsics, cams.intrinsics)
    assert np.load(tmp_path / "s" / "poses_bounds.npy").shape == (3, 17)


def test_depth_is_resampled_not_blended():
    depth = np.where(np.arange(8)[None, None, :] < 4, 1.0, 9.0) * np.ones((1, 6, 8))  # an occlusion edge
    scene = llff.SceneData(np.zeros((1, 6, 8, 3), np.float32), None, ["a"], depth.astype(np.float32))
    scene.cameras = cameras.Cameras(np.zeros((1, 3, 4)), np.array([[8.0, 8, 4, 3]]), 6, 8, np.ones((1, 2)))
    small = llff.resize_scene(scene, 3)
    assert set(np.unique(small.depths)) <= {1.0, 9.0}  # only depths of real surfaces
    assert small.depths.shape == (1, 2, 3)

"""Augmentation: the affine maps, determinism, pixel-aligned (RGB, binary) pairs, bad settings."""

import numpy as np
import pytest

from spc3d import cameras, io, llff
from spc3d.inputs import augment
from spc3d.inputs.build import simulate_scene
from spc3d.physics import spc
from spc3d.specs.translators import split_count

IDENTITY = {"zoom": 1.0, "rotation_deg": 0.0, "shear_deg": 0.0, "flip": False}


def test_identity_parameters_keep_the_image():
    img = np.random.default_rng(0).random((12, 16, 3)).astype(np.float32)
    np.testing.assert_allclose(augment.affine_matrix(IDENTITY, 12, 16), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(augment.augment_image(img, IDENTITY), img, atol=2e-6)


def test_flip_mirrors_columns():
    img = np.random.default_rng(1).random((6, 10, 3)).astype(np.float32)
    out = augment.augment_image(img, IDENTITY | {"flip": True})
    np.testing.assert_allclose(out, img[:, ::-1], atol=2e-6)


def test_zoom_and_rotation_keep_the_centre_fixed():
    A = augment.affine_matrix({"zoom": 1.2, "rotation_deg": 10.0, "shear_deg": 5.0, "flip": True}, 48, 64)
    np.testing.assert_allclose(A @ [31.5, 23.5, 1.0], [31.5, 23.5, 1.0], atol=1e-9)
    # Zoom by s scales distances from the centre by s (no rotation/shear).
    Z = augment.affine_matrix(IDENTITY | {"zoom": 1.5}, 48, 64)
    np.testing.assert_allclose(Z @ [41.5, 23.5, 1.0], [46.5, 23.5, 1.0])


def test_sampled_parameters_respect_ranges():
    s = augment.AugmentSettings(zoom=(0.9, 1.1), rotation_deg=5, shear_deg=2, flip_prob=0.0)
    rng = np.random.default_rng(2)
    draws = [augment.sample_params(rng, s) for _ in range(200)]
    assert all(
        0.9 <= d["zoom"] <= 1.1 and abs(d["rotation_deg"]) <= 5 and abs(d["shear_deg"]) <= 2 and not d["flip"]
        for d in draws
    )


def test_split_count_sums_to_total():
    assert [split_count(10, 3, i) for i in range(3)] == [4, 3, 3]
    assert sum(split_count(15000, 7, i) for i in range(7)) == 15000


@pytest.mark.parametrize(
    "kwargs,match",
    [({"zoom": (1.2, 0.8)}, "zoom"), ({"flip_prob": 1.5}, "flip_prob"), ({"rotation_deg": -1}, "rotation_deg")],
)
def test_bad_settings_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        augment.AugmentSettings(**kwargs)


@pytest.fixture
def tiny_scene(tmp_path):
    """A 3-view scene of smooth gradients, written canonically, with its SPC frames."""
    yy, xx = np.mgrid[0:24, 0:32] / np.array([24.0, 32.0])[:, None, None]
    images = np.stack([np.stack([xx, yy, 0.5 * (xx + yy)], -1) * (0.6 + 0.2 * i) for i in range(3)]).astype(np.float32)
    w2c = np.stack([cameras.look_at(np.array([0.1 * i, 0.0, 0.0]), np.array([0.0, 0.0, 4.0])) for i in range(3)])
    cams = cameras.Cameras(w2c, np.tile([30.0, 30.0, 16.0, 12.0], (3, 1)), 24, 32, np.tile([1.0, 8.0], (3, 1)))
    llff.write_scene(tmp_path / "scene", llff.SceneData(images, cams, ["v0", "v1", "v2"]), {"seed": 0})
    simulate_scene(tmp_path / "scene", tmp_path / "spc", spc.SPCParams(frames=64), seed=0)
    return tmp_path


def test_augmented_pairs_are_aligned_and_deterministic(tiny_scene):
    s = augment.AugmentSettings()
    rec = augment.augment_scene(tiny_scene / "scene", tiny_scene / "spc", tiny_scene / "aug", 3, s, seed=7)
    assert len(rec["samples"]) == 3 and rec["flux_scale"] == io.read_json(tiny_scene / "spc" / "spc.json")["flux_scale"]
    for i in range(3):
        rgb = io.read_rgb(tiny_scene / "aug" / "rgb" / f"{i:05d}.png")
        frames = spc.unpack_frames(*io.load_frames(tiny_scene / "aug" / "frames" / f"{i:05d}.npz"))
        assert frames.shape == (64,) + rgb.shape
        # Pixel-aligned: the 64-frame detection rate follows the RGB image's own detection probability.
        p = spc.detection_probability(spc.flux_from_srgb(rgb, rec["flux_scale"]), spc.SPCParams(frames=64))
        assert np.corrcoef(frames.mean(0).ravel(), p.ravel())[0, 1] > 0.9
        np.testing.assert_array_equal(io.read_rgb(tiny_scene / "aug" / "binary" / f"{i:05d}.png") > 0.5, frames[0])
    again = augment.augment_scene(tiny_scene / "scene", tiny_scene / "spc", tiny_scene / "aug2", 3, s, seed=7)
    assert again["samples"] == rec["samples"]
    assert np.array_equal(
        io.load_frames(tiny_scene / "aug" / "frames" / "00001.npz")[0],
        io.load_frames(tiny_scene / "aug2" / "frames" / "00001.npz")[0],
    )

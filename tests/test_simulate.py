"""Scene-level SPC simulation: calibrated exposure, consistent products, determinism, records."""

import numpy as np
import pytest

from spc3d import io
from spc3d.evaluation.metrics import psnr
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene") / "courtyard"
    write_builtin_scene("courtyard", out, height=24, width=32, views=3, supersample=1, seed=0)
    return out


def _mle_srgb(S: np.ndarray, K: int, flux_scale: float, params: spc.SPCParams) -> np.ndarray:
    """Reference estimate of the scene's sRGB image from S ones among K frames: the MLE flux at the
    exact gain (clipped to [0, 1] linear), against which the simulated frames are checked."""
    return spc.linear_to_srgb(np.clip(spc.mle_flux(S, K, params) / flux_scale, 0.0, 1.0))


def test_calibrated_scene_products(scene_dir, tmp_path):
    params = spc.SPCParams(frames=32)
    rec = simulate_scene(scene_dir, tmp_path / "spc", params, target_detection=0.4, seed=5)
    assert rec["flux_scale_calibrated"] and rec["seed"] == 5 and rec["views"] == 3
    assert rec["mean_detection_rate"] == pytest.approx(0.4, abs=0.03)  # the calibration target
    name = "image001"
    frames = spc.unpack_frames(*io.load_frames(tmp_path / "spc" / "frames" / f"{name}.npz"))
    assert frames.shape == (32, 24, 32, 3)
    S = frames.sum(0)
    np.testing.assert_array_equal(io.read_rgb(tmp_path / "spc" / "binary" / f"{name}.png") > 0.5, frames[0])
    np.testing.assert_allclose(io.read_rgb(tmp_path / "spc" / "average" / f"{name}.png"), S / 32, atol=1e-4)
    np.testing.assert_allclose(
        io.read_image(tmp_path / "spc" / "mle" / f"{name}.exr"), spc.mle_flux(S, 32, params), rtol=1e-6
    )
    # 32 frames recover the image far better than one binary frame does (shown at the exact gain here;
    # the table rows meter theirs: spc3d.inputs.exposure). No display image that used the exact gain is written.
    gt = io.read_rgb(scene_dir / "images" / f"{name}.png")
    mle = _mle_srgb(S, 32, rec["flux_scale"], params)
    assert psnr(mle, gt) > psnr(frames[0].astype(float), gt) + 5
    folders = ["average", "binary", "capture", "frames", "mle", "spc.json"]
    assert sorted(p.name for p in (tmp_path / "spc").iterdir()) == folders
    assert rec["mean_mle_psnr_exact_gain_db"] > 20


def test_same_seed_same_bits_given_flux(scene_dir, tmp_path):
    params = spc.SPCParams(frames=2, mode="paper")
    a = simulate_scene(scene_dir, tmp_path / "a", params, flux_scale=2e4, seed=1)
    simulate_scene(scene_dir, tmp_path / "b", params, flux_scale=2e4, seed=1)
    simulate_scene(scene_dir, tmp_path / "c", params, flux_scale=2e4, seed=2)
    assert a["flux_scale"] == 2e4 and not a["flux_scale_calibrated"]

    def bits(d):
        return io.load_frames(tmp_path / d / "frames" / "image000.npz")[0]

    assert np.array_equal(bits("a"), bits("b")) and not np.array_equal(bits("a"), bits("c"))


def test_bad_flux_scale_is_named(scene_dir, tmp_path):
    with pytest.raises(ValueError, match="spc.flux_scale=-1"):
        simulate_scene(scene_dir, tmp_path / "x", spc.SPCParams(), flux_scale=-1.0)
    assert not (tmp_path / "x").exists()  # nothing half-written


def test_psnr_identical_is_inf():
    img = np.full((4, 4, 3), 0.5)
    assert psnr(img, img) == float("inf")
    assert psnr(img, img + 0.1) == pytest.approx(20.0)


def test_frames_without_an_image_are_warned_in_spc_json_and_named_in_the_tables(scene_dir, tmp_path):
    """An overexposed (fixed flux far above the scene) and a starved scene say so in spc.json, and
    the paper tables' captions name them; a calibrated scene says nothing."""
    from spc3d.evaluation.tables import photon_note

    params = spc.SPCParams(frames=2)
    bright = simulate_scene(scene_dir, tmp_path / "bright", params, flux_scale=1e10, seed=0)
    dark = simulate_scene(scene_dir, tmp_path / "dark", params, flux_scale=1.0, seed=0)
    fine = simulate_scene(scene_dir, tmp_path / "fine", params, target_detection=0.5, seed=0)
    assert bright["warnings"] == [
        f"frames almost all 1 (mean detection {bright['mean_detection_rate']:.4f}): overexposed"
    ]
    assert dark["warnings"][0].startswith("frames almost all dark") and fine["warnings"] == []
    assert io.read_json(tmp_path / "bright" / "spc.json")["warnings"] == bright["warnings"]
    note = photon_note([tmp_path / "bright", tmp_path / "fine", tmp_path / "dark"])
    assert "bright: frames almost all 1" in note and "dark: frames almost all dark" in note and "fine" not in note
    assert photon_note([tmp_path / "fine"]) == ""


def test_frame_warning_thresholds():
    from spc3d.physics.record import frame_warnings

    assert frame_warnings(0.5, 0.01) == []
    assert "overexposed" in frame_warnings(0.995, 0.01)[0]
    assert "underexposed" in frame_warnings(0.015, 0.01)[0] and frame_warnings(0.03, 0.01) == []
    assert frame_warnings(0.5, 0.01, saturated_pixels=0.6) == ["60% of the pixels fired in every frame (saturated)"]

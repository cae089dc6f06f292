"""The capture-resolution binary frame (spc3d.inputs.build.capture_frame): one frame simulated at S x the
working resolution per axis and area-averaged back, as the paper's single-stage baselines most
plausibly saw it; its 16-bit storage, its seeding, a capture's S = 1 frame and its MLE display."""

import numpy as np
import pytest

from spc3d import io
from spc3d.captures import folders as captures
from spc3d.captures.importing import import_capture_frames, import_capture_scene
from spc3d.inputs import exposure
from spc3d.inputs.build import capture_frame, capture_rng, simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import sensors, spc
from spc3d.physics.flux_scale import frame_probability
from spc3d.physics.record import (
    MAX_CAPTURE_FACTOR,
    check_capture_factor,
    params_from_record,
    read_spc_record,
    spc_sensor,
)

H, W, VIEWS = 12, 16, 3


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("capture_frame")
    write_builtin_scene("tabletop", root / "tabletop", height=H, width=W, views=VIEWS, supersample=1, seed=0)
    return root / "tabletop"


def simulated(scene, out, S, seed=0, frames=2):
    return simulate_scene(scene, out, spc.SPCParams(frames=frames), seed=seed, capture_factor=S)


def frames_of(spc_dir, name):
    return spc.unpack_frames(*io.load_frames(spc_dir / "frames" / f"{name}.npz"))


@pytest.mark.parametrize("mode", spc.MODES)
def test_capture_fraction_has_the_binomial_mean_and_variance(mode):
    """A constant image: each pixel's fraction is Binomial(S², p) / S² with p the frame's detection
    probability (Monte Carlo over 64 x 64 x 3 values, S = 4)."""
    params, S, scale = spc.SPCParams(mode=mode), 4, 7e4  # p ~ 1/2
    srgb = np.full((64, 64, 3), 0.5, np.float32)
    frac = capture_frame(srgb, scale, params, S, np.random.default_rng(1))
    assert frac.shape == srgb.shape and frac.dtype == np.float32
    frac = frac.astype(np.float64)
    p = float(frame_probability(spc.flux_from_srgb(np.float64(0.5), scale), params))
    assert 0.2 < p < 0.8  # a rate where both the mean and the spread say something
    n = frac.size
    assert abs(frac.mean() - p) < 4 * np.sqrt(p * (1 - p) / S**2 / n)
    assert frac.var() == pytest.approx(p * (1 - p) / S**2, rel=0.1)
    np.testing.assert_array_equal(np.rint(frac * S * S) / (S * S), frac)  # fractions k / S²


@pytest.mark.parametrize("S", [1, 2, 3, 4, 16, MAX_CAPTURE_FACTOR])
def test_sixteen_bit_round_trip_is_exact(tmp_path, S):
    k = np.arange(S * S + 1)
    io.write_image(tmp_path / "k.png", (k / (S * S)).astype(np.float32)[None, :, None], bits=16)
    back = io.read_image(tmp_path / "k.png")[0, :, 0]
    np.testing.assert_array_equal(np.rint(back.astype(np.float64) * S * S), k)


def test_one_past_the_largest_factor_would_not_round_trip(tmp_path):
    S = MAX_CAPTURE_FACTOR + 1  # S² + 1 fractions cannot fit 65536 codes distinctly
    k = np.arange(S * S + 1)
    io.write_image(tmp_path / "k.png", (k / (S * S)).astype(np.float32)[None, :, None], bits=16)
    assert not np.array_equal(np.rint(io.read_image(tmp_path / "k.png")[0, :, 0].astype(np.float64) * S * S), k)


@pytest.mark.parametrize("bad", [0, -1, MAX_CAPTURE_FACTOR + 1, 2.5, True, "2", None])
def test_bad_capture_factors_are_named(scene, tmp_path, bad):
    with pytest.raises(ValueError, match=r"capture_factor"):
        check_capture_factor(bad)
    with pytest.raises(ValueError, match=r"spc.capture_factor"):
        simulated(scene, tmp_path / "spc", bad)
    assert not (tmp_path / "spc").exists()


def test_factor_one_is_frame_zero(scene, tmp_path):
    rec = simulated(scene, tmp_path / "spc", 1)
    assert rec["capture_factor"] == 1
    for name in ("image000", "image001"):
        capture = io.read_rgb(tmp_path / "spc" / "capture" / f"{name}.png")
        np.testing.assert_array_equal(capture, frames_of(tmp_path / "spc", name)[0].astype(np.float32))


def test_capture_frame_is_seeded_and_apart_from_the_main_frames(scene, tmp_path):
    a, b, c, one = (tmp_path / n for n in ("a", "b", "c", "one"))
    rec = simulated(scene, a, 4)
    simulated(scene, b, 4)
    simulated(scene, c, 4, seed=1)
    simulated(scene, one, 1)
    assert rec["capture_factor"] == 4 and io.read_json(a / "spc.json")["capture_factor"] == 4
    name = "image001"
    read = {d: io.read_rgb(d / "capture" / f"{name}.png") for d in (a, b, c)}
    np.testing.assert_array_equal(read[a], read[b])  # deterministic per seed
    assert not np.array_equal(read[a], read[c])
    assert np.abs(read[a] * 16 - np.rint(read[a] * 16)).max() < 1e-3  # k / S² to 16 bits
    for view in ("image000", "image001", "image002"):  # drawing it leaves the main frames' stream alone
        np.testing.assert_array_equal(frames_of(a, view), frames_of(one, view))
    # independent of the main frames: at a constant image, frame 0 and the capture frame are uncorrelated
    srgb, params = np.full((64, 64, 3), 0.5, np.float32), spc.SPCParams()
    frame0 = spc.simulate_frames(srgb, 2e4, params, spc.view_rng(0, "s", 0))[0].ravel()
    frac = capture_frame(srgb, 2e4, params, 4, capture_rng(0, "s", 0)).ravel()
    assert abs(np.corrcoef(frame0, frac)[0, 1]) < 4 / np.sqrt(frac.size)


def test_large_factors_draw_in_bands_and_extreme_flux_is_finite():
    params = spc.SPCParams()
    srgb = np.random.default_rng(0).random((6, 8, 3)).astype(np.float32)
    frac = capture_frame(srgb, 2e4, params, 64, np.random.default_rng(0))  # 384 x 512 sub-pixels, 3 bands
    assert frac.shape == (6, 8, 3) and np.isfinite(frac).all() and 0 <= frac.min() and frac.max() <= 1
    for scale in (0.0, 1e300):
        frac = capture_frame(srgb, scale, params, 4, np.random.default_rng(0))
        assert np.isfinite(frac).all()
        phi = spc.mle_flux(np.rint(frac * 16).astype(np.int64), 16, params)
        assert np.isfinite(phi).all() and (phi >= 0).all()
    assert capture_frame(np.ones((2, 2, 3), np.float32), 1e300, params, 4, np.random.default_rng(0)).min() == 1.0


def test_capture_mle_reads_k_of_s_squared_and_stays_finite(scene, tmp_path):
    spc_dir, S = tmp_path / "spc", 4
    rec = simulated(scene, spc_dir, S)
    params = spc.SPCParams(**rec["params"])
    io.write_image(spc_dir / "capture" / "image001.png", np.ones((H, W, 3), np.float32), bits=16)  # all ones
    io.write_image(spc_dir / "capture" / "image002.png", np.zeros((H, W, 3), np.float32), bits=16)  # all zeros
    names, phi = exposure.mle_views(spc_dir, 1, capture=True)
    assert names == ["image000", "image001", "image002"] and np.isfinite(phi).all()
    k = np.rint(io.read_rgb(spc_dir / "capture" / "image000.png").astype(np.float64) * S * S)
    np.testing.assert_allclose(phi[0], spc.mle_flux(k, S * S, params), rtol=1e-6)
    np.testing.assert_allclose(phi[1], spc.mle_flux(np.array(S * S), S * S, params), rtol=1e-6)  # the ln(2S²) clamp
    assert (phi[2] == 0).all()
    with pytest.raises(ValueError, match="K must be 1"):
        exposure.mle_views(spc_dir, 2, capture=True)


def test_capture_display_records_its_factor_and_refuses_another(scene, tmp_path):
    spc_dir = tmp_path / "spc"
    simulated(scene, spc_dir, 2)
    cal = exposure.calibrate_display([scene], [spc_dir], 1, tmp_path / "cal-capture.json", capture=True)
    assert cal["capture_factor"] == 2 and cal["K"] == 1
    rec = exposure.write_display(spc_dir, tmp_path / "cal-capture.json", 1, tmp_path / "display", capture=True)
    assert rec["capture_factor"] == 2 and rec["views"] == VIEWS and rec["gain"] == cal["level"] * rec["flux_per_linear"]
    assert len(list((tmp_path / "display" / "images").glob("*.png"))) == VIEWS
    exposure.calibrate_display([scene], [spc_dir], 1, tmp_path / "cal-k1.json")
    with pytest.raises(ValueError, match=r"capture_factor = 1.*capture_factor = 2"):
        exposure.write_display(spc_dir, tmp_path / "cal-k1.json", 1, tmp_path / "bad", capture=True)
    with pytest.raises(ValueError, match=r"capture_factor = 2.*capture_factor = 1"):
        exposure.write_display(spc_dir, tmp_path / "cal-capture.json", 1, tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_a_captured_scene_has_its_frame_zero_as_capture_frame(scene, tmp_path):
    simulated(scene, tmp_path / "spc", 1, frames=4)
    captures.export_simulated(tmp_path / "spc", tmp_path / "cap", "RGGB", "npz", scene_dir=scene)
    import_capture_scene(tmp_path / "cap", tmp_path / "cap_scene")
    rec = import_capture_frames(tmp_path / "cap", tmp_path / "cap_scene", tmp_path / "cap_spc")
    assert rec["capture_factor"] == 1 and rec["held_out_views"] == ["image000"]
    for name in ("image000", "image001"):
        capture = io.read_rgb(tmp_path / "cap_spc" / "capture" / f"{name}.png")
        np.testing.assert_allclose(capture, io.read_rgb(tmp_path / "cap_spc" / "binary" / f"{name}.png"), atol=1 / 255)
    names, phi = exposure.mle_views(tmp_path / "cap_spc", 1, capture=True)
    np.testing.assert_array_equal(phi, exposure.mle_views(tmp_path / "cap_spc", 1)[1])  # S = 1: frame 0's MLE
    pattern, valid = spc_sensor(tmp_path / "cap_spc")  # a Bayer mosaic: demosaiced, not read as RGB bits
    params = params_from_record(read_spc_record(tmp_path / "cap_spc"))
    for name, view in zip(names, phi):
        counts = frames_of(tmp_path / "cap_spc", name)[:1].sum(0, dtype=np.int64)
        np.testing.assert_array_equal(view, sensors.mle_rgb(counts, 1, params, pattern, ~valid).astype(np.float32))
        assert counts.shape == (H, W) and view.shape == (H, W, 3)  # one bit per pixel; R, G and B shown

"""The display level (spc3d.inputs.exposure): the MLE views a display reads, the preview's average
metering, the error the level is fitted on, and what a display records.

A simulated scene with K = 3 frames and a capture frame at S = 2 stands for every SPC folder; the
expected values are computed here from the frames on disk with the physics module's own MLE.
"""

from __future__ import annotations

import re
import shutil
import time

import numpy as np
import pytest

from spc3d import io
from spc3d.inputs import exposure
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc
from spc3d.physics.record import params_from_record, read_spc_record

H, W, VIEWS = 12, 16, 3


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("exposure")
    write_builtin_scene("tabletop", root / "scene", height=H, width=W, views=VIEWS, supersample=1, seed=0)
    simulate_scene(root / "scene", root / "spc", spc.SPCParams(frames=3), seed=0, capture_factor=2)
    return root


def params(spc_dir):
    return params_from_record(read_spc_record(spc_dir))


def test_mle_views_read_the_first_k_frames_of_every_view(folders):
    names, phi = exposure.mle_views(folders / "spc", 2)
    assert names == sorted(names) and len(names) == VIEWS and phi.shape == (VIEWS, H, W, 3)
    for name, view in zip(names, phi):
        frames = spc.unpack_frames(*io.load_frames(folders / "spc" / "frames" / f"{name}.npz"))
        expected = spc.mle_flux(frames[:2].sum(0, dtype=np.int64), 2, params(folders / "spc"))
        np.testing.assert_array_equal(view, expected.astype(np.float32))


def test_the_capture_frame_is_read_as_k_ones_of_s_squared_trials(folders):
    assert exposure.capture_factor(folders / "spc") == 2
    names, phi = exposure.mle_views(folders / "spc", 1, capture=True)
    counts = np.rint(io.read_rgb(folders / "spc" / "capture" / f"{names[0]}.png") * 4).astype(np.int64)
    np.testing.assert_array_equal(phi[0], spc.mle_flux(counts, 4, params(folders / "spc")).astype(np.float32))
    assert not np.array_equal(phi[0], exposure.mle_views(folders / "spc", 1)[1][0])  # not frame 0


def test_mle_views_refuse_naming_what_is_wrong(folders, tmp_path):
    spc_dir = folders / "spc"
    with pytest.raises(ValueError, match=r"^capture=True meters the one capture-resolution frame per view: K must"):
        exposure.mle_views(spc_dir, 2, capture=True)
    with pytest.raises(ValueError, match=rf"^K = 4 frames asked of {re.escape(str(spc_dir))}, which stores K = 3"):
        exposure.mle_views(spc_dir, 4)
    empty = tmp_path / "spc"
    shutil.copytree(spc_dir, empty)
    shutil.rmtree(empty / "frames")
    (empty / "frames").mkdir()
    with pytest.raises(FileNotFoundError, match=rf"^{re.escape(str(empty / 'frames'))} holds no \.npz frames"):
        exposure.mle_views(empty, 1)


def test_a_folder_without_a_capture_frame_has_capture_factor_one(folders, tmp_path):
    record = io.read_json(folders / "spc" / "spc.json")
    record.pop("capture_factor", None)
    io.write_json(tmp_path / "spc.json", record)
    assert exposure.capture_factor(tmp_path) == 1


def test_flux_per_linear_is_the_reported_exposure_over_q_t_and_a_missing_one_names_the_file(folders, tmp_path):
    record = read_spc_record(folders / "spc")
    p = params(folders / "spc")
    expected = record["exposure"]["photons_per_frame"] / (p.q * p.exposure_s)
    assert exposure.flux_per_linear(folders / "spc") == pytest.approx(expected, rel=1e-12)
    old = {k: v for k, v in record.items() if k not in ("exposure", "flux_scale")}
    io.write_json(tmp_path / "spc.json", old)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(tmp_path / 'spc.json'))} reports no camera exposure"):
        exposure.flux_per_linear(tmp_path)


def test_the_preview_shows_the_mean_flux_at_eighteen_percent_grey():
    """Average metering, a camera's default: the mean flux is shown at 18 % linear grey, however
    faint (a mean below one photon per second is still metered); no detection at all: unit gain."""
    phi = np.array([[[0.2, 0.4, 0.9]]]).repeat(4, 0)  # mean 0.5 photons/s
    gain = exposure.metered_gain(phi, exposure.PREVIEW_LEVEL)
    assert gain == pytest.approx(0.5 / 0.18, rel=1e-12)
    linear = spc.srgb_to_linear(exposure.display_srgb(phi, gain).astype(np.float64))
    assert linear.mean() == pytest.approx(0.18, rel=1e-4)
    assert exposure.metered_gain(np.zeros((2, 2)), 0.18) == 1.0


def test_scene_error_takes_any_positive_flux_and_names_itself_when_it_refuses():
    rng = np.random.default_rng(0)
    shown, gt = rng.random((2, 2, 3)), rng.random((2, 2, 3))
    error = exposure.scene_error(shown, gt, 0.5)  # a flux below 1 per unit intensity is valid
    direct = np.mean((exposure.display_srgb(shown, 2.0 * 0.5).astype(np.float64) - gt) ** 2)
    assert error(2.0) == pytest.approx(direct, rel=1e-9)
    with pytest.raises(ValueError, match=r"^scene_error: the shown flux has shape \(2, 2, 3\) but its ground truth"):
        exposure.scene_error(shown, gt[:, :1], 0.5)
    with pytest.raises(ValueError, match=r"^scene_error: the flux per linear intensity must be finite and > 0, got 0"):
        exposure.scene_error(shown, gt, 0.0)


def test_a_display_records_its_rule_level_and_gains(folders, tmp_path):
    start = time.perf_counter()
    cal = exposure.calibrate_display([folders / "scene"], [folders / "spc"], 2, tmp_path / "display-k2.json")
    took = time.perf_counter() - start
    assert cal == io.read_json(tmp_path / "display-k2.json") and cal["rule"] == exposure.RULE
    assert (cal["K"], cal["capture_factor"], cal["level_likelihood"]) == (2, 1, 1.0)
    assert cal["training_scenes"] == ["scene"] and cal["per_scene_level"] == {"scene": cal["level"]}
    assert 0.0 <= cal["wall_s"] <= took + 1e-3
    start = time.perf_counter()
    record = exposure.write_display(folders / "spc", tmp_path / "display-k2.json", 2, tmp_path / "mle")
    took = time.perf_counter() - start
    assert record == io.read_json(tmp_path / "mle" / "display.json")
    flux = exposure.flux_per_linear(folders / "spc")
    assert record["rule"] == exposure.RULE and record["gain"] == pytest.approx(cal["level"] * flux)
    assert (record["scene"], record["K"], record["capture_factor"], record["views"]) == ("spc", 2, 1, VIEWS)
    assert record["level"] == cal["level"] and record["level_likelihood"] == 1.0
    assert record["exposure"] == read_spc_record(folders / "spc")["exposure"] and record["exposure"]
    assert record["calibration"] == str(tmp_path / "display-k2.json") and record["flux_per_linear"] == flux
    assert 0.0 <= record["wall_s"] <= took + 1e-3
    assert exposure.read_gain(tmp_path / "mle") == pytest.approx(cal["level"] * flux)
    assert exposure.read_gain(tmp_path / "mle", likelihood=True) == pytest.approx(flux)  # the likelihood: k = 1
    shown = sorted(p.stem for p in (tmp_path / "mle" / "images").glob("*.png"))
    assert shown == exposure.mle_views(folders / "spc", 2)[0]


def test_the_rule_a_display_records_states_the_gain_it_applies():
    """g = k F with F = exposure / (q T), k fitted on the training scenes, and k = 1 for the
    likelihood's flux: what write_display computes (test_a_display_records_its_rule_level_and_gains)."""
    assert re.fullmatch(
        r"display gain g = k F, F = .* \(spc\.json exposure / \(q T\)\); k fitted on the training scenes "
        r"\(same K\) .*; the SPAD likelihood's flux is shown at k = 1",
        exposure.RULE,
    )


def test_a_display_is_written_again_over_its_last_one(folders, tmp_path):
    exposure.calibrate_display([folders / "scene"], [folders / "spc"], 1, tmp_path / "cal.json")
    first = exposure.write_display(folders / "spc", tmp_path / "cal.json", 1, tmp_path / "mle")
    again = exposure.write_display(folders / "spc", tmp_path / "cal.json", 1, tmp_path / "mle")
    assert {k: v for k, v in again.items() if k != "wall_s"} == {k: v for k, v in first.items() if k != "wall_s"}
    assert len(list((tmp_path / "mle" / "images").glob("*.png"))) == VIEWS


def test_a_calibration_without_the_newer_keys_reads_as_capture_factor_one_and_likelihood_level_one(folders, tmp_path):
    cal = exposure.calibrate_display([folders / "scene"], [folders / "spc"], 1, tmp_path / "cal.json")
    old = {k: v for k, v in cal.items() if k not in ("capture_factor", "level_likelihood")}
    io.write_json(tmp_path / "old.json", old)
    flux = exposure.flux_per_linear(folders / "spc")
    record = exposure.write_display(folders / "spc", tmp_path / "old.json", 1, tmp_path / "mle")
    assert record["level_likelihood"] == 1.0 and record["gain_likelihood"] == pytest.approx(flux, rel=1e-12)
    io.write_json(tmp_path / "twice.json", cal | {"level_likelihood": 2.0})
    record = exposure.write_display(folders / "spc", tmp_path / "twice.json", 1, tmp_path / "mle2")
    assert record["level_likelihood"] == 2.0 and record["gain_likelihood"] == pytest.approx(2.0 * flux, rel=1e-12)
    message = (
        f"{tmp_path / 'old.json'} was fitted for K = 1, capture_factor = 1; this display of {folders / 'spc'} "
        "is K = 2, capture_factor = 1 (capture=False): calibrate_display with the same K and capture"
    )
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        exposure.write_display(folders / "spc", tmp_path / "old.json", 2, tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("factor,bound", [(30.0, 20.0), (1 / 30.0, 0.05)])
def test_the_level_is_searched_within_its_range_and_stops_at_its_ends(factor, bound):
    """A scene 30x brighter (darker) than its reported exposure says is shown at the range's end,
    20x (1/20x), not beyond: the level corrects a miscalibrated exposure, within reason."""
    gt = np.random.default_rng(1).uniform(0.05, 0.95, (8, 8, 3))
    shown = spc.srgb_to_linear(gt) * 100.0 * factor  # F = 100: the true level is `factor`
    level, per_scene = exposure.fit_level([shown], [gt], [100.0])
    assert level == pytest.approx(bound, rel=1e-6) and per_scene == [level]
    inside, _ = exposure.fit_level([spc.srgb_to_linear(gt) * 100.0 * 3.0], [gt], [100.0])
    assert inside == pytest.approx(3.0, rel=1e-3)  # inside the range: the true level


def test_fit_level_refuses_empty_or_mismatched_lists_by_name():
    with pytest.raises(ValueError, match=r"^fit_level: need matching non-empty lists .*, got 0, 0 and 0$"):
        exposure.fit_level([], [], [])
    one = [np.ones((2, 2, 3))]
    with pytest.raises(ValueError, match=r"^fit_level: need matching non-empty lists .*, got 1, 1 and 2$"):
        exposure.fit_level(one, one, [1.0, 2.0])


def test_calibrating_refuses_no_training_scene_or_mixed_capture_factors(folders, tmp_path):
    with pytest.raises(ValueError, match=r"^the display level .* none was given \(scenes\.train is empty\)$"):
        exposure.calibrate_display([], [], 1, tmp_path / "d.json")
    simulate_scene(folders / "scene", tmp_path / "spc3", spc.SPCParams(frames=1), seed=1, capture_factor=3)
    spc_dirs = [folders / "spc", tmp_path / "spc3"]
    with pytest.raises(ValueError, match=r"^training scenes \[.*\] have capture frames of different capture_factor"):
        exposure.calibrate_display([folders / "scene"] * 2, spc_dirs, 1, tmp_path / "d.json", capture=True)
    assert not (tmp_path / "d.json").exists()

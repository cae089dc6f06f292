"""A real SPAD capture in the loop: frame-mean PNGs read and checked (spc3d.captures.photon_cubes),
the simulator's binomial statistics on real bits (spc3d.physics.real_frames), one frame through a
trained model (python -m spc3d.translate) and the benchmark's smoke mode (benchmarks/real_spad.py)."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from spc3d import io
from spc3d.captures import photon_cubes as pc
from spc3d.physics import real_frames as rf
from spc3d.translate import model_io
from spc3d.translate.__main__ import main as translate_main
from spc3d.translate.blurred_mle import Config as PriorConfig
from spc3d.translate.blurred_mle import Translator as Prior

from conftest import REPO, load_script

SPAD = REPO.parent / "shared" / "data" / "spad" / "wision_yellowthroat"


def real_capture(*ks):
    if not (SPAD / "average256.png").is_file():
        pytest.skip(f"real SPAD capture {SPAD} not available (needs ../shared next to the repository)")
    return {k: pc.read_frame_mean(SPAD / f"average{k}.png", k).counts for k in ks}


def counts_of(k, shape=(12, 16), seed=0):
    return np.random.default_rng(seed).binomial(k, 0.3, shape)


def grey_png(path, codes, bits=8):
    io.write_image(path, (np.asarray(codes, np.float64) / (255 if bits == 8 else 65535))[:, :, None], bits=bits)
    return path


# --------------------------------------------------------------------------------------------
# the reader


def test_a_binary_frame_needs_no_k_and_is_a_one_frame_cube(tmp_path):
    bits = counts_of(1).astype(bool)
    path = grey_png(tmp_path / "frame.png", bits * 255)
    got = pc.read_frame_mean(path)
    assert (got.frames, got.frames_from) == (1, "binary")
    np.testing.assert_array_equal(got.counts, bits)
    np.testing.assert_array_equal(pc.read_cube(path), bits[None])


@pytest.mark.parametrize("k", [4, 16, 255, 300])
def test_a_k_frame_mean_round_trips_through_its_sidecar(tmp_path, k):
    counts = counts_of(k)
    path = pc.write_frame_mean(tmp_path / f"average{k}.png", counts, k)
    assert json.loads(pc.sidecar_path(path).read_text()) == {"frames": k}
    got = pc.read_frame_mean(path)
    assert (got.frames, got.frames_from, got.ambiguous) == (k, "sidecar", 0)
    np.testing.assert_array_equal(got.counts, counts)
    assert pc.read_frame_mean(path, k).frames_from == "argument"


def test_levels_rounded_either_way_are_read(tmp_path):
    """The mean x 255 may be rounded up or down at .5 (K = 4: 127.5 -> 127 or 128)."""
    path = grey_png(tmp_path / "m.png", np.array([[0, 64, 127, 191, 255, 128]]))
    np.testing.assert_array_equal(pc.read_frame_mean(path, 4).counts, [[0, 1, 2, 3, 4, 2]])


def test_k_above_the_full_scale_counts_the_levels_two_counts_share(tmp_path):
    """K = 256 in 8 bits: counts 0-127 have levels of their own; 127.5 (count 128) does not."""
    path = grey_png(tmp_path / "m.png", np.array([[0, 5, 119, 128, 128]]))
    got = pc.read_frame_mean(path, 256)
    assert got.ambiguous == 2 and list(got.counts[0, :3]) == [0, 5, 119]


@pytest.mark.parametrize(
    "codes, frames, fault",
    [
        ([[0, 64, 100, 255]], 4, r"1 pixels hold levels that are not multiples of 1/4 .*100/255 at row 0, column 2"),
        ([[0, 64, 128, 255]], 1, r"not a binary frame: 2 pixels are neither 0 nor 255 .*fit a mean of K = 4"),
        ([[0, 64, 128, 191, 255]], 16, r"K = 16 \(argument\) does not match the levels present.*mean of 4 frames"),
        ([[0, 255, 255, 0]], 4, r"does not match the levels present.*a single binary frame"),
        ([[0, 64, 128, 255]], None, r"4 grey levels, so not a binary frame; a K-frame mean needs K.*m.json"),
        ([[0, 16, 32, 255]], 4, r"not multiples of 1/4 .*fit a mean of K = 16"),
    ],
)
def test_bad_levels_are_named_with_the_file(tmp_path, codes, frames, fault):
    path = grey_png(tmp_path / "m.png", np.array(codes))
    with pytest.raises(ValueError, match=fault) as err:
        pc.read_frame_mean(path, frames)
    assert str(path) in str(err.value)


def test_sidecar_faults_are_named(tmp_path):
    path = pc.write_frame_mean(tmp_path / "m.png", counts_of(4), 4)
    with pytest.raises(ValueError, match=r"frames=16 was given but its sidecar m.json says 4"):
        pc.read_frame_mean(path, 16)
    pc.sidecar_path(path).write_text('{"frames": 0}')
    with pytest.raises(ValueError, match=r"m.json: frames=0; the sidecar of m.png states"):
        pc.read_frame_mean(path)


def test_colour_and_non_png_files_are_refused(tmp_path):
    rgb = tmp_path / "rgb.png"
    io.write_image(rgb, np.stack([np.zeros((4, 4)), np.ones((4, 4)), np.zeros((4, 4))], -1))
    with pytest.raises(ValueError, match=r"rgb.png: a colour image .* monochrome"):
        pc.read_frame_mean(rgb, 1)
    grey3 = tmp_path / "grey3.png"
    io.write_image(grey3, np.repeat(counts_of(1, (4, 4))[:, :, None].astype(float), 3, -1))
    assert pc.read_frame_mean(grey3).frames == 1  # equal RGB channels: a grey image saved as RGB
    with pytest.raises(ValueError, match=r"m.tif: a frame mean is read from a .png file"):
        io.write_image(tmp_path / "m.tif", np.zeros((4, 4, 1)))
        pc.read_frame_mean(tmp_path / "m.tif", 1)


# --------------------------------------------------------------------------------------------
# the statistics: known truth, then the real capture


def test_simulated_means_have_the_predicted_variance_ratios():
    """λT known: nested draws give (1 - K/256)/(1 - 1/256) around the 256-mean and 1 against the
    other frames; independent draws give (1 + K/256)/(1 - 1/256)."""
    lam = np.full((96, 96), -np.log1p(-0.3))
    nested = rf.simulate_means(lam, (1, 4, 64, 256), np.random.default_rng(1))
    indep = rf.simulate_means(lam, (1, 4, 64, 256), np.random.default_rng(2), nested=False)
    for k in (4, 64):
        pred = rf.ratio_predictions(k, 256)
        assert rf.nested_ratio(nested[k], k, nested[256], 256, 16).value == pytest.approx(pred["nested"], rel=0.04)
        assert rf.disjoint_ratio(nested[k], k, nested[256], 256, 16).value == pytest.approx(1.0, rel=0.04)
        assert rf.nested_ratio(indep[k], k, indep[256], 256, 16).value == pytest.approx(pred["independent"], rel=0.04)
    assert rf.violations(nested[1], 1, nested[4], 4) == rf.violations(nested[4], 4, nested[64], 64) == 0
    assert rf.violations(indep[1], 1, indep[4], 4) > 0
    assert rf.histogram_tv(nested[4], 4, nested[256], 256) < 0.02


def test_real_bits_are_binomial_at_k_1_and_4():
    """The capture's 1- and 4-frame means scatter around its other frames with the binomial variance
    (interval over 16 x 16 pixel blocks holds 1), and lie inside the 256-frame mean (nested)."""
    real = real_capture(1, 4, 16, 256)
    rng = np.random.default_rng(0)
    for k in (1, 4):
        fig = rf.disjoint_ratio(real[k], k, real[256], 256, 16)
        lo, hi = fig.interval(400, rng)
        assert lo < 1.0 < hi and 0.97 < fig.value < 1.03, (k, fig.value, lo, hi)
        pred = rf.ratio_predictions(k, 256)["nested"]
        lo, hi = rf.nested_ratio(real[k], k, real[256], 256, 16).interval(400, rng)
        assert lo < pred < hi
    assert rf.violations(real[1], 1, real[4], 4) == rf.violations(real[4], 4, real[16], 16) == 0
    assert rf.violations(real[16], 16, real[256], 256) == 0


# --------------------------------------------------------------------------------------------
# one frame through a model; the benchmark


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """The physics prior (the stage-1 method with no network: built in milliseconds) as a model folder
    of the simulated RGB sensor, and the same recorded as trained for an RGGB sensor."""
    root = tmp_path_factory.mktemp("models")
    cfg = PriorConfig()
    model = Prior(cfg, torch.device("cpu"))
    for folder, sensor in (("models", None), ("models-rggb", {"cfa": "RGGB"})):
        record = {"method": "prior", "settings": dataclasses.asdict(cfg), "sensor": sensor}
        model_io.write_model_folder(root / folder / "prior", model, record, [])
    return root


def test_the_command_translates_a_frame_and_names_a_bad_one(tmp_path, capsys, models):
    model = models / "models" / "prior"
    frame = grey_png(tmp_path / "frame.png", counts_of(1, (24, 40)) * 255)
    assert translate_main([str(model), str(frame), str(tmp_path / "out.png")]) == 0
    out = io.read_image(tmp_path / "out.png")
    assert out.shape == (24, 40, 1) and 0 < out.mean() < 1
    assert "K = 1, 40x24, input replicated" in capsys.readouterr().out
    bad = grey_png(tmp_path / "bad.png", np.array([[0, 64, 100, 255]]))
    assert translate_main([str(model), str(bad), str(tmp_path / "bad_out.png"), "--frames", "4"]) == 2
    assert f"{bad}: 1 pixels hold levels that are not multiples of 1/4" in capsys.readouterr().err
    assert not (tmp_path / "bad_out.png").exists()
    rggb = models / "models-rggb" / "prior"
    assert translate_main([str(rggb), str(frame), str(tmp_path / "x.png")]) == 2
    assert "trained for the RGGB colour-filter sensor" in capsys.readouterr().err


def test_the_benchmark_smoke_mode_writes_both_tables(tmp_path, models):
    real_capture(1)
    bench = load_script(REPO / "benchmarks" / "real_spad.py")
    assert bench.main(["--smoke", "--models", str(models / "models"), "--out", str(tmp_path / "out")]) == 0
    physics = (tmp_path / "out" / "tables" / "real_spad_physics.md").read_text()
    stage1 = (tmp_path / "out" / "tables" / "real_spad_stage1.md").read_text()
    assert "64 x 48 = 3,072 pixels" in physics and physics.count("| Var(m_K") == 8
    assert "| prior |" in stage1 and "| binary frame, MLE (no model) |" in stage1
    assert (tmp_path / "out" / "real_spad_stage1.png").is_file()

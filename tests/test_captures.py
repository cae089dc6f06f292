"""Captured SPAD data: photon-cube formats, CFA sensors, the masked likelihood, hot pixels, and the
simulated export read back as a capture."""

import gzip
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from spc3d import io
from spc3d.captures import folders as captures
from spc3d.captures import photon_cubes
from spc3d.evaluation.metrics import psnr
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import render_scene, write_builtin_scene
from spc3d.physics import hot_pixels, sensors, spc
from spc3d.reconstruct.objectives import BernoulliObjective

from conftest import REPO

BAYER = ("RGGB", "BGGR", "GRBG", "GBRG")
OBJ = BernoulliObjective(flux_scale=2000.0, q=0.45, exposure_s=1e-3, dark_count_rate=100.0)


def random_cube(shape=(5, 7, 13), p=0.3, seed=0):
    return np.random.default_rng(seed).random(shape) < p


def cube_name(fmt):
    return "view" if fmt == "png" else f"view.{fmt}"


# --------------------------------------------------------------------------------------------
# photon-cube formats


@pytest.mark.parametrize("fmt", photon_cubes.FORMATS)
@pytest.mark.parametrize("width", [16, 13])
@pytest.mark.parametrize("bitorder", photon_cubes.BITORDERS)
def test_every_format_round_trips_exactly(tmp_path, fmt, width, bitorder):
    cube = random_cube((4, 6, width))
    path = photon_cubes.write_cube(tmp_path / cube_name(fmt), cube, bitorder=bitorder)
    assert photon_cubes.cube_format(path) == fmt
    back = photon_cubes.read_cube(path, width=width, bitorder=bitorder)
    assert back.dtype == bool and np.array_equal(back, cube)
    assert np.array_equal(photon_cubes.read_cube(path, width=width, bitorder=bitorder, max_frames=2), cube[:2])


def test_npy_layout_is_packbits_along_the_width(tmp_path):
    """Big bit order (the SwissSPAD2 .npy layout): pixel 8j is the top bit of byte j of its row."""
    cube = np.zeros((1, 2, 11), bool)
    cube[0, 0, 0] = cube[0, 1, 9] = True
    photon_cubes.write_cube(tmp_path / "a.npy", cube)
    photon_cubes.write_cube(tmp_path / "b.npy", cube, bitorder="little")
    big, little = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")
    assert big.dtype == np.uint8 and big.shape == (1, 2, 2)
    assert big[0].tolist() == [[0x80, 0], [0, 0x40]] and little[0].tolist() == [[0x01, 0], [0, 0x02]]
    assert np.array_equal(big, np.packbits(cube, axis=-1))
    with gzip.open(photon_cubes.write_cube(tmp_path / "c.npy.gz", cube)) as f:  # gzip of the same .npy
        assert np.array_equal(np.load(f), big)


def test_odd_width_drops_the_padding_bits(tmp_path):
    packed = np.full((2, 3, 2), 0xFF, np.uint8)  # a sensor that leaves garbage in the padding
    io.save_npy(tmp_path / "x.npy", packed)
    assert photon_cubes.read_cube(tmp_path / "x.npy", width=13).shape == (2, 3, 13)
    assert photon_cubes.read_cube(tmp_path / "x.npy").shape == (2, 3, 16)  # no width: all bits
    with pytest.raises(ValueError, match=r"x.npy: width=20 does not fit rows of 2 bytes.*\[9, 16\]"):
        photon_cubes.read_cube(tmp_path / "x.npy", width=20)


@pytest.mark.parametrize("name", ["f.npy", "f.npy.gz"])
def test_fortran_ordered_npy_is_read_too(tmp_path, name):
    cube = random_cube((3, 4, 16))
    packed = np.asfortranarray(np.packbits(cube, axis=-1))
    with (gzip.open if name.endswith(".gz") else open)(tmp_path / name, "wb") as f:
        np.lib.format.write_array(f, packed)
    assert np.array_equal(photon_cubes.read_cube(tmp_path / name), cube)
    assert np.array_equal(photon_cubes.read_cube(tmp_path / name, max_frames=2), cube[:2])


def test_gzip_is_streamed_and_deterministic(tmp_path):
    cube = random_cube((30, 8, 24))
    a = photon_cubes.write_cube(tmp_path / "a.npy.gz", cube).read_bytes()
    b = photon_cubes.write_cube(tmp_path / "a.npy.gz", cube).read_bytes()
    assert a == b  # no time stamp in the gzip header
    assert np.array_equal(photon_cubes.read_cube(tmp_path / "a.npy.gz", max_frames=3), cube[:3])


def test_png_frames_are_single_channel_0_255_in_natural_order(tmp_path):
    cube = random_cube((11, 5, 6))
    folder = photon_cubes.write_cube(tmp_path / "v", cube)
    files = photon_cubes.png_frames(folder)
    assert [f.name for f in files[:2]] == ["0000.png", "0001.png"]
    assert io.read_image(files[3]).shape == (5, 6, 1) and set(np.unique(io.read_image(files[3]) * 255)) <= {0, 255}
    for k, f in enumerate(files):  # unpadded names: 2.png before 10.png
        f.rename(folder / f"f{k}.png")
    assert np.array_equal(photon_cubes.read_cube(folder), cube)


@pytest.mark.parametrize(
    "make,message",
    [
        (
            lambda p: np.save(p / "c.npy", np.zeros((2, 3, 4), np.float32)),
            r"c.npy: holds a float32 .*expected uint8 \(K, H, ceil\(W/8\)\)",
        ),
        (lambda p: np.save(p / "c.npy", np.zeros((3, 4), np.uint8)), r"c.npy: holds a uint8 array of shape \(3, 4\)"),
        (lambda p: np.save(p / "c.npy", np.zeros((2, 3, 4), bool)), r"c.npy: .*bool.*unpacked cube"),
        (lambda p: (p / "c.npy").write_bytes(b"\x93NUMPY garbage"), r"cannot read photon cube .*c.npy"),
        (lambda p: (p / "c.npy.gz").write_bytes(b"not gzip at all"), r"c.npy.gz: .*gzip"),
        (lambda p: (p / "c.npz").write_bytes(b"nope"), r"c.npz"),
        (lambda p: (p / "c.tif").write_bytes(b"x"), r"c.tif: unknown photon-cube format"),
    ],
)
def test_bad_files_name_the_file_and_the_expectation(tmp_path, make, message):
    make(tmp_path)
    path = next(p for p in tmp_path.iterdir())
    with pytest.raises(ValueError, match=message):
        photon_cubes.read_cube(path)


def test_truncated_gzip_and_npy_are_named(tmp_path):
    data = photon_cubes.write_cube(tmp_path / "c.npy.gz", random_cube((20, 16, 32), 0.5)).read_bytes()
    (tmp_path / "c.npy.gz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"c.npy.gz: .*truncated"):
        photon_cubes.read_cube(tmp_path / "c.npy.gz")
    raw = photon_cubes.write_cube(tmp_path / "d.npy", random_cube((20, 16, 32))).read_bytes()
    (tmp_path / "d.npy").write_bytes(raw[:-100])
    with pytest.raises(ValueError, match=r"d.npy"):
        photon_cubes.read_cube(tmp_path / "d.npy")


def test_bad_png_frames_are_named(tmp_path):
    (tmp_path / "ragged").mkdir()
    io.write_image(tmp_path / "ragged" / "0.png", np.zeros((4, 5, 1)))
    io.write_image(tmp_path / "ragged" / "1.png", np.zeros((4, 6, 1)))
    with pytest.raises(ValueError, match=r"ragged/1.png: frame is 6x4 .* but 0.png is 5x4"):
        photon_cubes.read_cube(tmp_path / "ragged")
    (tmp_path / "gray").mkdir()
    io.write_image(tmp_path / "gray" / "0.png", np.full((4, 5, 1), 0.5))
    with pytest.raises(ValueError, match=r"gray/0.png: 20 pixels are neither 0 nor full scale .*128.0/255"):
        photon_cubes.read_cube(tmp_path / "gray")
    (tmp_path / "rgb").mkdir()
    io.write_image(tmp_path / "rgb" / "0.png", np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match=r"rgb/0.png: 3 channels; a binary frame is a single-channel"):
        photon_cubes.read_cube(tmp_path / "rgb")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="empty: no PNG frames"):
        photon_cubes.read_cube(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="nothere.npy does not exist"):
        photon_cubes.read_cube(tmp_path / "nothere.npy")


def test_simulator_rgb_npz_and_bad_writes_are_explained(tmp_path):
    io.save_frames(tmp_path / "rgb.npz", *spc.pack_frames(random_cube((2, 3, 4, 3))))
    with pytest.raises(ValueError, match=r"rgb.npz: frames of shape \(2, 3, 4, 3\).*export_simulated"):
        photon_cubes.read_cube(tmp_path / "rgb.npz")
    with pytest.raises(ValueError, match=r"w.npy: got uint8 .*non-empty bool \(K, H, W\)"):
        photon_cubes.write_cube(tmp_path / "w.npy", np.zeros((2, 3, 4), np.uint8))
    with pytest.raises(ValueError, match=r"fmt='npz' needs a name ending in .npz"):
        photon_cubes.write_cube(tmp_path / "w.npy", random_cube(), fmt="npz")
    with pytest.raises(ValueError, match="bitorder='middle'"):
        photon_cubes.write_cube(tmp_path / "w.npy", random_cube(), bitorder="middle")


# --------------------------------------------------------------------------------------------
# CFA patterns and masks


@pytest.mark.parametrize("name", BAYER + ("RGBW",))
def test_named_patterns_lay_out_their_letters_row_by_row(name):
    mask = sensors.cfa_mask(sensors.cfa_pattern(name), 5, 7)  # odd sizes: the tile is cropped
    assert mask.shape == (5, 7, 3) and mask.dtype == np.float32
    letters = sensors.BAYER[name]
    for y in range(5):
        for x in range(7):
            assert tuple(mask[y, x]) == sensors._SEES[letters[y % 2][x % 2]]


def test_rgbw_white_is_the_sum_or_the_mean_of_the_channels():
    assert sensors.cfa_mask(sensors.cfa_pattern("RGBW"), 2, 2)[1, 0].tolist() == [1, 1, 1]
    mean = sensors.cfa_mask(sensors.cfa_pattern("RGBW", white="mean"), 2, 2)
    np.testing.assert_allclose(mean[1, 0], [1 / 3] * 3)
    assert mean[0, 0].tolist() == [1, 0, 0]  # single-channel pixels keep weight 1
    labels, names = sensors.cfa_pattern("RGBW").classes()
    assert names == ["R", "G", "B", "W"] and labels.tolist() == [[0, 1], [3, 2]]
    with pytest.raises(ValueError, match="white='max'"):
        sensors.cfa_pattern("RGBW", white="max")


def test_mono_sees_luminance_weights_that_sum_to_one():
    mono = sensors.cfa_pattern("mono")
    mask = sensors.cfa_mask(mono, 3, 4)
    np.testing.assert_allclose(mask[..., :], np.broadcast_to(sensors.LUMINANCE, (3, 4, 3)), rtol=1e-6)
    gray = np.full((3, 4, 3), 0.25)
    np.testing.assert_allclose(sensors.mosaic(gray, mono), 0.25, rtol=1e-12)  # gray: same flux as one channel
    assert mono.classes()[1] == ["P"] and mono.to_json() == "mono"


def test_pattern_from_a_tile_image_or_array(tmp_path):
    tile = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 1, 0], [0, 0, 1]]], np.float32)
    io.write_image(tmp_path / "cfa.png", tile)
    from_png = sensors.cfa_pattern(str(tmp_path / "cfa.png"))
    from_list = sensors.cfa_pattern((tile * 255).astype(int).tolist())
    for p in (from_png, from_list):
        assert np.array_equal(sensors.cfa_mask(p, 4, 6), sensors.cfa_mask(sensors.cfa_pattern("RGGB"), 4, 6))
    assert from_list.to_json() == (tile * 255).astype(int).tolist()
    quad = np.ones((2, 4, 3)) * 255  # a 2x4 tile: W everywhere but one R pixel
    quad[0, 1] = [255, 0, 0]
    assert sensors.cfa_mask(sensors.cfa_pattern(quad), 2, 8)[0, 5].tolist() == [1, 0, 0]


@pytest.mark.parametrize(
    "tile,message",
    [
        (np.full((2, 2, 3), 128), "values other than 0 and 255"),
        (np.array([[[255, 0, 0], [0, 0, 0]]]), r"pixel \(row 0, column 1\) is black"),
        (np.zeros((2, 2)), r"shape \(2, 2\); expected \(th, tw, 3\)"),
    ],
)
def test_bad_tiles_are_explained(tile, message):
    with pytest.raises(ValueError, match=message):
        sensors.cfa_pattern(tile)


def test_unknown_pattern_name_lists_the_names():
    with pytest.raises(ValueError, match="RGGB, BGGR, GRBG, GBRG, RGBW, mono"):
        sensors.cfa_pattern("XYZ")


# --------------------------------------------------------------------------------------------
# mosaics and demosaicing


@pytest.mark.parametrize("name", BAYER)
def test_mosaic_frames_keep_the_bit_of_the_channel_each_pixel_sees(name):
    frames = random_cube((3, 4, 6, 3), 0.5)
    raw = sensors.mosaic_frames(frames, sensors.cfa_pattern(name))
    idx = sensors.pure_channel(sensors.cfa_pattern(name), 4, 6)
    for y in range(4):
        for x in range(6):
            assert np.array_equal(raw[:, y, x], frames[:, y, x, idx[y, x]])


def test_white_pixels_are_not_made_from_channel_bits():
    with pytest.raises(ValueError, match=r"pixel \(row 1, column 0\) sees weights \[1.0, 1.0, 1.0\].*simulate_m"):
        sensors.mosaic_frames(random_cube((2, 4, 4, 3)), sensors.cfa_pattern("RGBW"))


def test_simulated_mosaic_fires_at_the_rate_of_the_weighted_flux():
    params = spc.SPCParams(frames=4000, exposure_s=1e-4, dark_count_rate=100.0)
    phi = np.broadcast_to([2000.0, 5000.0, 1000.0], (4, 4, 3))
    bits = sensors.simulate_mosaic(phi, sensors.cfa_pattern("RGBW"), params, np.random.default_rng(1))
    expected = spc.detection_probability(np.array([2000.0, 5000.0, 8000.0, 1000.0]), params)  # R G W(sum) B
    got = [bits[:, y::2, x::2].mean() for y, x in ((0, 0), (0, 1), (1, 0), (1, 1))]
    np.testing.assert_allclose(got, expected, atol=0.012)  # 16000 draws per class: sd <= 0.004


@pytest.mark.parametrize("name", BAYER + ("RGBW",))
def test_demosaic_of_a_flat_colour_returns_the_colour(name):
    colour = np.array([0.6, 0.3, 0.1])
    pattern = sensors.cfa_pattern(name)
    flat = np.broadcast_to(colour, (9, 12, 3))
    plane = sensors.mosaic(flat, pattern)
    np.testing.assert_allclose(sensors.demosaic_bilinear(plane, pattern), flat, rtol=1e-12)
    valid = np.ones((9, 12), bool)
    valid[4, 5] = valid[0, 0] = False  # masked pixels are filled from neighbours of their colour
    np.testing.assert_allclose(sensors.demosaic_bilinear(plane, pattern, valid), flat, rtol=1e-12)


def test_mono_demosaic_is_the_luminance_as_gray():
    mono = sensors.cfa_pattern("mono")
    colour = np.array([0.6, 0.3, 0.1])
    plane = sensors.mosaic(np.broadcast_to(colour, (5, 6, 3)), mono)
    luminance = float(colour @ np.array(sensors.LUMINANCE))
    np.testing.assert_allclose(sensors.demosaic_bilinear(plane, mono), luminance, rtol=1e-12)


def test_bayer_demosaic_is_classic_bilinear():
    rng = np.random.default_rng(2)
    plane = rng.random((8, 8))
    rgb = sensors.demosaic_bilinear(plane, sensors.cfa_pattern("RGGB"))
    y, x = 4, 4  # an R site
    assert rgb[y, x, 0] == plane[y, x]
    assert rgb[y, x, 1] == pytest.approx(plane[[y - 1, y + 1, y, y], [x, x, x - 1, x + 1]].mean())
    assert rgb[y, x, 2] == pytest.approx(plane[[y - 1, y - 1, y + 1, y + 1], [x - 1, x + 1, x - 1, x + 1]].mean())
    assert rgb[y, x + 1, 0] == pytest.approx((plane[y, x] + plane[y, x + 2]) / 2)  # R at a G site of an R row


def test_average_demosaic_is_the_demosaic_of_the_mean():
    pattern = sensors.cfa_pattern("RGBW")
    cube = random_cube((6, 4, 6), 0.4)
    np.testing.assert_allclose(
        sensors.demosaic_average(cube, pattern), sensors.demosaic_bilinear(cube.mean(0), pattern)
    )


def test_mle_rgb_leaves_out_hot_pixels_and_demosaics():
    params = spc.SPCParams(frames=200, exposure_s=1e-4, dark_count_rate=0.0)
    pattern = sensors.cfa_pattern("RGGB")
    phi = np.broadcast_to([3000.0, 6000.0, 1500.0], (8, 10, 3))
    S = np.round(spc.detection_probability(sensors.mosaic(phi, pattern), params) * 200).astype(int)
    hot = np.zeros((8, 10), bool)
    hot[3, 4] = hot[4, 4] = True
    S[hot] = 200  # saturated: would read as ln(400)/(qT)
    rgb = sensors.mle_rgb(S, 200, params, pattern, hot)
    np.testing.assert_allclose(rgb, np.broadcast_to(phi, rgb.shape), rtol=0.05)  # S rounded to counts
    blind = sensors.mle_rgb(S, 200, params, pattern)  # the same counts, hot pixels taken at their word
    assert not np.allclose(blind[3:5, 3:6], phi[3:5, 3:6], rtol=0.05)


# --------------------------------------------------------------------------------------------
# the masked SPAD likelihood


def fractions(shape, seed=3, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=dtype), torch.rand(shape, generator=g, dtype=dtype) * 0.5


def test_log_detection_probability_is_accurate_at_extreme_rates():
    """Both implementations of the SPAD NLL (BernoulliObjective.loss, sensors.bernoulli_nll_terms)
    give log p = log(1 - exp(-x)) and log(1 - p) = -x to full precision from x = λT = 1e-12 (the
    objective's clamp; log p -> log x) to x = 800 (log p = 0 in float64), across the ln 2 branch
    point, with gradients -f / expm1(x) + (1 - f) accurate there too."""
    x = torch.tensor([1e-12, 1e-8, 0.1, 0.69, 0.7, 5.0, 40.0, 800.0], dtype=torch.float64)
    log_p = [math.log(-math.expm1(-v)) if v < 1 else math.log1p(-math.exp(-v)) for v in x.tolist()]
    unit = BernoulliObjective(flux_scale=1.0, q=1.0, exposure_s=1.0, dark_count_rate=0.0)  # λT = pred
    ones, zeros = torch.ones_like(x), torch.zeros_like(x)
    for nll in (sensors.bernoulli_nll_terms, lambda a, f: torch.stack([unit.loss(v, g) for v, g in zip(a, f)])):
        torch.testing.assert_close(-nll(x, ones), torch.tensor(log_p, dtype=torch.float64), rtol=1e-14, atol=1e-300)
        torch.testing.assert_close(nll(x, zeros), x, rtol=0, atol=0)  # log(1 - p) = -λT exactly
        assert -nll(x[:1], ones[:1]).item() == pytest.approx(math.log(1e-12), rel=1e-15)
        assert -nll(x[-2:-1], ones[:1]).item() == pytest.approx(-math.exp(-40.0), rel=1e-12)
        assert nll(x[-1:], ones[:1]).item() == 0.0
        for f in (0.0, 0.3, 1.0):
            a = x.clone().requires_grad_(True)
            (g,) = torch.autograd.grad(nll(a, torch.full_like(x, f)).sum(), a)
            torch.testing.assert_close(g, -f / torch.expm1(x) + (1 - f), rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", BAYER)
def test_bayer_mosaic_likelihood_is_the_one_hot_channel_likelihood(name):
    pattern = sensors.cfa_pattern(name)
    pred, target = fractions((6, 8, 3))
    w = torch.from_numpy(sensors.cfa_mask(pattern, 6, 8)).double()
    raw = (target * w).sum(-1)  # the fraction each pixel measured, in its own channel
    mosaic_loss = sensors.mosaic_bernoulli_loss(OBJ, pred, raw, w)
    seen = w > 0  # one channel per pixel: BernoulliObjective over the measured (pixel, channel) pairs
    torch.testing.assert_close(mosaic_loss, OBJ.loss(pred[seen], target[seen]), rtol=1e-14, atol=0)


def test_white_pixel_rate_is_the_sum_of_the_channels():
    pred, _ = fractions((1, 1, 3))
    target = torch.tensor([[0.4]], dtype=torch.float64)
    w = torch.ones(1, 1, 3, dtype=torch.float64)
    expected = OBJ.loss(pred.sum(-1, keepdim=True), target[..., None])
    torch.testing.assert_close(sensors.mosaic_bernoulli_loss(OBJ, pred, target, w), expected, rtol=1e-14, atol=0)
    half = sensors.mosaic_bernoulli_loss(OBJ, pred, target, w / 3)  # white="mean": the channels' mean
    torch.testing.assert_close(half, OBJ.loss(pred.mean(-1, keepdim=True), target[..., None]), rtol=1e-14, atol=0)


def test_masked_pixels_get_no_gradient_and_do_not_count():
    pattern = sensors.cfa_pattern("RGGB")
    pred, target = fractions((6, 8, 3))
    raw = target[..., 0]
    w = torch.from_numpy(sensors.cfa_mask(pattern, 6, 8)).double()
    valid = torch.ones(6, 8, dtype=torch.bool)
    valid[2, 3] = False
    pred.requires_grad_(True)
    loss = sensors.mosaic_bernoulli_loss(OBJ, pred, raw, w, valid)
    loss.backward()
    assert torch.all(pred.grad[2, 3] == 0)  # the hot pixel
    assert torch.all(pred.grad[w == 0] == 0) and torch.all(pred.grad[(w > 0) & valid[..., None]] != 0)
    other = raw.clone()
    other[2, 3] = 1.0  # whatever the hot pixel fired, the loss is the same
    assert torch.equal(sensors.mosaic_bernoulli_loss(OBJ, pred, other, w, valid), loss)
    ref = sensors.mosaic_bernoulli_loss(OBJ, pred[valid], raw[valid], w[valid])  # the valid pixels alone
    torch.testing.assert_close(loss, ref, rtol=1e-14, atol=0)
    assert torch.isfinite(loss) and sensors.mosaic_bernoulli_loss(OBJ, pred, raw, w, torch.zeros_like(valid)) == 0


def test_packed_target_objective_matches_the_function():
    pattern = sensors.cfa_pattern("RGBW")
    pred, target = fractions((6, 8, 3))
    raw = target[..., 1]
    w = torch.from_numpy(sensors.cfa_mask(pattern, 6, 8)).double()
    valid = torch.rand(6, 8, generator=torch.Generator().manual_seed(0)) > 0.2
    packed = sensors.pack_mosaic_target(raw, w, valid)
    obj = sensors.MosaicBernoulliObjective(OBJ)
    assert packed.shape == (6, 8, 5)
    assert torch.equal(obj.loss(pred, packed), sensors.mosaic_bernoulli_loss(OBJ, pred, raw, w, valid))
    i = torch.tensor([0, 5, 17, 40])  # a ray batch gathers targets with their weights
    assert torch.equal(
        obj.loss(pred.reshape(-1, 3)[i], packed.reshape(-1, 5)[i]),
        sensors.mosaic_bernoulli_loss(
            OBJ, pred.reshape(-1, 3)[i], raw.reshape(-1)[i], w.reshape(-1, 3)[i], valid.reshape(-1)[i]
        ),
    )


# --------------------------------------------------------------------------------------------
# hot pixels


def plant(shape, count, seed):
    rng = np.random.default_rng(seed)
    hot = np.zeros(shape, bool)
    hot.flat[rng.choice(hot.size, count, replace=False)] = True
    return hot


def frames_from_p(p, frames, seed):
    """(frames, H, W) bool with per-pixel firing probability p (H, W)."""
    return np.random.default_rng(seed).random((frames,) + p.shape) < p


def with_hot(p, hot, lam_t_hot=1.0):
    """Add a hot pixel's dark counts (lam_t_hot detections per frame) to firing probabilities p."""
    return np.where(hot, 1.0 - (1.0 - p) * np.exp(-lam_t_hot), p)


@pytest.mark.parametrize("pattern", [None, "RGGB"])
def test_clean_flat_field_has_no_hot_pixels(pattern):
    p = np.full((64, 96), 0.2)
    if pattern:  # R, G, B at very different levels: only same-colour neighbours may be compared
        p = sensors.mosaic(np.broadcast_to([0.3, 0.08, 0.02], (64, 96, 3)), sensors.cfa_pattern(pattern))
    counts, k = hot_pixels.count_ones([frames_from_p(p, 200, 0), frames_from_p(p, 200, 1)])
    hot, rec = hot_pixels.detect_hot_pixels(counts, k, pattern and sensors.cfa_pattern(pattern))
    assert k == 400 and rec["count"] == 0 and not hot.any()


@pytest.mark.parametrize("pattern", [None, "RGGB"])
def test_planted_hot_pixels_are_found_on_a_textured_scene(pattern):
    h, w = 64, 96
    yy, xx = np.mgrid[0:h, 0:w]
    texture = 0.15 + 0.1 * np.sin(xx / 5.0) * np.cos(yy / 7.0) + 0.1 * (xx / w)  # smooth, in [0, 0.35]
    rgb = np.stack([texture, 0.5 * texture, 0.2 + 0 * texture], -1)
    cfa = sensors.cfa_pattern(pattern) if pattern else sensors.cfa_pattern("mono")
    params = spc.SPCParams(exposure_s=1e-4, dark_count_rate=0)
    p = spc.detection_probability(sensors.mosaic(rgb, cfa) * 1e4, params)
    planted = plant((h, w), 30, 5)
    views = [frames_from_p(with_hot(np.roll(p, 3 * v, axis=1), planted), 100, v) for v in range(4)]
    counts, k = hot_pixels.count_ones(views)  # the scene moves between views, the hot pixels do not
    hot, rec = hot_pixels.detect_hot_pixels(counts, k, sensors.cfa_pattern(pattern) if pattern else None)
    assert (hot & planted).sum() == 30 and (hot & ~planted).sum() == 0
    assert rec["count"] == 30 and {tuple(x) for x in rec["positions"]} == {tuple(x) for x in np.argwhere(planted)}
    assert min(rec["rates"]) > max(rec["neighbour_rates"]) and min(rec["z"]) > rec["threshold"]


@pytest.mark.parametrize("name", ["mono", "RGGB"])
def test_planted_hot_pixels_on_a_rendered_scene_summed_over_views(name):
    """Sharp texture (the built-in courtyard): four views of 100 frames, summed."""
    scene = render_scene("courtyard", 72, 96, 4, 1, 0)
    cfa, params = sensors.cfa_pattern(name), spc.SPCParams()
    planted = plant((72, 96), 25, 0)
    clean, cubes = [], []
    for v, srgb in enumerate(scene.images):
        p = spc.detection_probability(sensors.mosaic(spc.flux_from_srgb(srgb, 1.5e4), cfa), params)
        u = np.random.default_rng(v).random((100,) + p.shape)
        clean.append(u < p)
        cubes.append(u < with_hot(p, planted))
    pattern = None if name == "mono" else cfa
    assert not hot_pixels.detect_hot_pixels(*hot_pixels.count_ones(clean), pattern)[0].any()
    assert np.array_equal(hot_pixels.detect_hot_pixels(*hot_pixels.count_ones(cubes), pattern)[0], planted)


def test_hot_pixels_in_the_dark_are_found():
    """At ~0.5 counts per pixel a log-rate z-score has no usable spread; the stabilised one has."""
    planted = plant((40, 40), 10, 7)
    counts, k = hot_pixels.count_ones([frames_from_p(with_hot(np.full((40, 40), 0.002), planted, 0.3), 250, 3)])
    hot, rec = hot_pixels.detect_hot_pixels(counts, k)
    assert np.array_equal(hot, planted)


def test_hot_pixel_inputs_and_maps(tmp_path):
    with pytest.raises(ValueError, match=r"counts span \[0, 9\]; ones among 5 frames"):
        hot_pixels.detect_hot_pixels(np.arange(10).reshape(2, 5), 5)
    with pytest.raises(ValueError, match="window=4"):
        hot_pixels.detect_hot_pixels(np.zeros((4, 4), int), 5, window=4)
    hot = plant((6, 7), 4, 0)
    for name in ("hot.png", "hot.npy"):
        hot_pixels.write_hot_pixel_map(tmp_path / name, hot)
        assert np.array_equal(hot_pixels.read_hot_pixel_map(tmp_path / name, (6, 7)), hot)
    with pytest.raises(ValueError, match=r"hot.png: 7x6 \(WxH\) but the sensor is 8x6"):
        hot_pixels.read_hot_pixel_map(tmp_path / "hot.png", (6, 8))


# --------------------------------------------------------------------------------------------
# export of a simulated scene -> capture folder -> read_capture


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim")
    write_builtin_scene("courtyard", root / "scene", height=24, width=30, views=3, supersample=1, seed=0)
    params = spc.SPCParams(frames=24)
    simulate_scene(root / "scene", root / "spc", params, target_detection=0.3, seed=4)
    return root


@pytest.mark.parametrize("fmt", photon_cubes.FORMATS)
def test_export_then_read_capture_round_trips(simulated, tmp_path, fmt):
    out = tmp_path / "cap"
    bitorder = "little" if fmt == "npy" else "big"
    rec = captures.export_simulated(simulated / "spc", out, "GRBG", fmt, bitorder, scene_dir=simulated / "scene")
    assert rec["width"] == 30 and rec["height"] == 24 and rec["frames"] == 24 and rec["cfa"] == "GRBG"
    names, cubes, sensor = captures.read_capture(out)
    assert names == ["image000", "image001", "image002"] and sensor.format == fmt and sensor.bitorder == bitorder
    spc_rec = io.read_json(simulated / "spc" / "spc.json")
    assert sensor.params == spc.SPCParams(**{**spc_rec["params"], "mode": "bernoulli"})
    for name, cube in zip(names, cubes):
        frames = spc.unpack_frames(*io.load_frames(simulated / "spc" / "frames" / f"{name}.npz"))
        assert np.array_equal(cube, sensors.mosaic_frames(frames, sensor.cfa))  # the simulated bits, exactly
    refs = captures.reference_images(out, names)
    assert refs.shape == (3, 24, 30, 3) and (out / "poses_bounds.npy").is_file()
    assert captures.read_capture(out, max_frames=5)[2].params.frames == 5


def test_exported_rgbw_and_mono_draw_white_pixels_afresh(simulated, tmp_path):
    with pytest.raises(ValueError, match="give scene_dir"):
        captures.export_simulated(simulated / "spc", tmp_path / "x", "RGBW")
    assert not (tmp_path / "x").exists()
    captures.export_simulated(simulated / "spc", tmp_path / "rgbw", "RGBW", "npz", scene_dir=simulated / "scene")
    names, cubes, sensor = captures.read_capture(tmp_path / "rgbw")
    frames = spc.unpack_frames(*io.load_frames(simulated / "spc" / "frames" / f"{names[0]}.npz"))
    bits, single = sensors.channel_bits(frames, sensor.cfa)
    assert np.array_equal(cubes[0][:, single], bits[:, single]) and sensor.cfa.name == "RGBW"
    w_rate, rgb_rate = cubes[0][:, ~single].mean(), cubes[0][:, single].mean()
    assert w_rate > rgb_rate  # W pixels collect the sum of the channels
    captures.export_simulated(simulated / "spc", tmp_path / "mono", "mono", "png", scene_dir=simulated / "scene")
    assert captures.read_capture(tmp_path / "mono")[2].cfa.name == "mono"


def test_captured_route_recovers_the_views_like_the_simulated_one(simulated, tmp_path):
    captures.export_simulated(simulated / "spc", tmp_path / "cap", "RGGB", "npy.gz", scene_dir=simulated / "scene")
    names, cubes, sensor = captures.read_capture(tmp_path / "cap")
    scale = io.read_json(simulated / "spc" / "spc.json")["flux_scale"]
    gt = captures.reference_images(tmp_path / "cap", names)
    for i, cube in enumerate(cubes):
        rgb = sensors.mle_rgb(cube.sum(0), len(cube), sensor.params, sensor.cfa) / scale
        simulated_bits = spc.unpack_frames(*io.load_frames(simulated / "spc" / "frames" / f"{names[i]}.npz"))
        full = spc.mle_flux(simulated_bits.sum(0), 24, sensor.params) / scale  # all three channels per pixel
        # a third of the measurements, interpolated: about as good at K = 24 (measured: +0.1 dB)
        srgb = [spc.linear_to_srgb(np.clip(lin, 0, 1)) for lin in (rgb, full)]
        assert psnr(srgb[0], gt[i]) > psnr(srgb[1], gt[i]) - 2


def test_bad_captures_name_the_file_and_key(simulated, tmp_path):
    captures.export_simulated(simulated / "spc", tmp_path / "cap", "RGGB", "npy")
    sensor_json = tmp_path / "cap" / "sensor.json"
    rec = io.read_json(sensor_json)
    io.write_json(sensor_json, {k: v for k, v in rec.items() if k != "q"})
    with pytest.raises(ValueError, match=r"sensor.json: missing keys \['q'\]"):
        captures.read_capture(tmp_path / "cap")
    io.write_json(sensor_json, {**rec, "q": 2.0})
    with pytest.raises(ValueError, match=r"sensor.json: q=2.0: quantum efficiency"):
        captures.read_capture(tmp_path / "cap")
    io.write_json(sensor_json, {**rec, "frames": 99})
    with pytest.raises(ValueError, match=r"image000.npy: 24 frames of 30x24 .*sensor.json says 99 frames"):
        captures.read_capture(tmp_path / "cap")
    io.write_json(sensor_json, {**rec, "width": 40})
    with pytest.raises(ValueError, match=r"image000.npy: width=40 does not fit rows of 4 bytes"):
        captures.read_capture(tmp_path / "cap")
    io.write_json(sensor_json, {**rec, "format": "png"})
    with pytest.raises(FileNotFoundError, match=r"frames: no views in format 'png'"):
        captures.read_capture(tmp_path / "cap")
    io.write_json(sensor_json, {**rec, "cfa": "cfa.png"})
    with pytest.raises(FileNotFoundError, match=r"cfa names cfa.png, which is not in"):
        captures.read_capture(tmp_path / "cap")


# --------------------------------------------------------------------------------------------
# the command line: export, then inspect (hot pixels, detection rates, previews without reference)

CAPTURE_TOOL = REPO / "workflow" / "tools" / "capture.py"


def capture_tool(*args):
    return subprocess.run(
        [sys.executable, str(CAPTURE_TOOL), *map(str, args)], capture_output=True, text=True, timeout=300
    )


def test_capture_tool_exports_and_inspects_a_capture_with_a_planted_hot_pixel(tmp_path):
    # 4 views x 64 frames: enough frames that one hot pixel stands out of the courtyard's sharp texture
    write_builtin_scene("courtyard", tmp_path / "scene", height=36, width=48, views=4, supersample=1, seed=0)
    simulate_scene(tmp_path / "scene", tmp_path / "spc", spc.SPCParams(frames=64), target_detection=0.3, seed=4)
    cap, out = tmp_path / "cap", tmp_path / "inspect"
    proc = capture_tool(
        "export", tmp_path / "spc", cap, "--cfa", "RGGB", "--format", "npz", "--scene", tmp_path / "scene"
    )
    assert proc.returncode == 0, proc.stderr
    assert "64 frames of 48x36, cfa RGGB" in proc.stdout
    for path in sorted((cap / "frames").glob("*.npz")):  # pixel (row 9, column 13) fires in 63 of 64 frames
        cube = photon_cubes.read_cube(path)
        cube[:, 9, 13] = np.arange(len(cube)) > 0
        photon_cubes.write_cube(path, cube)
    shutil.rmtree(cap / "images")  # inspecting needs no reference views
    proc = capture_tool("inspect", cap, out)
    assert proc.returncode == 0, proc.stderr
    assert "hot pixels: 1 (" in proc.stdout
    rec = io.read_json(out / "capture.json")
    assert rec["hot_pixels"]["positions"] == [[9, 13]] and rec["frames"] == 64 and rec["cfa"] == "RGGB"
    assert np.array_equal(hot_pixels.read_hot_pixel_map(out / "hot_pixels.png"), np.pad([[True]], ((9, 26), (13, 34))))
    # the simulation's exposure: 0.3 mean detection (rates per colour around it, R > G > B on this scene)
    rates = rec["detection_rate"]
    assert set(rates) == {"R", "G", "B"} and 0.15 < np.mean(list(rates.values())) < 0.45
    # previews: the demosaiced MLE at one metered gain, hot pixel excluded: the scene's picture
    gt = io.read_rgb(tmp_path / "scene" / "images" / "image000.png")
    preview = io.read_rgb(out / "preview" / "image000.png")
    assert preview.shape == gt.shape
    assert np.corrcoef(preview.mean(2).ravel(), gt.mean(2).ravel())[0, 1] > 0.6
    assert sorted(p.name for p in (out / "preview").iterdir()) == [f"image00{i}.png" for i in range(4)]


def test_capture_tool_errors_name_the_file(simulated, tmp_path):
    proc = capture_tool("inspect", tmp_path / "nowhere", tmp_path / "out")
    assert proc.returncode == 1 and "capture inspect:" in proc.stderr and "nowhere/sensor.json" in proc.stderr
    assert not (tmp_path / "out").exists()
    proc = capture_tool("inspect", tmp_path / "nowhere", tmp_path / "out", "--level", "0")
    assert proc.returncode == 1 and "level=0.0: the linear grey level" in proc.stderr
    proc = capture_tool("export", simulated / "spc", tmp_path / "w", "--cfa", "RGBW")
    assert proc.returncode == 1 and "give scene_dir" in proc.stderr and not (tmp_path / "w").exists()


def test_data_summary_figure_of_a_capture_without_reference_views(tmp_path):
    """The data summary's panels for a capture: no reference image (the figure says so instead of
    showing a black frame) and the MLE at a metered gain (there is no flux_scale to be exact with)."""
    from spc3d.evaluation.summary import figure_panels, write_figure

    scene, spc_dir = tmp_path / "scene", tmp_path / "spc"
    rng = np.random.default_rng(0)
    for kind in ("binary", "average"):
        io.write_image(spc_dir / kind / "v0.png", rng.random((6, 8, 3)).astype(np.float32))
    io.write_image(spc_dir / "mle" / "v0.exr", rng.random((6, 8, 3)).astype(np.float32) * 500.0)
    io.write_json(spc_dir / "spc.json", {"flux_scale": None})
    (scene / "images").mkdir(parents=True)

    view, panels, exact = figure_panels(scene, spc_dir)
    assert (view, panels[0], exact) == ("v0", None, False)
    assert all(p.shape == (6, 8, 3) and np.isfinite(p).all() for p in panels[1:])
    assert 0.05 < panels[3].mean() < 0.95  # metered: neither black nor blown out
    write_figure([(scene, spc_dir)], tmp_path / "summary.png", K=4)
    assert io.read_rgb(tmp_path / "summary.png").std() > 0


def test_luminance_and_colourless_sensors():
    gray = np.random.default_rng(0).random((4, 5, 1)).repeat(3, axis=-1).astype(np.float32)
    np.testing.assert_allclose(sensors.luminance_srgb(gray), gray, atol=1e-6)  # weights sum to 1
    green = np.zeros((1, 1, 3), np.float32)
    green[..., 1] = 1.0
    np.testing.assert_allclose(sensors.luminance_srgb(green)[0, 0], spc.linear_to_srgb(np.full(3, 0.7152)), atol=1e-6)
    assert not sensors.cfa_pattern("mono").colour and not sensors.cfa_pattern([[[255, 255, 255]] * 2]).colour
    assert all(sensors.cfa_pattern(name).colour for name in (*BAYER, "RGBW"))


def test_a_colourless_capture_is_scored_on_luminance(tmp_path, lpips_cache):
    """A mono capture's rows are scored on the luminance of render and reference: a render with the
    reference's luminance and none of its colour is perfect there, and the tables say so."""
    from spc3d import llff
    from spc3d.evaluation import tables
    from spc3d.evaluation.evaluate import LUMINANCE_NOTE, evaluate

    scene_dir = tmp_path / "scene"
    write_builtin_scene("courtyard", scene_dir, height=48, width=64, views=8, supersample=1)
    scene = llff.read_scene(scene_dir)
    test = scene.names[:2]
    for name in test:
        io.write_image(
            tmp_path / "recon" / "renders" / f"{name}.png",
            sensors.luminance_srgb(scene.images[scene.names.index(name)]),
        )
    io.write_json(
        tmp_path / "recon" / "train.json", {"source": "mle-k4", "model": "3dgs", "frames": 4, "test_views": test}
    )

    rgb = evaluate(tmp_path / "recon", scene_dir, tmp_path / "rgb.json", lpips_cache)
    assert rgb["scored_on"] == "RGB" and np.isfinite(rgb["mean"]["psnr"])
    meta = io.read_json(scene_dir / "scene.json")
    io.write_json(scene_dir / "scene.json", {**meta, "sensor": "mono", "colour": False})
    mono = evaluate(tmp_path / "recon", scene_dir, tmp_path / "mono.json", lpips_cache)
    assert mono["scored_on"] == LUMINANCE_NOTE and mono["mean"]["ssim"] > 0.999
    assert mono["mean"]["psnr"] > 50 > rgb["mean"]["psnr"] + 20  # equal up to the render's 8-bit rounding
    assert mono["mean"]["lpips_alex"] < 0.01 < rgb["mean"]["lpips_alex"]

    tables.two_stage_table([tmp_path / "mono.json"], tmp_path / "two_stage", "nerf-mlp")
    assert "Scene scene: captured by a colourless sensor" in (tmp_path / "two_stage.md").read_text()
    tables.two_stage_table([tmp_path / "rgb.json"], tmp_path / "two_stage_rgb", "nerf-mlp")
    assert "colourless" not in (tmp_path / "two_stage_rgb.md").read_text()

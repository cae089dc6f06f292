"""A captured SPAD scene brought into the workflow (spc3d.captures.importing): scenes without reference
views, sensor-recorded frames, the imported SPC folder and the readers of its sensor (translator
inputs, stage-2 targets, the MLE display), and the config's ``captures``."""

import dataclasses
import json
import re
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from spc3d import io, llff
from spc3d.captures import folders as captures
from spc3d.captures import photon_cubes
from spc3d.captures.importing import (
    MIN_POSED,
    capture_sensor,
    first_intrinsics,
    import_capture_frames,
    import_capture_scene,
    sensor_tag,
)
from spc3d.inputs import augment, exposure
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import LAYOUTS, write_builtin_scene
from spc3d.jobs import scene_specs
from spc3d.names import ConfigError
from spc3d.physics import hot_pixels, sensors, spc
from spc3d.physics.record import spc_sensor
from spc3d.reconstruct.objectives import BernoulliObjective
from spc3d.reconstruct.sources import bit_fractions, sensor_targets
from spc3d.translate.apply import input_sensor
from spc3d.translate.data import binary_input, load_pairs

from conftest import REPO

H, W, VIEWS, K = 24, 32, 4, 16
HOT = (5, 7)  # a B site of RGGB (odd row, odd column), planted where the courtyard is flat enough


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated built-in scene, exported as an RGGB capture (reference views and poses) and imported."""
    root = tmp_path_factory.mktemp("capture_import")
    write_builtin_scene("courtyard", root / "scene", height=H, width=W, views=VIEWS, supersample=1, seed=0)
    simulate_scene(root / "scene", root / "spc", spc.SPCParams(frames=K), target_detection=0.3, seed=4)
    captures.export_simulated(root / "spc", root / "cap", "RGGB", "npz", scene_dir=root / "scene")
    import_capture_scene(root / "cap", root / "cap_scene")
    import_capture_frames(root / "cap", root / "cap_scene", root / "cap_spc")
    return root


def names_of(root):
    return sorted(p.stem for p in (root / "scene" / "images").glob("*.png"))


def simulated_frames(root, name):
    return spc.unpack_frames(*io.load_frames(root / "spc" / "frames" / f"{name}.npz"))  # (K, H, W, 3)


def imported_frames(spc_dir, name):
    return spc.unpack_frames(*io.load_frames(spc_dir / "frames" / f"{name}.npz"))


def copy_capture(sim, tmp_path):
    cap = tmp_path / "cap"
    shutil.copytree(sim / "cap", cap)
    return cap


# --------------------------------------------------------------------------------------------
# llff: a scene without reference views


def test_scene_without_reference_round_trips_its_cameras(sim, tmp_path):
    src = llff.read_scene(sim / "scene", with_images=False)
    shift = np.array([0.0, 0.0, 1.5, -0.5])  # off-centre principal point: intrinsics.npy is written too
    cams = dataclasses.replace(src.cameras, intrinsics=src.cameras.intrinsics + shift)
    out = tmp_path / "noref"
    llff.write_scene(out, llff.SceneData(None, cams, list(src.names)), {"source": "test"})
    meta = io.read_json(out / "scene.json")
    assert meta["reference"] is False and meta["names"] == src.names and meta["source"] == "test"
    assert (meta["views"], meta["height"], meta["width"]) == (VIEWS, H, W)
    assert not (out / "images").exists() and (out / "intrinsics.npy").is_file()

    back = llff.read_scene(out, with_images=False)
    assert back.images is None and back.names == src.names
    assert (back.cameras.height, back.cameras.width) == (H, W)
    np.testing.assert_allclose(back.cameras.w2c, cams.w2c, atol=1e-9)
    np.testing.assert_allclose(back.cameras.intrinsics, cams.intrinsics, rtol=1e-12)
    np.testing.assert_allclose(back.cameras.bounds, cams.bounds, rtol=1e-12)
    assert back.meta["reference"] is False

    with pytest.raises(llff.NoReference, match=re.escape(str(out))):
        llff.read_scene(out)
    assert issubclass(llff.NoReference, ValueError)
    assert llff.has_reference(out) is False
    assert llff.has_reference(sim / "scene") is True and llff.has_reference(sim / "cap_scene") is True
    assert llff.has_reference(tmp_path) is True  # no scene.json: an LLFF folder, which has its images


# --------------------------------------------------------------------------------------------
# sensors: the simulator's frames as a sensor records them


@pytest.mark.parametrize("name", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_sensor_frames_of_a_bayer_pattern_are_the_channel_bits(name):
    frames = np.random.default_rng(0).random((5, 6, 8, 3)) < 0.4
    pattern = sensors.cfa_pattern(name)
    got = sensors.sensor_frames(frames, pattern)  # no flux needed: every pixel sees one channel
    bits, single = sensors.channel_bits(frames, pattern)
    assert single.all() and got.dtype == np.bool_ and got.shape == (5, 6, 8)
    assert np.array_equal(got, bits)


@pytest.mark.parametrize("cfa", ["RGBW", "mono"])
def test_sensor_frames_of_white_pixels_need_the_flux(cfa):
    frames = np.random.default_rng(0).random((3, 4, 4, 3)) < 0.4
    with pytest.raises(ValueError, match=f"pattern {cfa}: .*give phi"):
        sensors.sensor_frames(frames, sensors.cfa_pattern(cfa))
    with pytest.raises(ValueError, match="give phi"):  # all three are needed
        sensors.sensor_frames(frames, sensors.cfa_pattern(cfa), phi=np.ones((4, 4, 3)), params=spc.SPCParams())


@pytest.mark.parametrize("white", ["sum", "mean"])
def test_sensor_frames_draw_white_pixels_at_the_rate_of_their_flux(white):
    k, h, w = 4000, 4, 4
    params = spc.SPCParams(q=0.45, exposure_s=1e-4, dark_count_rate=100.0, frames=1)  # frames: set from the cube
    phi = np.broadcast_to(np.array([2000.0, 5000.0, 1000.0]), (h, w, 3))
    frames = np.random.default_rng(1).random((k, h, w, 3)) < 0.2
    pattern = sensors.cfa_pattern("RGBW", white)
    got = sensors.sensor_frames(frames, pattern, phi, params, np.random.default_rng(2))
    bits, single = sensors.channel_bits(frames, pattern)
    assert got.shape == (k, h, w) and got.dtype == np.bool_
    assert np.array_equal(got[:, single], bits[:, single])  # R, G, B keep the simulated bits exactly
    assert (~single).sum() == 4  # the W site of each 2x2 tile
    flux = phi[0, 0].sum() if white == "sum" else phi[0, 0].mean()
    p = 1.0 - np.exp(-(params.q * flux + params.dark_count_rate) * params.exposure_s)
    n = k * (~single).sum()
    rate = got[:, ~single].mean()
    assert abs(rate - p) < 5 * np.sqrt(p * (1 - p) / n)  # 16000 draws
    assert abs(rate - 0.2) > 0.05  # not the channel bits (which fire at 0.2)


def test_sensor_input_of_a_mono_cube_is_gray():
    cube = np.random.default_rng(3).random((6, 5, 7)) < 0.3
    x = sensors.sensor_input(cube, sensors.cfa_pattern("mono"))
    assert x.shape == (5, 7, 3) and x.dtype == np.float32
    assert np.array_equal(x[..., 0], x[..., 1]) and np.array_equal(x[..., 1], x[..., 2])
    np.testing.assert_allclose(x[..., 0], cube.mean(0) / sum(sensors.LUMINANCE), rtol=1e-6)


def test_sensor_input_is_the_demosaiced_mean_with_hot_pixels_filled():
    cube = np.random.default_rng(4).random((8, 6, 8)) < 0.3
    pattern = sensors.cfa_pattern("RGGB")
    valid = np.ones((6, 8), bool)
    valid[2, 2] = False
    x = sensors.sensor_input(cube, pattern, valid)
    np.testing.assert_allclose(x, sensors.demosaic_average(cube, pattern, valid), rtol=1e-6)
    hot = cube.copy()
    hot[:, 2, 2] = True  # whatever a masked pixel fires does not reach the input
    assert np.array_equal(sensors.sensor_input(hot, pattern, valid), x)


# --------------------------------------------------------------------------------------------
# the imported SPC folder


def test_imported_frames_are_the_simulated_channel_bits(sim):
    names = names_of(sim)
    spc_dir = sim / "cap_spc"
    pattern = sensors.cfa_pattern("RGGB")
    for name in names:
        got = imported_frames(spc_dir, name)
        assert got.dtype == np.bool_ and got.shape == (K, H, W)
        assert np.array_equal(got, sensors.channel_bits(simulated_frames(sim, name), pattern)[0])
        for kind, suffix in (("binary", "png"), ("average", "png"), ("mle", "exr")):
            assert (spc_dir / kind / f"{name}.{suffix}").is_file()
    assert sorted(p.stem for p in (spc_dir / "frames").glob("*.npz")) == names

    rec = io.read_json(spc_dir / "spc.json")
    assert rec["flux_scale"] is None and rec["flux_scale_calibrated"] is False and rec["seed"] is None
    assert rec["sensor"] == {"cfa": "RGGB", "white": "sum", "name": "RGGB"}
    assert rec["views"] == VIEWS and rec["params"]["frames"] == K
    assert spc.SPCParams(**rec["params"]) == spc.SPCParams(**io.read_json(sim / "spc" / "spc.json")["params"])
    assert 0.05 < rec["mean_detection_rate"] < 0.6
    assert rec["hot_pixels"]["from_sensor_json"] is False and rec["hot_pixels"]["count"] == 0  # a clean simulation
    assert "rates" not in rec["hot_pixels"] and "z" not in rec["hot_pixels"]

    pattern_back, valid = spc_sensor(spc_dir)
    assert pattern_back.name == "RGGB" and np.array_equal(pattern_back.tile, pattern.tile)
    assert valid.dtype == np.bool_ and valid.shape == (H, W)
    assert (~valid).sum() == rec["hot_pixels"]["count"]
    assert spc_sensor(sim / "spc") is None  # the simulator's RGB frames


def test_imported_products_are_the_demosaiced_frames(sim):
    spc_dir = sim / "cap_spc"
    pattern, valid = spc_sensor(spc_dir)
    params = spc.SPCParams(**io.read_json(spc_dir / "spc.json")["params"])
    name = names_of(sim)[1]
    cube = imported_frames(spc_dir, name)
    binary = io.read_rgb(spc_dir / "binary" / f"{name}.png")
    np.testing.assert_allclose(binary, sensors.sensor_input(cube[:1], pattern, valid), atol=0.5 / 255 + 1e-6)
    average = io.read_rgb(spc_dir / "average" / f"{name}.png")
    np.testing.assert_allclose(average, sensors.demosaic_average(cube, pattern, valid), atol=0.5 / 65535 + 1e-6)
    mle = io.read_image(spc_dir / "mle" / f"{name}.exr")
    expected = sensors.mle_rgb(cube.sum(0), K, params, pattern, ~valid)
    np.testing.assert_allclose(mle, expected, rtol=1e-3)

    names, flux = exposure.mle_views(spc_dir, K)  # the display's MLE reads the capture's sensor
    assert names == names_of(sim) and flux.shape == (VIEWS, H, W, 3) and flux.dtype == np.float32
    np.testing.assert_allclose(flux[1], expected, rtol=1e-6)
    _, fewer = exposure.mle_views(spc_dir, 4)
    np.testing.assert_allclose(fewer[1], sensors.mle_rgb(cube[:4].sum(0), 4, params, pattern, ~valid), rtol=1e-6)
    with pytest.raises(ValueError, match=f"K = {K + 1} frames asked"):
        exposure.mle_views(spc_dir, K + 1)


def test_hot_pixel_map_of_sensor_json_is_masked(sim, tmp_path):
    cap = copy_capture(sim, tmp_path)
    known = np.zeros((H, W), bool)
    known[10, 20] = True
    hot_pixels.write_hot_pixel_map(cap / "hot_pixels.png", known)
    rec = io.read_json(cap / "sensor.json")
    io.write_json(cap / "sensor.json", {**rec, "hot_pixels": "hot_pixels.png"})
    out = tmp_path / "spc"
    spc_rec = import_capture_frames(cap, sim / "cap_scene", out)
    assert spc_rec["hot_pixels"]["from_sensor_json"] is True and spc_rec["hot_pixels"]["count"] >= 1
    _, valid = spc_sensor(out)
    assert not valid[10, 20]
    assert np.array_equal(~valid & ~known, ~spc_sensor(sim / "cap_spc")[1])  # the rest: as detected before
    for name in names_of(sim):  # the frames are the capture's, whatever the map
        assert np.array_equal(imported_frames(out, name), imported_frames(sim / "cap_spc", name))


def test_planted_hot_pixel_is_detected_and_masked(sim, tmp_path):
    cap = copy_capture(sim, tmp_path)
    for path in sorted((cap / "frames").glob("*.npz")):
        cube = photon_cubes.read_cube(path)
        cube[:, HOT[0], HOT[1]] = True  # fires in every frame of every view
        photon_cubes.write_cube(path, cube)
    out = tmp_path / "spc"
    rec = import_capture_frames(cap, sim / "cap_scene", out)
    assert rec["hot_pixels"]["count"] == 1 and rec["hot_pixels"]["positions"] == [list(HOT)]
    assert io.read_json(out / "spc.json")["hot_pixels"]["positions"] == [list(HOT)]
    pattern, valid = spc_sensor(out)
    assert not valid[HOT] and valid.sum() == H * W - 1
    assert np.array_equal(~valid, hot_pixels.read_hot_pixel_map(out / "hot_pixels.png"))
    # the hot pixel's all-ones count reaches neither the MLE, the average nor the translator input
    params = spc.SPCParams(**rec["params"])
    saturated = spc.mle_flux(np.array(K), K, params)
    name = names_of(sim)[0]
    mle = io.read_image(out / "mle" / f"{name}.exr")
    assert mle[HOT][2] < 0.5 * saturated
    assert io.read_rgb(out / "average" / f"{name}.png")[HOT][2] < 0.9
    clean = sensors.sensor_input(imported_frames(sim / "cap_spc", name), pattern, valid)
    np.testing.assert_array_equal(binary_input(out / "frames" / f"{name}.npz", K, pattern, valid), clean)
    assert rec["mean_detection_rate"] == pytest.approx(
        np.mean([imported_frames(out, n).mean(0)[valid].mean() for n in names_of(sim)]), rel=1e-9
    )


# --------------------------------------------------------------------------------------------
# the imported scene folder


def test_imported_scene_keeps_the_given_poses_and_reference_views(sim):
    truth = llff.read_scene(sim / "scene")
    got = llff.read_scene(sim / "cap_scene")
    assert got.names == truth.names and got.meta["reference"] is True
    assert got.meta["source"] == "capture" and got.meta["sensor"] == "RGGB" and got.meta["colour"] is True
    assert got.meta["poses"] == {"source": "poses_bounds.npy"}
    assert (got.cameras.height, got.cameras.width) == (H, W)
    np.testing.assert_allclose(got.cameras.w2c, truth.cameras.w2c, atol=1e-9)
    np.testing.assert_allclose(got.cameras.intrinsics, truth.cameras.intrinsics, rtol=1e-9)
    np.testing.assert_allclose(got.cameras.bounds, truth.cameras.bounds, rtol=1e-9)
    assert np.array_equal(got.images, truth.images)


def test_imported_scene_without_images_has_no_reference(sim, tmp_path):
    cap = copy_capture(sim, tmp_path)
    shutil.rmtree(cap / "images")
    out = tmp_path / "scene"
    rec = import_capture_scene(cap, out)
    meta = io.read_json(out / "scene.json")
    assert meta["reference"] is False and meta["names"] == names_of(sim)
    assert rec["poses"]["source"] == "poses_bounds.npy"
    assert not (out / "images").exists() and not llff.has_reference(out)
    back = llff.read_scene(out, with_images=False)
    np.testing.assert_allclose(back.cameras.w2c, llff.read_scene(sim / "scene").cameras.w2c, atol=1e-9)
    with pytest.raises(llff.NoReference):
        llff.read_scene(out)
    spc_rec = import_capture_frames(cap, out, tmp_path / "spc")  # the SPC folder needs no reference
    assert spc_rec["views"] == VIEWS
    for name in names_of(sim):
        assert np.array_equal(imported_frames(tmp_path / "spc", name), imported_frames(sim / "cap_spc", name))


def test_bad_capture_poses_and_images_are_named(sim, tmp_path):
    cap = copy_capture(sim, tmp_path)
    pb = np.load(cap / "poses_bounds.npy")
    np.save(cap / "poses_bounds.npy", pb[:-1])
    with pytest.raises(ValueError, match=rf"poses_bounds.npy has {VIEWS - 1} rows but .*frames holds {VIEWS} views"):
        import_capture_scene(cap, tmp_path / "a")
    np.save(cap / "poses_bounds.npy", pb)
    small = io.read_rgb(cap / "images" / "image000.png")[:, :-2]
    for p in (cap / "images").glob("*.png"):
        io.write_image(p, small)
    with pytest.raises(ValueError, match=rf"images: reference views are {W - 2}x{H} but the sensor is {W}x{H}"):
        import_capture_scene(cap, tmp_path / "b")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert MIN_POSED >= 3


# --------------------------------------------------------------------------------------------
# translator inputs


def test_binary_input_of_a_capture_needs_its_pattern(sim):
    path = sim / "cap_spc" / "frames" / f"{names_of(sim)[0]}.npz"
    with pytest.raises(ValueError, match=r"one bit per pixel .*no sensor pattern"):
        binary_input(path, 4)
    pattern, valid = spc_sensor(sim / "cap_spc")
    x = binary_input(path, 4, pattern, valid)
    assert x.shape == (H, W, 3) and x.dtype == np.float32 and 0.0 <= x.min() and x.max() <= 1.0
    cube = imported_frames(sim / "cap_spc", names_of(sim)[0])
    np.testing.assert_array_equal(x, sensors.sensor_input(cube[:4], pattern, valid))
    with pytest.raises(ValueError, match=rf"stage1.frames={K + 1} but .*stores K={K}"):
        binary_input(path, K + 1, pattern, valid)


def test_binary_input_of_simulated_frames_as_a_sensor_records_them(sim):
    name = names_of(sim)[0]
    path = sim / "spc" / "frames" / f"{name}.npz"
    frames = simulated_frames(sim, name)
    plain = binary_input(path, 3)
    assert plain.shape == (H, W, 3) and plain.dtype == np.float32
    np.testing.assert_array_equal(plain, frames[:3].mean(0, dtype=np.float32))
    rggb = sensors.cfa_pattern("RGGB")
    np.testing.assert_array_equal(
        binary_input(path, 3, rggb), sensors.sensor_input(sensors.channel_bits(frames[:3], rggb)[0], rggb)
    )
    # the capture's input is the same picture: its frames are the simulated channel bits
    capture = imported_frames(sim / "cap_spc", name)
    valid = np.ones((H, W), bool)
    np.testing.assert_array_equal(binary_input(path, 3, rggb), sensors.sensor_input(capture[:3], rggb, valid))
    with pytest.raises(ValueError, match="give phi"):
        binary_input(path, 3, sensors.cfa_pattern("RGBW"))


def test_load_pairs_records_the_inputs_as_the_sensor(sim, tmp_path):
    augment.augment_scene(sim / "scene", sim / "spc", tmp_path / "aug", 2, augment.AugmentSettings(), seed=1)
    frames = [spc.unpack_frames(*io.load_frames(tmp_path / "aug" / "frames" / f"{i:05d}.npz")) for i in range(2)]
    plain, rgb = load_pairs([tmp_path / "aug"], 4)
    assert len(plain) == len(rgb) == 2 and plain[0].shape == rgb[0].shape == (3, H, W)
    torch.testing.assert_close(plain[0], torch.from_numpy(frames[0][:4].mean(0, dtype=np.float32)).permute(2, 0, 1))
    rggb = sensors.cfa_pattern("RGGB")
    bayer, rgb2 = load_pairs([tmp_path / "aug"], 4, {"cfa": "RGGB", "white": "sum"})
    for b, f in zip(bayer, frames):
        expected = sensors.sensor_input(sensors.channel_bits(f[:4], rggb)[0], rggb)
        torch.testing.assert_close(b, torch.from_numpy(expected).permute(2, 0, 1), rtol=0, atol=0)
    assert all(torch.equal(a, b) for a, b in zip(rgb, rgb2))
    white, _ = load_pairs([tmp_path / "aug"], 4, {"cfa": "RGBW"})  # W drawn from the pair's RGB, seeded
    again, _ = load_pairs([tmp_path / "aug"], 4, {"cfa": "RGBW"})
    assert all(torch.equal(a, b) for a, b in zip(white, again))
    assert all(w.shape == (3, H, W) and 0 <= w.min() and w.max() <= 1 for w in white)


def write_train_json(folder, sensor):
    folder.mkdir(parents=True)
    (folder / "train.json").write_text(json.dumps({"method": "pix2pix", "sensor": sensor}))
    return folder


def test_translator_sensor_must_match_the_scene(sim, tmp_path):
    rgb_model = write_train_json(tmp_path / "rgb", None)
    rggb_model = write_train_json(tmp_path / "rggb", {"cfa": "RGGB", "white": "sum"})
    bggr_model = write_train_json(tmp_path / "bggr", {"cfa": "BGGR", "white": "sum"})
    with pytest.raises(ValueError, match=r"trained on inputs of the simulated RGB sensor but .* holds rggb frames"):
        input_sensor(rgb_model, sim / "cap_spc")
    with pytest.raises(ValueError, match=r"trained on inputs of the rggb sensor but .* holds simulated RGB frames"):
        input_sensor(rggb_model, sim / "spc")
    with pytest.raises(ValueError, match=r"bggr sensor but .* holds rggb frames"):
        input_sensor(bggr_model, sim / "cap_spc")
    pattern, valid = input_sensor(rggb_model, sim / "cap_spc")
    assert pattern.name == "RGGB" and valid.shape == (H, W) and valid.dtype == np.bool_
    assert input_sensor(rgb_model, sim / "spc") == (None, None)
    assert input_sensor(tmp_path / "no_train_json", sim / "spc") == (None, None)


def test_sensor_tags_name_one_training_per_sensor(sim, tmp_path):
    assert sensor_tag(sensors.cfa_pattern("RGGB")) == "rggb"
    assert sensor_tag(sensors.cfa_pattern("RGBW", "mean")) == "rgbwmean"
    assert sensor_tag(sensors.cfa_pattern("mono")) == "mono"
    tile = [[[255, 0, 0], [255, 255, 255]], [[0, 255, 0], [0, 0, 255]]]
    custom = sensor_tag(sensors.cfa_pattern(tile))
    assert re.fullmatch(r"custom[0-9a-f]{8}", custom) and custom == sensor_tag(sensors.cfa_pattern(tile))
    other = [[[255, 0, 0], [0, 255, 0]], [[255, 255, 255], [0, 0, 255]]]
    assert sensor_tag(sensors.cfa_pattern(other)) != custom
    assert capture_sensor(sim / "cap") == ("rggb", {"cfa": "RGGB", "white": "sum"})


# --------------------------------------------------------------------------------------------
# stage-2 targets


def test_sensor_targets_pack_the_mosaic(sim):
    spc_dir = sim / "cap_spc"
    names = names_of(sim)[:3]
    fractions = bit_fractions(spc_dir, names, 8)
    assert fractions.shape == (3, H, W) and fractions.dtype == np.float32
    obj = BernoulliObjective(flux_scale=1000.0, q=0.45, exposure_s=1e-4, dark_count_rate=100.0)
    # a hot pixel in the SPC folder's map (as the import writes it)
    _, valid = spc_sensor(spc_dir)
    targets, objective = sensor_targets(spc_dir, fractions, obj)
    assert targets.shape == (3, H, W, 5) and targets.dtype == np.float32
    assert isinstance(objective, sensors.MosaicBernoulliObjective) and objective.base is obj
    np.testing.assert_array_equal(targets[..., 0], fractions)
    mask = sensors.cfa_mask(sensors.cfa_pattern("RGGB"), H, W)
    np.testing.assert_array_equal(targets[..., 1:4], np.broadcast_to(mask, (3, H, W, 3)))
    np.testing.assert_array_equal(targets[..., 4], np.broadcast_to(valid.astype(np.float32), (3, H, W)))
    pred = torch.rand(3, H, W, 3, generator=torch.Generator().manual_seed(0))
    loss = objective.loss(pred, torch.from_numpy(targets))
    expected = sensors.mosaic_bernoulli_loss(
        obj, pred, torch.from_numpy(fractions), torch.from_numpy(mask), torch.from_numpy(valid)
    )
    torch.testing.assert_close(loss, expected)

    rgb = bit_fractions(sim / "spc", names, 8)  # the simulator's RGB fractions pass through
    same, objective = sensor_targets(sim / "spc", rgb, obj)
    assert same is rgb and objective is obj and rgb.shape == (3, H, W, 3)


def test_sensor_targets_zero_the_hot_pixels(sim, tmp_path):
    spc_dir = tmp_path / "spc"
    shutil.copytree(sim / "cap_spc", spc_dir)
    hot = np.zeros((H, W), bool)
    hot[HOT] = hot[0, 3] = True
    hot_pixels.write_hot_pixel_map(spc_dir / "hot_pixels.png", hot)
    fractions = bit_fractions(spc_dir, names_of(sim)[:2], K)
    obj = BernoulliObjective(flux_scale=1000.0, q=0.45, exposure_s=1e-4, dark_count_rate=100.0)
    targets, _ = sensor_targets(spc_dir, fractions, obj)
    np.testing.assert_array_equal(targets[..., 4], np.broadcast_to((~hot).astype(np.float32), (2, H, W)))


# --------------------------------------------------------------------------------------------
# the config: captures


def base_config():
    return yaml.safe_load((REPO / "config.yaml").read_text())


def test_capture_in_scenes_eval_is_a_capture_spec(sim):
    cfg = base_config() | {
        "captures": {"mycap": str(sim / "cap")},
        "scenes": {"train": ["tabletop"], "eval": ["mycap"]},
    }
    specs = scene_specs(cfg, sorted(LAYOUTS), REPO)
    assert specs["tabletop"]["kind"] == "builtin"
    spec = specs["mycap"]
    assert spec["kind"] == "capture" and spec["path"] == str(sim / "cap")
    assert spec["sensor_tag"] == "rggb" and spec["sensor"] == {"cfa": "RGGB", "white": "sum"}
    assert spec["reference"] is True
    assert spec["max_features"] == cfg["colmap"]["max_features"] and spec["seed"] == cfg["seed"]
    rel = base_config() | {"captures": {"mycap": "cap"}, "scenes": {"train": [], "eval": ["mycap"]}}
    assert scene_specs(rel, sorted(LAYOUTS), sim)["mycap"]["path"] == str(sim / "cap")  # relative to base_dir


def test_capture_config_errors_are_named(sim, tmp_path):
    cfg = base_config() | {
        "captures": {"mycap": str(sim / "cap")},
        "scenes": {"train": ["mycap"], "eval": ["courtyard"]},
    }
    with pytest.raises(ConfigError, match=r"scenes.train lists capture 'mycap'.*scenes.eval"):
        scene_specs(cfg, sorted(LAYOUTS), REPO)
    (tmp_path / "empty").mkdir()
    cfg = base_config() | {"captures": {"mycap": str(tmp_path / "empty")}, "scenes": {"train": [], "eval": ["mycap"]}}
    with pytest.raises(ConfigError, match=r"captures.mycap: .*empty is not a capture folder \(no sensor.json"):
        scene_specs(cfg, sorted(LAYOUTS), REPO)
    cap = copy_capture(sim, tmp_path)
    rec = io.read_json(cap / "sensor.json")
    io.write_json(cap / "sensor.json", {**rec, "cfa": "XYZ"})
    cfg = base_config() | {"captures": {"mycap": str(cap)}, "scenes": {"train": [], "eval": ["mycap"]}}
    with pytest.raises(ConfigError, match=r"captures.mycap: .*sensor.json"):
        scene_specs(cfg, sorted(LAYOUTS), REPO)


def _sensor_json(key, value):
    def damage(cap):
        rec = io.read_json(cap / "sensor.json")
        io.write_json(cap / "sensor.json", {**rec, key: value(rec) if callable(value) else value})

    return damage


def _swap_size(cap):
    rec = io.read_json(cap / "sensor.json")
    io.write_json(cap / "sensor.json", {**rec, "width": rec["height"], "height": rec["width"]})


def _extra_pose(cap):
    pb = np.load(cap / "poses_bounds.npy")
    np.save(cap / "poses_bounds.npy", np.concatenate([pb, pb[:1]]))


def _bool_npy(cap):
    _sensor_json("format", "npy")(cap)
    for f in (cap / "frames").glob("*.npz"):
        np.save(f.with_suffix(".npy"), np.zeros((K, H, W), bool))
        f.unlink()


DAMAGED_CAPTURES = {  # damage -> what the parse-time message must say
    "fewer frames than sensor.json": (
        _sensor_json("frames", K + 1),
        rf"{K} frames; sensor.json says .*frames = {K + 1}",
    ),
    "width and height swapped": (_swap_size, r"width and height look swapped"),
    "a reference view missing": (
        lambda cap: (cap / "images" / "image001.png").unlink(),
        r"no reference image .*image001",
    ),
    "more poses than views": (_extra_pose, rf"poses_bounds.npy: {VIEWS + 1} rows of poses for {VIEWS} views"),
    "no files in the declared format": (_sensor_json("format", "npy.gz"), r"no views in format 'npy.gz'"),
    "wrong dtype": (_bool_npy, r"holds a bool array .*expected uint8 \(K, H, ceil\(W/8\)\)"),
}


@pytest.mark.parametrize("damage", sorted(DAMAGED_CAPTURES))
def test_a_damaged_capture_folder_is_refused_at_parse_time_by_name(sim, tmp_path, damage):
    """Checked from headers and listings when the workflow parses (scene_specs), before any job."""
    cap = copy_capture(sim, tmp_path)
    change, match = DAMAGED_CAPTURES[damage]
    change(cap)
    cfg = base_config() | {"captures": {"mycap": str(cap)}, "scenes": {"train": [], "eval": ["mycap"]}}
    with pytest.raises(ConfigError, match=rf"captures\.mycap: .*{match}"):
        scene_specs(cfg, sorted(LAYOUTS), REPO)


# --------------------------------------------------------------------------------------------
# intrinsics of a capture posed by COLMAP


def fake_sensor(record, width=32, height=24):
    return SimpleNamespace(record=record, width=width, height=height)


def test_first_intrinsics_guess_or_given(tmp_path):
    values, guess = first_intrinsics(fake_sensor({}), tmp_path / "sensor.json")
    assert guess is True
    np.testing.assert_allclose(values, [1.2 * 32, 1.2 * 32, 16.0, 12.0])
    values, guess = first_intrinsics(fake_sensor({}, width=20, height=50), tmp_path / "sensor.json")
    np.testing.assert_allclose(values, [60.0, 60.0, 10.0, 25.0])
    values, guess = first_intrinsics(fake_sensor({"intrinsics": [30, 31.5, 15, 11]}), tmp_path / "sensor.json")
    assert guess is False and values.dtype == np.float64
    np.testing.assert_array_equal(values, [30.0, 31.5, 15.0, 11.0])


@pytest.mark.parametrize("bad", [[30, 30, 16], [0, 30, 16, 12], [30, -1, 16, 12], [float("nan"), 30, 16, 12], 42])
def test_bad_intrinsics_are_named(tmp_path, bad):
    with pytest.raises(ValueError, match=r"sensor.json: intrinsics=.*\[fx, fy, cx, cy\]"):
        first_intrinsics(fake_sensor({"intrinsics": bad}), tmp_path / "sensor.json")


@pytest.mark.parametrize("bad", [["f", 30, 16, 12], {"fx": 30}])
def test_non_numeric_intrinsics_are_named(tmp_path, bad):
    with pytest.raises(ValueError, match=r"sensor.json: intrinsics="):
        first_intrinsics(fake_sensor({"intrinsics": bad}), tmp_path / "sensor.json")


def test_config_sensor_settings_replace_sensor_json(sim, tmp_path):
    """captures.<name> as {path, q, dark_count_rate, hot_pixels}: the import uses and records them."""
    cap = copy_capture(sim, tmp_path)
    known = np.zeros((H, W), bool)
    known[5, 7] = True
    hot_pixels.write_hot_pixel_map(tmp_path / "known_hot.png", known)  # outside the capture folder
    overrides = {"q": 0.3, "dark_count_rate": 250.0, "hot_pixels": str(tmp_path / "known_hot.png")}
    rec = import_capture_frames(cap, sim / "cap_scene", tmp_path / "spc", overrides)
    assert rec["params"]["q"] == 0.3 and rec["params"]["dark_count_rate"] == 250.0
    assert rec["sensor_from_config"]["q"] == 0.3
    assert rec["sensor_json_values"]["q"] == io.read_json(cap / "sensor.json")["q"]
    assert rec["hot_pixels"]["from_sensor_json"] and not spc_sensor(tmp_path / "spc")[1][5, 7]
    with pytest.raises(ValueError, match=r"sensor settings \['cfa'\].*the config may set"):
        captures.read_sensor(cap, {"cfa": "mono"})
    cfg = base_config() | {
        "captures": {"mycap": {"path": str(cap), "q": 0.3}},
        "scenes": {"train": [], "eval": ["mycap"]},
    }
    spec = scene_specs(cfg, sorted(LAYOUTS), REPO)["mycap"]
    assert spec["path"] == str(cap) and spec["overrides"] == {"q": 0.3}

"""The scored (held-out) views stay unseen by every non-oracle input: replacing their ground-truth
images and their frames changes neither the simulated camera's exposure, nor a training view's
frames and images, nor the metered display gains, nor a stage-2 fit, nor a capture's hot pixels."""

import shutil

import numpy as np
import pytest

from spc3d import io
from spc3d.cameras import split_views
from spc3d.captures import folders as captures
from spc3d.captures import photon_cubes
from spc3d.captures.importing import import_capture_frames, import_capture_scene
from spc3d.inputs import exposure
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct

TINY_3DGS = {"iterations": 8, "densify_from": 4, "densify_until": 6, "densify_every": 2, "init_points": 200}
VIEWS, K, S = 9, 2, 2
TRAIN, TEST = (list(map(int, v)) for v in split_views(VIEWS))  # views 1..7 train, 0 and 8 are scored
NAMES = [f"image{i:03d}" for i in range(VIEWS)]
PRODUCTS = {"frames": "npz", "binary": "png", "capture": "png", "average": "png", "mle": "exr"}


def _simulate(scene, out):
    return simulate_scene(scene, out, spc.SPCParams(frames=K), seed=0, capture_factor=S)


def _replace_scored_frames(spc_dir):
    """Another measurement of the scored views: every bit flipped (frames and capture frame)."""
    for i in TEST:
        path = spc_dir / "frames" / f"{NAMES[i]}.npz"
        io.save_frames(path, *spc.pack_frames(~spc.unpack_frames(*io.load_frames(path))))
        capture = spc_dir / "capture" / f"{NAMES[i]}.png"
        io.write_image(capture, 1.0 - io.read_rgb(capture), bits=16)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """The same scene twice (same folder name: the same noise streams), the second with its scored
    views' images inverted before simulating and their frames flipped after; a training scene
    (gallery) for the display level."""
    root = tmp_path_factory.mktemp("heldout_unseen")
    write_builtin_scene("tabletop", root / "a" / "tabletop", height=24, width=32, views=VIEWS, supersample=1, seed=0)
    shutil.copytree(root / "a" / "tabletop", root / "b" / "tabletop")
    for i in TEST:
        path = root / "b" / "tabletop" / "images" / f"{NAMES[i]}.png"
        io.write_image(path, 1.0 - io.read_rgb(path))
    records = {side: _simulate(root / side / "tabletop", root / side / "spc") for side in "ab"}
    _replace_scored_frames(root / "b" / "spc")
    write_builtin_scene("gallery", root / "train" / "gallery", height=24, width=32, views=VIEWS, supersample=1)
    _simulate(root / "train" / "gallery", root / "train" / "spc")
    for capture in (False, True):
        k = 1 if capture else K
        cal = root / f"display-{'capture' if capture else f'k{K}'}.json"
        exposure.calibrate_display([root / "train" / "gallery"], [root / "train" / "spc"], k, cal, capture=capture)
        for side in "ab":
            out = root / side / ("capture" if capture else f"mle-k{K}")
            exposure.write_display(root / side / "spc", cal, k, out, capture=capture)
    return root, records


def _content(path):
    """What a file holds: the frames of an .npz, the pixels of an image (EXR headers carry a date)."""
    return spc.unpack_frames(*io.load_frames(path)) if path.suffix == ".npz" else io.read_image(path)


def _same_files(root, sub, names):
    for name in names:
        a, b = (next((root / side / sub).glob(f"{name}.*")) for side in "ab")
        assert np.array_equal(_content(a), _content(b)), a.relative_to(root)


def test_the_exposure_is_metered_on_the_training_views(pair):
    root, records = pair
    assert records["a"]["flux_scale"] == records["b"]["flux_scale"]
    assert records["a"]["exposure"] == records["b"]["exposure"]  # what the camera reports, every row may read
    assert records["a"]["metered_views"] == len(TRAIN) and records["a"]["held_out_views"] == [NAMES[i] for i in TEST]


def test_training_frames_and_images_are_unchanged(pair):
    root, _ = pair
    for kind in PRODUCTS:
        _same_files(root, f"spc/{kind}", [NAMES[i] for i in TRAIN])
        scored = [_content(root / side / "spc" / kind / f"{NAMES[0]}.{PRODUCTS[kind]}") for side in "ab"]
        assert not np.array_equal(*scored), kind  # the change did reach the scored views


def test_metered_gains_and_training_displays_are_unchanged(pair):
    root, _ = pair
    for sub in (f"mle-k{K}", "capture"):
        rec = {side: io.read_json(root / side / sub / "display.json") for side in "ab"}
        for key in ("gain", "gain_likelihood", "flux_per_linear", "exposure"):
            assert rec["a"][key] == rec["b"][key], (sub, key)
        assert rec["a"]["views"] == VIEWS
        assert rec["a"]["capture_factor"] == (S if sub == "capture" else 1)
        _same_files(root, f"{sub}/images", [NAMES[i] for i in TRAIN])
        assert len(list((root / "a" / sub / "images").glob("*.png"))) == VIEWS  # scored views: outputs too


def test_a_stage2_fit_is_unchanged(pair):
    """A tiny 3DGS fit on the metered MLE and on the SPAD likelihood: the same model, so the same
    training loss and the same renders (the renders are of the scored views, from the model alone)."""
    root, _ = pair
    for source in (f"mle-k{K}", f"bernoulli-k{K}"):
        rec = {
            side: reconstruct(
                ReconstructJob(
                    root / side / "tabletop",
                    root / side / "recon" / source,
                    source,
                    "3dgs",
                    TINY_3DGS,
                    seed=1,
                    spc_dir=root / side / "spc",
                    frames=K,
                    display_dir=root / side / f"mle-k{K}",
                    threads=1,
                )
            )
            for side in "ab"
        }
        assert rec["a"]["final_loss"] == rec["b"]["final_loss"], source
        _same_files(root, f"recon/{source}/renders", [NAMES[i] for i in TEST])


def _plant(cap, views, pixel):
    """``pixel`` fires in every frame of ``views`` of capture folder ``cap``."""
    for i in views:
        path = photon_cubes.cube_path(cap / "frames", NAMES[i], "npz")
        cube = photon_cubes.read_cube(path)
        cube[:, pixel[0], pixel[1]] = True
        photon_cubes.write_cube(path, cube)


def test_a_captures_hot_pixels_ignore_the_scored_views(pair, tmp_path):
    """A pixel fires in every frame of the training views (too few frames to call it hot from them);
    in the second capture it fires in the scored views too, which would make it hot if they were
    counted. The hot-pixel maps and the training views' imported products are the same."""
    root, _ = pair
    hot = (3, 15)  # a G site where the training views alone leave the z-score under 6 (measured)
    cap = {side: tmp_path / side / "cap" for side in "ab"}
    captures.export_simulated(root / "a" / "spc", cap["a"], "RGGB", "npz", scene_dir=root / "a" / "tabletop")
    _plant(cap["a"], TRAIN, hot)
    shutil.copytree(cap["a"], cap["b"])
    _plant(cap["b"], TEST, hot)
    counts = {side: [c.sum(0, dtype=np.int64) for c in captures.read_capture(cap[side])[1]] for side in "ab"}
    sensor = captures.read_sensor(cap["a"])
    assert captures.capture_hot_pixels(counts["b"], sensor)[0][hot]  # counting every view would see it ...
    assert not captures.capture_hot_pixels(counts["a"], sensor)[0][hot]  # ... only in the second capture
    for side in "ab":
        import_capture_scene(cap[side], tmp_path / side / "scene")
        import_capture_frames(cap[side], tmp_path / side / "scene", tmp_path / side / "spc")
    rec = {side: io.read_json(tmp_path / side / "spc" / "spc.json") for side in "ab"}
    assert rec["a"]["hot_pixels"]["positions"] == rec["b"]["hot_pixels"]["positions"] == []
    assert rec["a"]["held_out_views"] == [NAMES[i] for i in TEST]
    assert np.array_equal(*(_content(tmp_path / side / "spc" / "hot_pixels.png") for side in "ab"))
    for kind in PRODUCTS:
        _same_files(tmp_path, f"spc/{kind}", [NAMES[i] for i in TRAIN])

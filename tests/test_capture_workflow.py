"""Captured SPAD scenes through the workflow: simulate -> export as photon cubes -> import as a
capture -> the same rows, scored as the simulated route is (spc3d.captures.importing)."""

import dataclasses
import os

import numpy as np
import pandas as pd
import pytest
import yaml

from spc3d import io, llff
from spc3d.captures.folders import export_simulated
from spc3d.inputs.build import prepare_scene, simulate_scene
from spc3d.physics import sensors, spc
from spc3d.physics.record import params_from_record, read_spc_record
from spc3d.poses.alignment import pose_error

from conftest import REPO, run_snakemake

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
ROWS = ["pix2pix+3dgs", "gt+3dgs", "none+3dgs", "bernoulli+3dgs", "mle-k4+3dgs"]


def write_config(path, settings):
    path.write_text(yaml.safe_dump(settings))
    return str(path)


@pytest.mark.slow
def test_exported_capture_scores_as_the_simulated_scene(tmp_path, lpips_cache):
    """An RGGB export of courtyard, imported as a capture beside courtyard itself: its frames are the
    simulated channel bits, its translators are trained for RGGB, and every row scores close to the
    simulated route (a Bayer sensor keeps one of the three bits per pixel)."""
    res = tmp_path / "results"
    local = {"metrics": {"lpips_source": str(lpips_cache)}}
    configs = ["--configfile", str(SMOKE), write_config(tmp_path / "local.yaml", local)]
    first = run_snakemake(tmp_path, "results/spc/courtyard", "results/scenes/courtyard", "--cores", "2", *configs)
    assert first.returncode == 0, first.stderr[-3000:]
    capture = tmp_path / "captures" / "cap"
    export_simulated(res / "spc" / "courtyard", capture, "RGGB", "npy.gz", scene_dir=res / "scenes" / "courtyard")
    cap_cfg = {
        **local,
        "scenes": {"train": ["tabletop"], "eval": ["courtyard", "cap"]},
        "captures": {"cap": str(capture)},
        "stage2": {"combinations": ROWS},
    }
    configs[-1] = write_config(tmp_path / "cap.yaml", cap_cfg)
    proc = run_snakemake(tmp_path, "--cores", "2", *configs)
    assert proc.returncode == 0, proc.stderr[-4000:]
    # The imported frames are the simulated channel bits, bit for bit.
    pattern = sensors.cfa_pattern("RGGB")
    sim = spc.unpack_frames(*io.load_frames(res / "spc" / "courtyard" / "frames" / "image003.npz"))
    cap = spc.unpack_frames(*io.load_frames(res / "spc" / "cap" / "frames" / "image003.npz"))
    assert cap.shape == sim.shape[:3] and np.array_equal(cap, sensors.channel_bits(sim, pattern)[0])
    rec = io.read_json(res / "spc" / "cap" / "spc.json")
    assert rec["flux_scale"] is None and rec["sensor"]["name"] == "RGGB" and rec["capture"] == str(capture)
    # One translator per sensor: the simulator's RGB and the capture's RGGB.
    assert io.read_json(res / "models-rggb" / "pix2pix" / "train.json")["sensor"] == {"cfa": "RGGB", "white": "sum"}
    assert io.read_json(res / "models" / "pix2pix" / "train.json")["sensor"] is None
    assert io.read_json(res / "translate" / "cap" / "pix2pix" / "translate.json")["sensor"] == "RGGB"
    scores = {
        (scene, row): io.read_json(res / "eval" / scene / row / "metrics.json")["mean"]["psnr"]
        for scene in ("courtyard", "cap")
        for row in ROWS
    }
    assert scores["cap", "gt+3dgs"] == pytest.approx(scores["courtyard", "gt+3dgs"], abs=1e-6)  # same views, poses
    for row in ("pix2pix+3dgs", "bernoulli+3dgs", "mle-k4+3dgs", "none+3dgs"):
        assert abs(scores["cap", row] - scores["courtyard", row]) < 1.5, (row, scores)
    summary = pd.read_csv(res / "summary" / "data_summary.csv", index_col=0)
    assert summary.loc["cap", "sensor"] == "RGGB" and summary.loc["cap", "source"] == "capture"
    stage1 = io.read_json(res / "stage1" / "cap" / "pix2pix.json")
    assert np.isfinite(stage1["mean"]["psnr"])


def simulated_capture(tmp_path, frames):
    """A 128 x 96 courtyard simulated at ``frames`` frames per view, exported as an RGGB capture
    without poses and without reference views; returns (capture folder, the truth's scene folder)."""
    scene = tmp_path / "truth" / "courtyard"
    spec = {"kind": "builtin", "layout": "courtyard", "height": 96, "width": 128, "views": 24, "supersample": 1}
    prepare_scene({**spec, "seed": 0}, scene)
    params = dataclasses.replace(spc.SPCParams(), frames=frames)
    simulate_scene(scene, tmp_path / "truth" / "spc", params, seed=0)
    capture = tmp_path / "captures" / "dark"
    export_simulated(tmp_path / "truth" / "spc", capture, "RGGB", "npy")  # no scene_dir: no images, no poses
    assert not (capture / "images").exists() and not (capture / "poses_bounds.npy").exists()
    return capture, scene


@pytest.mark.slow
def test_capture_without_poses_or_reference_runs_on_photon_poses(tmp_path, lpips_cache):
    """No poses_bounds.npy, no images/: COLMAP poses every view from its MLE image (focal refined
    from a guess), the rows reconstruct on those cameras and are recorded unscored."""
    capture, truth = simulated_capture(tmp_path, 64)
    cfg = {
        "metrics": {"lpips_source": str(lpips_cache)},
        "scenes": {"train": ["tabletop"], "eval": ["dark"]},
        "captures": {"dark": str(capture)},
        "spc": {"frames": 64},  # the training scenes' K: the display level of the K = 64 MLE row is fitted on them
        "stage2": {"combinations": ["mle-k64+3dgs", "bernoulli+3dgs", "gt+3dgs"]},
    }
    configs = ["--configfile", str(SMOKE), write_config(tmp_path / "dark.yaml", cfg)]
    proc = run_snakemake(tmp_path, "--cores", "2", *configs)
    assert proc.returncode == 0, proc.stderr[-4000:]
    res = tmp_path / "results"
    meta = io.read_json(res / "scenes" / "dark" / "scene.json")
    assert meta["reference"] is False and meta["poses"]["registered"] >= 20 and meta["poses"]["frames"] == 64
    assert not llff.has_reference(res / "scenes" / "dark")
    # The photon poses agree with the truth up to a similarity.
    est = llff.read_scene(res / "scenes" / "dark", with_images=False)
    ref = llff.read_scene(truth, with_images=False)
    err = pose_error(ref.cameras, est.cameras, [ref.names.index(n) for n in est.names])
    assert err["rotation_deg"]["median"] < 3.0 and err["center_rel"]["median"] < 0.2, err
    for row in ("mle-k64+3dgs", "bernoulli+3dgs"):
        m = io.read_json(res / "eval" / "dark" / row / "metrics.json")
        assert m["reference"] is False and m["mean"] is None and len(m["renders"]) == 3
        assert m["poses"].startswith("COLMAP on every view's 64-frame MLE (the capture has no poses)")
        heldout = m["no_reference"]  # how well the renders explain the held-out views' 64 frames
        assert heldout["frames"] == 64 and heldout["views"] == 3 and 0 <= heldout["excess_nll"] < heldout["nll"]
        assert all(os.path.isfile(tmp_path / r) or os.path.isfile(r) for r in m["renders"])
    assert not (res / "eval" / "dark" / "gt+3dgs").exists()  # the oracle needs reference views
    assert not (res / "figures" / "qualitative_dark.png").exists()
    table = pd.read_csv(res / "tables" / "no_reference.csv").set_index("combination")
    assert sorted(table.index) == ["bernoulli+3dgs", "mle-k64+3dgs"] and (table["excess NLL↓"] >= 0).all()
    two = pd.read_csv(res / "tables" / "two_stage.csv")
    assert (two["runs"] == 0).all()  # unscored rows stay out of the image tables
    spc_rec = read_spc_record(res / "spc" / "dark")
    assert params_from_record(spc_rec).frames == 64

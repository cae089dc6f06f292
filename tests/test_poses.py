"""Poses from the photons (spc3d.poses.estimate): COLMAP on a source's training views, stage 2 on the estimated
cameras, evaluation after the similarity alignment, rows that could not be posed, and the table."""

import json

import numpy as np
import pytest

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.evaluation import tables
from spc3d.evaluation.evaluate import evaluate
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.names import ConfigError, parse_combination, resolve_combinations
from spc3d.poses.estimate import NoPoses, estimate_poses, estimated_views, filled_bounds
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct

TINY_3DGS = {"iterations": 30, "densify_from": 10, "densify_until": 25, "densify_every": 5, "init_points": 500}


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    """A built-in scene at 128x96 and COLMAP's poses from its RGB training views (registers at this size)."""
    root = tmp_path_factory.mktemp("poses")
    write_builtin_scene("courtyard", root / "scene", height=96, width=128, views=16, supersample=1)
    record = estimate_poses(root / "scene" / "images", root / "scene", root / "poses", "gt", None)
    return root, record


def test_colmap_poses_the_training_views_only_and_aligns_them(posed):
    root, record = posed
    scene = llff.read_scene(root / "scene", with_images=False)
    train, test = split_views(len(scene.names))
    assert record["status"] == "ok" and record["total"] == len(train) and record["registered"] >= 3
    held_out = {scene.names[i] for i in test}
    assert not held_out & set(record["cameras"]["names"])  # COLMAP never saw a held-out view
    assert record["rotation_deg"]["median"] < 2.0 and record["center_rel"]["median"] < 0.1
    names = [scene.names[i] for i in train]
    keep, cams = estimated_views(names, root / "poses")
    assert [names[i] for i in keep] == record["cameras"]["names"] and len(cams) == len(keep)
    ref = scene.cameras.subset(train[keep])
    spread = np.sqrt(((ref.centers - ref.centers.mean(0)) ** 2).sum(1).mean())
    # in the reference frame after the alignment: close to the reference cameras, same intrinsics
    assert np.median(np.linalg.norm(cams.centers - ref.centers, axis=1)) < 0.1 * spread
    np.testing.assert_allclose(cams.intrinsics, ref.intrinsics)
    assert np.isfinite(cams.bounds).all() and (cams.bounds[:, 0] < cams.bounds[:, 1]).all()
    saved = json.loads((root / "poses" / "cameras.json").read_text(), parse_constant=pytest.fail)  # no NaN
    assert saved["views_given"].startswith("training views only")
    assert (root / "poses" / "sparse" / "0").is_dir() and not (root / "poses" / "colmap").exists()


def test_stage2_trains_on_the_estimated_cameras_and_is_scored_in_the_reference_frame(posed, tmp_path, lpips_cache):
    root, record = posed
    rec = reconstruct(
        ReconstructJob(
            root / "scene",
            tmp_path / "recon",
            "gt",
            "3dgs",
            TINY_3DGS,
            seed=0,
            poses_dir=root / "poses",
            threads=1,
            frames=None,  # the oracle consumes no photons; neither did its RGB poses
        )
    )
    assert rec["train_views"] == record["registered"]
    assert rec["poses"]["kind"] == "estimated (COLMAP)" and rec["poses"]["source"] == "gt" and rec["frames"] is None
    scores = evaluate(tmp_path / "recon", root / "scene", tmp_path / "metrics.json", lpips_cache)
    assert scores["combination"] == "gt+3dgs@gt" and np.isfinite(scores["mean"]["psnr"])
    assert len(scores["per_view"]) == len(split_views(16)[1])


def test_too_few_posed_views_is_a_recorded_row_not_a_crash(posed, tmp_path, lpips_cache):
    root, _ = posed
    rng = np.random.default_rng(0)
    noise = tmp_path / "noise"
    for p in io.list_images(root / "scene" / "images"):  # binary noise: nothing matches
        io.write_image(noise / p.name, (rng.random((96, 128, 1)) < 0.5).astype(np.float32))
    rec = estimate_poses(noise, root / "scene", tmp_path / "poses", "none", 1)
    assert rec["status"].startswith("failed: ") and rec["cameras"] is None
    with pytest.raises(NoPoses, match="no poses from 'none'"):
        estimated_views(["image001"], tmp_path / "poses")
    out = reconstruct(
        ReconstructJob(root / "scene", tmp_path / "recon", "gt", "3dgs", TINY_3DGS, poses_dir=tmp_path / "poses")
    )
    assert out["status"].startswith(f"{tmp_path / 'poses'}: no poses") and out["frames"] == 1
    assert not (tmp_path / "recon" / "renders").exists()
    scores = evaluate(tmp_path / "recon", root / "scene", tmp_path / "metrics.json", lpips_cache)
    assert scores["mean"] is None and scores["combination"] == "gt+3dgs@none"
    df = tables.estimated_poses_table([tmp_path / "metrics.json"], tmp_path / "poses_table", {})
    assert np.isnan(df.loc[0, "psnr_mean"]) and "not reconstructed" in df.loc[0, "poses"]
    assert "| –" in (tmp_path / "poses_table.md").read_text()


def test_missing_training_image_is_named(posed, tmp_path):
    root, _ = posed
    one = io.list_images(root / "scene" / "images")[1]  # a training view; the others are missing
    io.write_image(tmp_path / "few" / one.name, io.read_rgb(one))
    with pytest.raises(FileNotFoundError, match="no image for training views"):
        estimate_poses(tmp_path / "few", root / "scene", tmp_path / "out", "pix2pix", 1)
    assert not (tmp_path / "out").exists()


def test_combination_syntax_and_budget():
    assert parse_combination("bernoulli+3dgs@mle-k16") == ("bernoulli", "3dgs", "mle-k16")
    assert parse_combination("pix2pix+nerf-grid") == ("pix2pix", "nerf-grid", None)
    assert resolve_combinations(["bernoulli+nerf@pix2pix"], "nerf-grid") == ["bernoulli+nerf-grid@pix2pix"]
    for bad in ("bernoulli+3dgs@bernoulli", "gt+3dgs@pix2pix-k4", "gt+3dgs@photos"):
        with pytest.raises(ConfigError, match="(unknown pose source|name the images COLMAP poses) .*valid|from: "):
            resolve_combinations([bad], "nerf-grid")


def test_filled_bounds():
    b = filled_bounds(np.array([[1.0, 5.0], [np.nan, np.nan], [3.0, 7.0]]))
    np.testing.assert_allclose(b, [[1.0, 5.0], [2.0, 6.0], [3.0, 7.0]])
    np.testing.assert_allclose(filled_bounds(np.full((2, 2), np.nan)), [[1.0, 100.0]] * 2)


def test_estimated_poses_table_puts_each_row_below_its_ground_truth_twin(tmp_path):
    def record(combo, psnr, poses):
        source, _, model = combo.partition("@")[0].partition("+")
        return {
            "scene": "s",
            "combination": combo,
            "seed": 0,
            "frames": 16,
            "source": source,
            "model": model,
            "poses": poses,
            "mean": {"psnr": psnr, "ssim": 0.5, "lpips_alex": 0.3, "lpips_vgg": 0.4},
            "per_view": [{"view": "v", "psnr": psnr}],
        }

    est = {
        "kind": "estimated (COLMAP)",
        "source": "mle-k16",
        "frames": 16,
        "status": "ok",
        "registered": 18,
        "total": 21,
        "rotation_deg": {"median": 0.4},
        "center_rel": {"median": 0.02},
    }
    files = []
    for combo, psnr, poses in (("mle-k16+3dgs", 26.0, "ground truth"), ("mle-k16+3dgs@mle-k16", 24.5, est)):
        files.append(tmp_path / f"{combo}.json")
        io.write_json(files[-1], record(combo, psnr, poses))
    df = tables.estimated_poses_table(files, tmp_path / "t", {"mle": "MLE"})
    assert list(df["combination"]) == ["mle-k16+3dgs", "mle-k16+3dgs@mle-k16"]
    assert df.loc[0, "poses"] == "ground truth" and df.loc[1, "poses"].startswith("COLMAP on mle-k16: 18/21")
    md = (tmp_path / "t.md").read_text()
    assert "**26.00**" in md and "**24.50**" in md  # ranked apart: ground-truth and estimated poses
    assert "rotation 0.40°" in md and "centre 2.0 %" in md
    # the paper tables leave rows on estimated poses out
    two = tables.two_stage_table(files, tmp_path / "two", "nerf-grid")
    assert "mle-k16+3dgs@mle-k16" not in set(two["combination"])

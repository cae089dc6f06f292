"""The Snakemake workflow: config checks with clear errors, dry runs, and a tiny end-to-end run."""

import re

import numpy as np
import pandas as pd
import pytest
import yaml

from spc3d import io
from spc3d.config import workflow_config
from spc3d.inputs.scenes import LAYOUTS
from spc3d.jobs import scene_fold, scene_specs, training_scene_names
from spc3d.names import (
    ConfigError,
    display_budgets,
    parse_combination,
    parse_source,
    resolve_combinations,
    scored_before_3d,
    stage1_sources,
)
from spc3d.physics import spc

from conftest import LLFF_ROOT, REPO, run_snakemake

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"


def snakemake(workdir, *args, timeout=600, **kw):
    return run_snakemake(workdir, *args, timeout=timeout, **kw)


def base_config():
    return yaml.safe_load((REPO / "config.yaml").read_text())


def test_default_config_names_only_known_scenes():
    specs = scene_specs(base_config(), sorted(LAYOUTS), REPO)
    assert set(specs) == {"tabletop", "orchard", "gallery", "courtyard"}
    assert all(s["kind"] == "builtin" for s in specs.values())
    assert len(LAYOUTS) >= 4


@pytest.mark.parametrize(
    "change,match",
    [
        ({"scenes": {"train": ["tabletop"], "eval": ["mars"]}}, r"scenes.eval: unknown scene 'mars'.*courtyard"),
        ({"scenes": {"train": ["tabletop"], "eval": ["tabletop"]}}, r"share \['tabletop'\]"),
        (
            {"scenes": {"train": [], "eval": ["fern"]}, "llff_scenes": {"fern": "/nonexistent/fern"}},
            r"llff_scenes.fern: the folder /nonexistent/fern does not exist",
        ),
    ],
)
def test_bad_scene_config_is_named(change, match):
    cfg = base_config() | change
    with pytest.raises(ConfigError, match=match):
        scene_specs(cfg, sorted(LAYOUTS), REPO)


def planned_jobs(config: dict) -> dict[str, int]:
    """Jobs per rule that a configuration plans, counted from its own lists (scenes, seeds,
    combinations, COLMAP inputs) with the library's naming rules, not copied from a dry run."""
    combos = resolve_combinations(config["stage2"]["combinations"], config["stage2"]["nerf_variant"])
    scenes, seeds = config["scenes"], config["seeds"]
    train, evaluate = training_scene_names(config), scenes["eval"]
    every = list(dict.fromkeys(train + evaluate))
    folds = {scene_fold(scene, train, scenes["leave_one_out"]) for scene in evaluate}
    methods = stage1_sources(combos)  # each trained per fold and seed, applied per scene and seed
    budgets = display_budgets(combos, config["stage2"]["frames"], config["stage1"]["frames"])
    pose_sources = {poses for c in combos if (poses := parse_combination(c)[2])}
    fits = len(combos) * len(evaluate) * seeds
    choose = config["stage2"]["joint"].get("choose") or {}
    chosen = [c for c in combos if parse_source(parse_combination(c)[0]).joint and parse_combination(c)[1] in choose]
    return {
        "all": 1,
        "lpips_weights": 1,
        "choose_joint_weight": len(chosen) * len(folds) * seeds,  # per joint row, fold and seed
        "prepare_scene": len(every),
        "simulate_scene": len(every) * seeds,
        "augment_scene": len(train) * seeds if config["stage1"]["data"] == "fixed" else 0,
        "colmap_poses": len(every) * len(config["colmap"]["inputs"]),
        "reconstruct": fits,
        "evaluate": fits,
        "estimate_poses": len(pose_sources) * len(evaluate) * seeds,
        "train_translator": len(methods) * len(folds) * seeds,
        "translate_scene": len(methods) * len(evaluate) * seeds,
        "score_images": len(scored_before_3d(combos)) * len(evaluate) * seeds,
        "calibrate_display": len(budgets) * len(folds) * seeds,
        "write_display": len(budgets) * len(evaluate) * seeds,
        "qualitative_figure": len(evaluate),
        "write_summary": 1,
        "write_all_tables": 1,
    }


def dry_run_counts(proc) -> dict[str, int]:
    """Rule -> job count from the output of ``snakemake -n --quiet rules``."""
    return {
        line.split()[0]: int(line.split()[1])
        for line in (proc.stdout + proc.stderr).splitlines()
        if len(line.split()) == 2 and line.split()[1].isdigit()
    }


def test_dry_run_lists_the_dag(tmp_path):
    proc = snakemake(tmp_path, "-n", "--quiet", "rules", timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts, expected = dry_run_counts(proc), planned_jobs(workflow_config())
    assert {rule: counts.get(rule, 0) for rule in expected} == expected
    assert set(counts) - {"total"} <= set(expected), "a rule the plan above does not count: add it"
    assert "tables" not in counts  # `tables` is an explicit target only
    # The count is not trivially met: the default plans every kind of job, and rows posed by COLMAP.
    assert min(v for rule, v in expected.items() if rule != "choose_joint_weight") >= 1  # (the findings presets')
    assert expected["estimate_poses"] >= 1


@pytest.mark.slow
def test_smoke_run_end_to_end(tmp_path, smoke_run):
    """One output path alone, then the whole DAG on the smoke preset (the session's smoke run, with
    the toy plugin models), then a no-op rerun and the tables rewritten from the metrics."""
    built = smoke_run.built
    assert built["single_rc"] == 0, built["single_err"]
    assert built["single_only_target"]  # the first target built only what it needs
    assert built["full_rc"] == 0, built["full_err"]
    work = smoke_run.copy(tmp_path / "work")
    res, configs = work / "results", smoke_run.configs
    assert (res / "spc" / "courtyard" / "spc.json").exists()
    table = pd.read_csv(res / "summary" / "data_summary.csv", index_col=0)
    assert list(table.index) == ["tabletop", "courtyard"]
    assert table.loc["courtyard", "detection_rate"] == pytest.approx(0.5, abs=0.05)  # calibrated exposure
    assert (res / "summary" / "data_summary.png").stat().st_size > 10_000
    # Records next to the outputs: seed, settings, wall time.
    rec = io.read_json(res / "spc" / "courtyard" / "spc.json")
    assert rec["seed"] == 0 and rec["params"]["frames"] == 4 and rec["wall_s"] > 0
    frames = spc.unpack_frames(*io.load_frames(res / "spc" / "courtyard" / "frames" / "image000.npz"))
    assert frames.shape == (4, 48, 64, 3) and 0.2 < frames.mean() < 0.8
    pose = io.read_json(res / "colmap" / "courtyard" / "rgb" / "pose_error.json")
    assert pose["total"] == 9 and "status" in pose
    assert len(list((res / "augment" / "tabletop" / "rgb").glob("*.png"))) == 4
    assert np.load(res / "scenes" / "tabletop" / "poses_bounds.npy").shape == (9, 17)
    assert (work / "logs" / "simulate_scene" / "courtyard.log").read_text().strip()
    assert (work / "benchmarks" / "simulate_scene" / "courtyard.tsv").exists()
    # Stage 2: every combination evaluated, the table in the paper's layout.
    metrics = io.read_json(res / "eval" / "courtyard" / "bernoulli+3dgs" / "metrics.json")
    assert set(metrics["mean"]) == {"psnr", "ssim", "lpips_alex", "lpips_vgg"} and metrics["seed"] == 0
    assert metrics["capacity"]["gaussians"] > 0 and metrics["train_s"] > 0 and len(metrics["per_view"]) == 2
    stage2 = pd.read_csv(res / "tables" / "single_stage.csv").set_index("combination")
    assert stage2.loc["gt+nerf-grid", "runs"] == 1 and np.isfinite(stage2.loc["none+3dgs", "psnr_mean"])
    assert (res / "checkpoints" / "courtyard" / "gt+3dgs" / "checkpoint.pt").exists()
    # Stage 1: trained models with records, translated views, scores before 3D, both paper tables.
    model = io.read_json(res / "models" / "pix2pixhd" / "train.json")
    assert model["seed"] == 0 and model["iterations"] == 4 and model["parameters"]["G"] > 0
    assert model["data"]["mode"] == "fixed" and model["data"]["pairs"] == 4 and model["data"]["samples"] == 4 * 2
    assert model["validation"]["views"] == ["tabletop/image000", "tabletop/image008"]
    assert [v["iteration"] for v in model["validation"]["curve"]] == [0, 2, 4] and model["stopped"]["step"] == 4
    assert (res / "models" / "restormer" / "curve.png").exists() and not (res / "models" / "cyclegan").exists()
    assert len(list((res / "translate" / "courtyard" / "diffusion" / "images").glob("*.png"))) == 9
    s1 = pd.read_csv(res / "tables" / "stage1.csv").set_index("combination")
    # smoke runs no mle row; "prior": the translators' physics prior alone, a method of its own
    assert set(s1.index) == {"pix2pixhd", "restormer", "diffusion", "prior", "toy", "none", "none-x1"}
    assert s1.loc["none", "S"] == 4 and s1.loc["none-x1", "S"] == 1  # the capture frame: 4 x 4 px per pixel
    prior = io.read_json(res / "eval" / "courtyard" / "prior+3dgs" / "metrics.json")
    assert prior["frames"] == 1 and np.isfinite(prior["mean"]["psnr"])
    assert io.read_json(res / "eval" / "courtyard" / "none+3dgs" / "metrics.json")["capture_factor"] == 4
    assert io.read_json(res / "eval" / "courtyard" / "none-x1-mse+3dgs" / "metrics.json")["loss"] == "mse"
    findings = (res / "tables" / "findings.md").read_text()
    assert "DESCRIPTIVE ONLY" in findings and "**HOLDS**" not in findings  # one run: no verdict
    two = pd.read_csv(res / "tables" / "two_stage.csv").set_index("combination")
    assert two.loc["pix2pixhd+3dgs", "runs"] == 1 and two.loc["pix2pix+nerf-grid", "runs"] == 0
    assert (res / "figures" / "qualitative_courtyard.png").stat().st_size > 10_000
    # A row on poses COLMAP estimated from the training views (posed or recorded as not reconstructed).
    posed = io.read_json(res / "poses" / "courtyard" / "gt" / "cameras.json")
    assert posed["total"] == 7 and posed["source"] == "gt"  # 9 views, 2 held out: never given to COLMAP
    est = pd.read_csv(res / "tables" / "estimated_poses.csv").set_index("combination")
    assert list(est.index) == ["gt+3dgs", "gt+3dgs@gt"] and est.loc["gt+3dgs@gt", "poses"].startswith("COLMAP on gt")
    again = snakemake(work, "-n", "--cores", "2", *configs, env=smoke_run.env)
    assert "Nothing to be done" in again.stdout + again.stderr
    # `tables` rewrites the tables from the metrics on disk and runs nothing else.
    (res / "tables" / "two_stage.md").unlink()
    tables = snakemake(work, "tables", "--cores", "2", *configs, env=smoke_run.env)
    assert tables.returncode == 0, tables.stderr[-3000:]
    assert (res / "tables" / "two_stage.md").exists()
    assert re.search(r"^tables\s+1$", tables.stdout + tables.stderr, re.M) and "reconstruct" not in tables.stderr


@pytest.mark.slow
def test_real_llff_scene_through_the_workflow(tmp_path):
    if not (LLFF_ROOT / "fern" / "poses_bounds.npy").is_file():
        pytest.skip("real LLFF scenes not available")
    cfg = tmp_path / "fern.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "scenes": {"train": [], "eval": ["fern"]},
                "llff_scenes": {"fern": str(LLFF_ROOT / "fern")},
                "resolution": {"width": 128},
                "spc": {"frames": 4},
                "colmap": {"inputs": ["rgb"]},
                # no training scene: only rows that need none
                # (no translator, no fitted display level)
                "stage2": {"combinations": ["gt+3dgs", "none+3dgs"]},
            }
        )
    )
    proc = snakemake(tmp_path, "results/summary/data_summary.md", "--cores", "2", "--configfile", str(SMOKE), str(cfg))
    assert proc.returncode == 0, proc.stderr[-4000:]
    meta = io.read_json(tmp_path / "results" / "scenes" / "fern" / "scene.json")
    assert meta["source"] == "llff" and meta["width"] == 128 and meta["height"] == 96
    pose = io.read_json(tmp_path / "results" / "colmap" / "fern" / "rgb" / "pose_error.json")
    assert pose["registered"] >= 18  # real photos register from their RGB views


@pytest.mark.parametrize("preset", ["smoke", "llff-cpu", "paper", "findings", "findings-llff"])
def test_presets_validate_and_plan(tmp_path, preset):
    """Every preset passes the schema and plans its DAG: as many jobs of each rule as its
    configuration asks for (e.g. fits: combinations x evaluation scenes x seeds; translator
    trainings: stage-1 models x folds x seeds, a repeat redraws everything random)."""
    path = REPO / "workflow" / "presets" / f"{preset}.yaml"
    if "../shared/data/llff" in path.read_text() and not (LLFF_ROOT / "fern" / "poses_bounds.npy").is_file():
        pytest.skip("the preset reads the LLFF scenes of ../shared")
    proc = snakemake(tmp_path, "-n", "--quiet", "rules", "--configfile", str(path), timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts, expected = dry_run_counts(proc), planned_jobs(workflow_config(path))
    assert {rule: counts.get(rule, 0) for rule in expected} == expected, proc.stdout[-2000:]
    assert set(counts) - {"total"} <= set(expected), "a rule the plan above does not count: add it"

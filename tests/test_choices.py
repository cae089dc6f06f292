"""Choices made inside a fold (spc3d.choices, rule choose_joint_weight): from the fold's training scenes
only, by the workflow, recorded, and applied to the fold's rows.

- The job graph: every job a fold's choices depend on (its translators, classical denoiser, display
  level, joint weights) is walked back to the data; the left-out scene appears nowhere in it, so
  changing that scene's data can move none of them. On a synthetic leave-one-out configuration, and
  on the real-scene preset where ../shared is present.
- The library: every candidate fitted and scored as its row, the best mean chosen, the choice read
  back into the row's settings; the weight reaches the fit (two candidates render differently).
- The configuration: a choice needs held-out training scenes; one stopping rule for every row.
"""

import re
import subprocess
import sys

import pytest
import yaml

from spc3d import io
from spc3d.choices import choose_joint_weight, chosen_joint
from spc3d.config import ConfigError, check_joint_choice, check_one_rule, workflow_config

from conftest import LLFF_ROOT, REPO, load_script

# The built-in scenes share content within the training and within the evaluation pool, so they cannot
# leave one out of each other: the synthetic fold is scenes.train (fold ""), the evaluation scenes left out.
TRAIN, EVAL = ["tabletop", "orchard", "gallery"], ["courtyard", "observatory"]
SYNTHETIC = {
    "scenes": {"train": TRAIN, "eval": EVAL},
    "stage1": {"validation": {"hold_out": 1}},
    "stage2": {
        "combinations": ["joint-prior+3dgs", "joint-restormer+3dgs", "restormer+3dgs", "classical+3dgs"],
        "joint": {"choose": {"3dgs": [0.1, 1.0]}},
    },
}


def dry_run_jobs(tmp_path, configfile, targets) -> list[dict]:
    """The jobs Snakemake plans for ``targets`` (a dry run): rule, wildcards, input and output files."""
    cmd = [sys.executable, "-m", "snakemake", *targets, "-n", "--cores", "1", "-s", str(REPO / "Snakefile")]
    cmd += ["--directory", str(tmp_path), "--configfile", str(configfile)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, (out.stdout + out.stderr)[-3000:]
    jobs, job = [], None
    for line in out.stdout.splitlines():
        if re.match(r"^(local)?rule \w+:", line):
            job = {"rule": line.split()[-1].rstrip(":"), "input": [], "output": [], "wildcards": {}}
            jobs.append(job)
        elif job is not None and line.startswith("    input: "):
            job["input"] = line[len("    input: ") :].split(", ")
        elif job is not None and line.startswith("    output: "):
            job["output"] = line[len("    output: ") :].split(", ")
        elif job is not None and line.startswith("    wildcards: "):
            job["wildcards"] = dict(w.split("=", 1) for w in line[len("    wildcards: ") :].split(", "))
    return jobs


def fold_targets(fold: str, rows: list[str]) -> list[str]:
    """Everything chosen or fitted for a fold ("" or "-without-{scene}"): translators, display, joint weights."""
    return [
        f"results/models{fold}/restormer",
        f"results/models{fold}/classical",
        f"results/calibration{fold}/display-k1.json",
        *(f"results/choices{fold}/{row}.json" for row in rows),
    ]


def assert_never_reads(jobs: list[dict], scene: str, source: str | None = None) -> None:
    """No planned job is of ``scene`` (wildcard) or reads a file of it (``source``: its data folder)."""
    own = re.compile(rf"(^|/){re.escape(scene)}($|/|-seed)")
    for job in jobs:
        assert job["wildcards"].get("scene") != scene, job
        for path in job["input"] + job["output"]:
            assert not own.search(path.replace(f"-without-{scene}", "")), (job["rule"], path)
            assert source is None or source not in path, (job["rule"], path)


def test_the_choices_never_depend_on_an_evaluation_scene(tmp_path):
    config = tmp_path / "synthetic.yaml"
    config.write_text(yaml.safe_dump(SYNTHETIC))
    rows = ["joint-prior+3dgs", "joint-restormer+3dgs"]
    jobs = dry_run_jobs(tmp_path, config, fold_targets("", rows))
    for scene in EVAL:
        assert_never_reads(jobs, scene)
    choice = [j for j in jobs if j["rule"] == "choose_joint_weight"]
    assert len(choice) == 2 and all(j["wildcards"]["fold"] == "" for j in choice)
    for job in choice:  # fitted on the fold's held-out training scene: its last, never trained on
        assert "results/scenes/gallery" in job["input"] and "results/scenes/tabletop" not in job["input"]
        assert f"results/models/{job['wildcards']['method']}" in job["input"]
    trained = {j["wildcards"]["method"] for j in jobs if j["rule"] == "train_translator"}
    assert trained >= {"prior", "restormer", "classical"}


def test_a_joint_row_reads_its_folds_choice(tmp_path):
    config = tmp_path / "synthetic.yaml"
    config.write_text(yaml.safe_dump(SYNTHETIC))
    jobs = dry_run_jobs(tmp_path, config, ["results/recon/courtyard/joint-restormer+3dgs"])
    recon = next(j for j in jobs if j["rule"] == "reconstruct")
    assert "results/choices/joint-restormer+3dgs.json" in recon["input"]
    plain = dry_run_jobs(tmp_path, config, ["results/recon/courtyard/restormer+3dgs"])
    assert not any(j["rule"] == "choose_joint_weight" for j in plain)


@pytest.mark.llff
def test_the_real_preset_keeps_each_left_out_scene_out_of_its_choices(tmp_path):
    preset = REPO / "workflow" / "presets" / "findings-llff.yaml"
    if not (LLFF_ROOT / "canclip" / "poses_bounds.npy").is_file():
        pytest.skip(f"the six real scenes are not in {LLFF_ROOT}")
    spec = yaml.safe_load(preset.read_text())
    rows = [c for c in spec["stage2"]["combinations"] if c.startswith("joint-")]
    rows = [r.replace("+nerf", "+nerf-grid") for r in rows]
    local = {"llff_scenes": {s: str(LLFF_ROOT / s) for s in spec["llff_scenes"]}}  # the preset's paths: repo-relative
    held = {"fern": "canclip", "trex": "ollie"}  # the scene before the left-out one, cyclically
    config = tmp_path / "preset.yaml"
    config.write_text(yaml.safe_dump(spec | local))
    for scene in ("fern", "trex"):
        jobs = dry_run_jobs(tmp_path, config, fold_targets(f"-without-{scene}", rows))
        assert_never_reads(jobs, scene, source=str(LLFF_ROOT / scene))
        choice = [j for j in jobs if j["rule"] == "choose_joint_weight"]
        assert len(choice) == len(rows)
        assert all(f"results/scenes/{held[scene]}" in j["input"] for j in choice)


# --- the library ------------------------------------------------------------------------------------

TINY_3DGS = {"iterations": 30, "densify_from": 10, "densify_until": 20, "densify_every": 10, "init_points": 300}


def test_every_candidate_fitted_and_the_best_mean_chosen(smoke_run, tmp_path, lpips_cache, one_thread):
    if smoke_run.built["full_rc"] != 0:
        pytest.fail(f"the smoke run failed: {smoke_run.built['full_err']}")
    results = smoke_run.work / "results"
    out = tmp_path / "choices" / "joint-prior+3dgs.json"
    record = choose_joint_weight(
        results / "models" / "prior",
        [(str(results / "scenes" / "tabletop"), str(results / "spc" / "tabletop"))],
        results / "calibration" / "display-k1.json",
        out,
        method="prior",
        model="3dgs",
        settings=TINY_3DGS,
        joint={"decay_until": 0.5},
        candidates=[0.0, 30.0],
        seed=0,
        frames=1,
        display=(1, False),
        lpips_dir=lpips_cache,
    )
    assert io.read_json(out) == record and not list(out.parent.glob(".*"))  # no work files left
    scores = record["psnr"]
    assert set(scores) == {"0.0", "30.0"} and all(set(s) == {"tabletop"} for s in scores.values())
    # the weight reaches the fit: the likelihood alone and a strong prior term render differently
    assert abs(scores["0.0"]["tabletop"] - scores["30.0"]["tabletop"]) > 0.01
    best = max(record["candidates"], key=lambda w: record["mean_psnr"][str(w)])
    assert record["chosen"] == {"weight": best, "weight_final": best}
    assert record["scenes"] == ["tabletop"] and record["seed"] == 0 and record["wall_s"] > 0
    assert chosen_joint({"weight": 0.1, "decay_until": 0.5}, out) == {
        "weight": best,
        "weight_final": best,
        "decay_until": 0.5,
    }
    assert chosen_joint({"weight": 0.1}, None) == {"weight": 0.1}


def test_a_choice_needs_held_out_scenes_and_valid_candidates(tmp_path):
    with pytest.raises(ValueError, match="held-out training scenes"):
        choose_joint_weight(
            tmp_path, [], tmp_path / "c.json", tmp_path / "out.json", method="prior", model="3dgs",
            settings={}, joint={}, candidates=[0.1], seed=0, frames=1, display=(1, False),
        )  # fmt: skip
    for bad in ([], [0.1, 0.1], [-1.0], [float("nan")]):
        with pytest.raises(ValueError, match="stage2.joint.choose.3dgs"):
            choose_joint_weight(
                tmp_path, [("a", "b")], tmp_path / "c.json", tmp_path / "out.json", method="prior", model="3dgs",
                settings={}, joint={}, candidates=bad, seed=0, frames=1, display=(1, False),
            )  # fmt: skip


# --- the configuration ------------------------------------------------------------------------------


def _config(**stage1) -> dict:
    base = yaml.safe_load((REPO / "config.yaml").read_text())
    base["stage1"]["validation"] |= stage1
    base["stage2"]["joint"]["choose"] = {"3dgs": [0.1, 1.0]}
    return base


def test_a_chosen_weight_needs_a_held_out_training_scene():
    rows = ["joint-restormer+3dgs"]
    with pytest.raises(ConfigError, match=r"stage2.joint.choose.3dgs: .*restormer holds none out.*hold_out: 1"):
        check_joint_choice(_config(hold_out=0), rows)
    check_joint_choice(_config(hold_out=1), rows)
    check_joint_choice(_config(hold_out=0), ["joint-restormer+nerf-grid", "restormer+3dgs"])  # 3DGS rows only
    with pytest.raises(ConfigError, match="estimated poses"):
        check_joint_choice(_config(hold_out=1), ["joint-restormer+3dgs@mle-k16"])


def test_one_stopping_rule_for_every_row_of_a_model():
    rows = ["restormer+3dgs", "bernoulli+3dgs", "joint-prior+nerf-grid"]
    with pytest.raises(ConfigError, match=r"stage2.3dgs.plateau_views = 2: the rows \['bernoulli\+3dgs'\]"):
        check_one_rule({"3dgs": {"plateau_views": 2}}, rows)
    with pytest.raises(ConfigError, match=r"stage2.3dgs.plateau_patience = 2: .* set plateau_patience: 0"):
        check_one_rule({"3dgs": {"plateau_patience": 2}}, rows)  # stops on the training loss: also a rule
    check_one_rule({"3dgs": {"plateau_views": 0}, "nerf-grid": {"plateau_views": 2}}, rows)  # grid: joint only
    check_one_rule({"3dgs": {"plateau_views": 2}}, ["restormer+3dgs", "gt+3dgs"])  # one kind: one rule
    for preset in sorted((REPO / "workflow" / "presets").glob("*.yaml")) + [REPO / "config.yaml"]:
        stage2 = yaml.safe_load(preset.read_text()).get("stage2") or {}
        for model in ("3dgs", "nerf-mlp", "nerf-grid"):  # no preset stops a row early (one rule)
            block = stage2.get(model) or {}
            assert not block.get("plateau_views") and not block.get("plateau_patience"), (preset.name, model)


def test_the_exploratory_benchmarks_guard_reads_the_merged_configuration(monkeypatch):
    """benchmarks/joint_weight.py refuses the evaluation scenes of config.yaml overlaid by --configfile
    (it read config.yaml alone: with the real-scene preset it let every scored scene through)."""
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    bench = load_script(REPO / "benchmarks" / "joint_weight.py")
    preset = workflow_config(REPO / "workflow" / "presets" / "findings-llff.yaml")  # what main() reads
    default = workflow_config()
    assert set(preset["scenes"]["eval"]) == {"canclip", "fern", "flower", "fortress", "ollie", "trex"}
    assert preset["stage2"]["3dgs"] == default["stage2"]["3dgs"]  # nested keys merged, not replaced
    assert "evaluation scenes" in bench.refused(["fortress", "trex"], preset, None)
    assert "--fold SCENE" in bench.refused(["fortress"], preset, None)
    assert bench.refused(["fortress", "trex"], preset, "fern") is None  # fern's fold: the others are training
    assert "left-out scene" in bench.refused(["fern", "trex"], preset, "fern")
    assert bench.refused(["tabletop", "gallery"], default, None) is None
    assert "evaluation scenes" in bench.refused(["courtyard"], default, None)
    assert "not a left-out scene" in bench.refused(["tabletop"], default, "courtyard")

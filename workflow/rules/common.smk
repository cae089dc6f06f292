# Config validation and the small named helpers the rules use (no logic in the rules themselves).
import sys
from pathlib import Path

from snakemake.utils import validate

from spc3d.config import check_config, check_settings, read_yaml, resolve_paths, upgrade_keys
from spc3d.checks.crosscheck import check_capture_frames

# Renamed keys moved to their new names (a warning each), short messages naming the key (Snakemake's
# own validate prints the whole schema), then its validate fills in the defaults; every relative
# path is then taken from the repository root.
for warning in upgrade_keys(config):
    if workflow.is_main_process:
        print(f"spc3d warning: {warning}", file=sys.stderr)
check_config(config, read_yaml(Path(workflow.basedir) / "workflow" / "schemas" / "config.schema.yaml"))
validate(config, schema="../schemas/config.schema.yaml")
resolve_paths(config, workflow.basedir)

from spc3d.inputs.scenes import LAYOUTS
from spc3d.specs import RECONSTRUCTORS as MODELS
from spc3d.specs import TRANSLATORS as STAGE1_SPECS
from spc3d.names import (JOINT_SOURCES, PLAIN_SOURCES, POSES_PATTERN, SOURCE_PATTERN, STAGE1_METHODS, STAGE2_MODELS,
    parse_combination, stage1_sources)
from snakemake.exceptions import WorkflowError
from snakemake.io import apply_wildcards

from spc3d.jobs import benchmark_path, training_scene_names, scene_specs, training_folds
from spc3d.settings import Grid, Targets
from spc3d.settings.params import SweepReportParams
from spc3d.sweeps.plan import OVERLAY_PATTERN, PointSettings, Settings, photon_budget, sweep_scenes

# Deployment, not an experiment setting: the SLURM profile sets conda_env=gpu (see its README).
ENV = {"cpu": "../../envs/spc3d.yaml", "gpu": "../../envs/spc3d-gpu.yaml"}[config["conda_env"]]
LPIPS_WEIGHTS = {net: f"results/cache/lpips/lpips_v0.1_{net}.npz" for net in ("alex", "vgg")}
config["scenes"]["train"] = training_scene_names(config)  # + configured LLFF scenes (scenes.train_llff)
TRAIN_SCENES, EVAL_SCENES = list(config["scenes"]["train"]), list(config["scenes"]["eval"])
# The training scenes of each evaluation scene: all of scenes.train (fold ""), or with
# scenes.leave_one_out all but the scene itself ("-without-{scene}": its translators and display level).
FOLDS = training_folds(TRAIN_SCENES, EVAL_SCENES, config["scenes"]["leave_one_out"])
# Every job asks its settings object (spc3d.settings): the grid's, or its sweep point's (below).
GRID = Grid(config, scene_specs(config, sorted(LAYOUTS)), FOLDS, workflow.basedir)
TARGETS = Targets(GRID)  # the files the run makes: every row on every evaluation scene, for every seed
ALL_SCENES, COMBINATIONS = TARGETS.scenes, TARGETS.combinations
# Checked once, by the main process (torch-free: spc3d.specs); each job's own process reads this
# file again and builds only its own settings.
if workflow.is_main_process:
    check_settings(config, stage1_sources(COMBINATIONS), sorted({parse_combination(c)[1] for c in COMBINATIONS}),
                   COMBINATIONS)
    check_capture_frames({s: GRID.specs[s] for s in EVAL_SCENES}, COMBINATIONS, config)  # captures hold K frames
# Sweep points (tradeoff.smk) are these rules' jobs under a settings overlay: the {overlay} wildcard
# after results/ ("" for the grid, "sweeps/tradeoff/iters~300/res~64/" for a point: spc3d.sweeps.plan).
SWEEP_SCENE, SWEEP_TRAIN = sweep_scenes(config["tradeoff"]["scene"], config["tradeoff"]["train_scenes"], EVAL_SCENES,
                                        TRAIN_SCENES, sorted(LAYOUTS) + sorted(config["llff_scenes"]))
SWEEP_SPECS = scene_specs(config | {"scenes": {"train": SWEEP_TRAIN, "eval": [SWEEP_SCENE]}}, sorted(LAYOUTS))
POINTS = PointSettings(config, SWEEP_SPECS, SWEEP_SCENE, SWEEP_TRAIN, photon_budget(config["photon_level"]["budget"]))
SETTINGS = Settings(GRID, POINTS)


wildcard_constraints:
    scene="|".join(ALL_SCENES + [s for s in SWEEP_SPECS if s not in ALL_SCENES]) or "(?!)",
    images="rgb|binary|average",
    source=SOURCE_PATTERN,  # the row grammar: spc3d.names
    poses=POSES_PATTERN,  # "@mle-k16": poses COLMAP estimated from that source's images
    model="|".join(STAGE2_MODELS),
    method=f"({'|'.join(STAGE1_METHODS)})(-pub)?",  # "-pub": the published network (prior_sigma: 0)
    rep="(-seed[0-9]+)?",
    fold=f"({'|'.join(FOLDS)})",  # "" or "-without-{scene}": the training scenes of a model folder / display level
    budget="k[0-9]+|capture",  # a metered display: the first K frames, or the capture-resolution frame
    sensor=f"({'|'.join(GRID.sensors)})?",  # "" (the simulator's RGB) or a capture's "-rggb", ...
    overlay=OVERLAY_PATTERN,  # "" (the grid) or a sweep point's settings, "sweeps/tradeoff/iters~300/.../"


def settings_of(wildcards):
    """The job's settings (spc3d.settings.Grid): the grid's, or its sweep point's ({overlay}; the rules
    without the wildcard, colmap and poses, are the grid's)."""
    return SETTINGS.at(getattr(wildcards, "overlay", ""))


def setting(name):
    """An input or params function: the job's settings object's answer ``name`` (spc3d.settings.grid)."""
    return lambda wildcards: getattr(settings_of(wildcards), name)(wildcards)


def point_benchmarks(points):
    """Each point with the benchmark files of its jobs (spc3d.jobs.logged writes one beside each log)."""
    return [{k: v for k, v in p.items() if k != "outputs"} | {"benchmarks": [job_benchmark(o) for o in p["outputs"]]}
            for p in points]


def job_benchmark(path):
    """The benchmark file of the job that makes ``path``: its rule found by output pattern, its log's wildcards."""
    rules = [rule for rule in workflow.rules if rule.is_producer(path)]
    if len(rules) != 1:
        raise WorkflowError(f"{path}: made by {len(rules)} rules ({', '.join(r.name for r in rules)}); expected one")
    return str(benchmark_path(apply_wildcards(rules[0].log[0], rules[0].get_wildcards(path))))


def sweep_report(points, combos, clock=None):
    """A sweep report's params: its points with their benchmark files, its combinations and clock."""
    return SweepReportParams(point_benchmarks(points), combos, clock)


def get_translator_gpus(wildcards):
    """A network trains on CUDA when present; the untrained methods (prior, classical) need no GPU."""
    return int(STAGE1_SPECS[settings_of(wildcards).translator_base(wildcards)].trained)


def get_stage2_gpus(wildcards):
    """GPUs a stage-2 job can use (its spec's ``gpu``): 3DGS runs on CPU threads here, the NeRFs use CUDA when present."""
    return int(MODELS[wildcards.model].gpu)


# SLURM: every distinct request is tried with `sbatch --test-only` before anything is submitted.
onstart:
    if getattr(workflow.executor_plugin, "name", None) == "slurm":
        from spc3d.checks.slurm import slurm_problems

        if problems := slurm_problems(workflow.dag.needrun_jobs()):
            raise WorkflowError("SLURM cannot run these jobs, nothing was submitted:\n  " + "\n  ".join(problems))

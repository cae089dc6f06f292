# Config validation and the small named helpers the rules use (no logic in the rules themselves).
import functools
from pathlib import Path

from snakemake.utils import validate

from spc3d.config import check_config, check_settings, read_yaml, resolve_paths
from spc3d.checks.crosscheck import check_capture_frames

# Short messages naming the key (Snakemake's own validate prints the whole schema), then its
# validate fills in the defaults; every relative path is then taken from the repository root.
check_config(config, read_yaml(Path(workflow.basedir) / "workflow" / "schemas" / "config.schema.yaml"))
validate(config, schema="../schemas/config.schema.yaml")
resolve_paths(config, workflow.basedir)

from spc3d.inputs.augment import split_count
from spc3d.inputs.scenes import LAYOUTS
from spc3d.models import RECONSTRUCTORS as MODELS
from spc3d.models import TRANSLATORS as STAGE1_SPECS
from spc3d.names import JOINT_SOURCES, PLAIN_SOURCES, POSES_PATTERN, SOURCE_IMAGES, SOURCE_PATTERN, STAGE1_METHODS, STAGE2_MODELS, display_budget, display_budgets, joint_settings, parse_combination, parse_source, reads_capture_frame, resolve_combinations, scored_before_3d, source_frames, source_images, spc_settings, stage1_sources, stage2_row_settings, translator_settings, translator_validation, uses_display
from snakemake.io import apply_wildcards

from spc3d.provenance import closure_digest, entry_file
from spc3d.jobs import benchmark_path, folder_files, training_scene_names, llff_input_files, scene_fold, scene_specs, training_folds
from spc3d.sweeps.plan import OVERLAY_PATTERN, PointSettings, photon_budget, sweep_scenes

# Deployment, not an experiment setting: the SLURM profile sets conda_env=gpu (see its README).
ENV = {"cpu": "../../envs/spc3d.yaml", "gpu": "../../envs/spc3d-gpu.yaml"}[config["conda_env"]]
LPIPS_WEIGHTS = {net: f"results/cache/lpips/lpips_v0.1_{net}.npz" for net in ("alex", "vgg")}
config["scenes"]["train"] = training_scene_names(config)  # + configured LLFF scenes (scenes.train_llff)
SCENE_SPECS = scene_specs(config, sorted(LAYOUTS))
TRAIN_SCENES = list(config["scenes"]["train"])
EVAL_SCENES = list(config["scenes"]["eval"])
ALL_SCENES = list(dict.fromkeys(TRAIN_SCENES + EVAL_SCENES))
# The training scenes of each evaluation scene: all of scenes.train (fold ""), or with
# scenes.leave_one_out all but the scene itself ("-without-{scene}": its translators and display level).
LEAVE_ONE_OUT = config["scenes"]["leave_one_out"]
FOLDS = training_folds(TRAIN_SCENES, EVAL_SCENES, LEAVE_ONE_OUT)
# Captured SPAD scenes (config `captures`): their translators are trained for their sensor (one
# model folder per sensor: results/models-rggb/...), and one without reference views is not scored.
SENSORS = {f"-{s['sensor_tag']}": s["sensor"] for s in SCENE_SPECS.values() if s["kind"] == "capture"}
NO_REFERENCE = [name for name, s in SCENE_SPECS.items() if s["kind"] == "capture" and not s["reference"]]
COLMAP_INPUTS = list(config["colmap"]["inputs"])
COMBINATIONS = resolve_combinations(config["stage2"]["combinations"], config["stage2"]["nerf_variant"])
# The rivals the claims over "every" row compare with, listed (findings.rivals; the library's default for
# a list not given): a listed rival that did not run makes its claim NOT RUN (spc3d.evaluation.findings).
FINDINGS_RIVALS = {k: resolve_combinations(v, config["stage2"]["nerf_variant"], f"findings.rivals.{k}")
                   for k, v in config["findings"]["rivals"].items()}
STAGE1_USED = stage1_sources(COMBINATIONS)
check_settings(config, STAGE1_USED, sorted({parse_combination(c)[1] for c in COMBINATIONS}), COMBINATIONS)
check_capture_frames({s: SCENE_SPECS[s] for s in EVAL_SCENES}, COMBINATIONS, config)  # captures hold K frames
# Repeats: the first seed is `seed` (paths without a tag), the others add "-seed{N}". A repeat redraws
# everything random: SPC noise of every scene, augmentation, translator init and crops, stage-2 init.
SEEDS = [config["seed"] + k for k in range(config["seeds"])]
REPS = ["" if s == config["seed"] else f"-seed{s}" for s in SEEDS]
# Sources scored before 3D (score_images): the translators in use and the training-free images.
STAGE1_SCORED = scored_before_3d(COMBINATIONS)
# Sweep points (tradeoff.smk) are these rules' jobs under a settings overlay: the {overlay} wildcard
# after results/ ("" for the grid, "sweeps/tradeoff/iters~300/res~64/" for a point: spc3d.sweeps.plan).
# A get_* helper below returns the grid's value for "" and POINTS' for a point.
SWEEP_SCENE, SWEEP_TRAIN = sweep_scenes(config["tradeoff"]["scene"], config["tradeoff"]["train_scenes"], EVAL_SCENES,
                                        TRAIN_SCENES, sorted(LAYOUTS) + sorted(config["llff_scenes"]))
SWEEP_SPECS = scene_specs(config | {"scenes": {"train": SWEEP_TRAIN, "eval": [SWEEP_SCENE]}}, sorted(LAYOUTS))
POINTS = PointSettings(config, SWEEP_SPECS, SWEEP_SCENE, SWEEP_TRAIN, photon_budget(config["photon_level"]["budget"]))


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
    sensor=f"({'|'.join(SENSORS)})?",  # "" (the simulator's RGB) or a capture's "-rggb", ...
    overlay=OVERLAY_PATTERN,  # "" (the grid) or a sweep point's settings, "sweeps/tradeoff/iters~300/.../"


def overlay_of(wildcards):
    """The job's settings overlay ("" for the grid and for the rules without the wildcard: colmap, poses)."""
    return getattr(wildcards, "overlay", "")


def get_final_output():
    """What `snakemake` builds by default: the data summary, the tables (with the findings), the figures."""
    return [
        "results/summary/data_summary.md",
        *get_table_outputs(),
        *expand("results/figures/qualitative_{scene}.png", scene=[s for s in EVAL_SCENES if s not in NO_REFERENCE]),
    ]


def get_table_outputs():
    return expand("results/tables/{table}.{ext}",
                  table=["single_stage", "two_stage", "stage1", "estimated_poses", "no_reference", "stopping"],
                  ext=["csv", "md", "tex", "html"]) + expand("results/tables/findings.{ext}", ext=["md", "json", "html"])


def get_stage1_outputs():
    """Stage-1 scores (before 3D) of every scored source on every evaluation scene with reference
    views, for every seed."""
    scored = [s for s in EVAL_SCENES if s not in NO_REFERENCE]
    return expand("results/stage1/{scene}/{source}{rep}.json", scene=scored, source=STAGE1_SCORED, rep=REPS)


def needs_reference(combo):
    """Rows that read the ground truth before scoring (the oracle source or its poses)."""
    source, _, poses = parse_combination(combo)
    return source == "gt" or poses == "gt"


def get_eval_outputs():
    """metrics.json of every configured combination on every evaluation scene, for every seed (on a
    capture without reference views, every row but those that need them)."""
    return [f"results/eval/{scene}/{combo}{rep}/metrics.json" for scene in EVAL_SCENES for combo in COMBINATIONS
            for rep in REPS if not (scene in NO_REFERENCE and needs_reference(combo))]


def get_seed(wildcards):
    """The seed of a run from its tag ('' = config `seed`)."""
    return int(wildcards.rep.removeprefix("-seed")) if wildcards.rep else config["seed"]


def get_source_frames(wildcards):
    """Binary frames per view (K) the row's source consumes; None for the oracle."""
    if overlay_of(wildcards):
        return POINTS.frames(overlay_of(wildcards), wildcards.source)
    return source_frames(wildcards.source, config["stage1"]["frames"], config["stage2"]["frames"])


def get_capture_factor(wildcards):
    """S of a source's images (S x S sensor pixels per working pixel): spc.capture_factor for the
    capture-resolution frame of a simulated scene (a capture has no finer frame), else 1; a sweep
    point simulates no finer frame (S = 1)."""
    if overlay_of(wildcards):
        return 1
    simulated = SCENE_SPECS[wildcards.scene]["kind"] != "capture"
    return config["spc"]["capture_factor"] if simulated and reads_capture_frame(wildcards.source, config["stage2"]["frames"]) else 1


def display_folder(wildcards):
    """The metered MLE images of the row's frame budget (mle / bernoulli rows); a capture has no
    finer frame (S = 1), so its capture-frame rows read frame 0's display. A sweep point's: its K."""
    if overlay_of(wildcards):
        return f"results/{overlay_of(wildcards)}mle/{wildcards.scene}/k{get_source_frames(wildcards)}"
    budget = display_budget(wildcards.source, config["stage2"]["frames"], config["stage1"]["frames"])
    if budget == "capture" and SCENE_SPECS[wildcards.scene]["kind"] == "capture":
        budget = "k1"
    return f"results/mle/{wildcards.scene}/{budget}{wildcards.rep}"


def get_display_frames(wildcards):
    """K of a metered display ("k16": 16; "capture": the one capture-resolution frame)."""
    return 1 if get_display_capture(wildcards) else int(wildcards.budget[1:])


def get_display_capture(wildcards):
    """Whether a metered display is of the capture-resolution frame (spc.capture_factor)."""
    return wildcards.budget == "capture"


def get_reconstruct_inputs(wildcards):
    """The scene, its SPC folder for the SPC-derived sources, the stage-1 images or the metered MLE
    display (mle: its images; bernoulli: its gain), COLMAP's points for a 3DGS init (not a sweep point's)."""
    name, root = parse_source(wildcards.source), f"results/{overlay_of(wildcards)}"
    inputs = {"scene": f"{root}scenes/{wildcards.scene}"}
    if name.base != "gt":
        inputs["spc"] = f"{root}spc/{wildcards.scene}{wildcards.rep}"
    if name.method:
        inputs["translated"] = f"{root}translate/{wildcards.scene}/{name.method}{wildcards.rep}"
    if uses_display(wildcards.source):
        inputs["display"] = display_folder(wildcards)
    if MODELS[wildcards.model].accepts_points and get_stage2_init(wildcards) == "colmap":
        inputs["colmap"] = f"results/colmap/{wildcards.scene}/rgb"
    if wildcards.poses:
        inputs["poses"] = f"results/poses/{wildcards.scene}/{wildcards.poses[1:]}{wildcards.rep}"
    if name.joint and wildcards.model in JOINT_CHOOSE and not overlay_of(wildcards):
        inputs["choice"] = f"results/choices{fold_of(wildcards)}/{wildcards.source}+{wildcards.model}{wildcards.rep}.json"
    return inputs


def get_joint_settings(wildcards):
    """stage2.joint for this row's model (the prior term's schedule), None for every other row."""
    return joint_settings(config["stage2"]["joint"], wildcards.model) if parse_source(wildcards.source).joint else None


def get_stage2_init(wildcards):
    """stage2.init; a sweep point starts from random points, as every source alike (None: recorded so)."""
    return None if overlay_of(wildcards) else config["stage2"]["init"]


def get_eval_spc():
    """Every evaluation scene's SPC folder, per repeat (the tables name the ones whose frames carry no image)."""
    return expand("results/spc/{scene}{rep}", scene=EVAL_SCENES, rep=REPS)


def get_eval_frames(wildcards):
    """A scene without reference views is scored on its held-out frames (spc3d.evaluation.heldout); others need none."""
    return f"results/spc/{wildcards.scene}" if wildcards.scene in NO_REFERENCE and not overlay_of(wildcards) else []


def get_model_settings(wildcards):
    """The config's settings of the stage-2 model (spc3d.names.stage2_row_settings; a sweep point's: at its budget)."""
    settings = stage2_row_settings(config["stage2"], wildcards.model, wildcards.poses or None)
    return POINTS.stage2(overlay_of(wildcards), wildcards.model, settings) if overlay_of(wildcards) else settings


# A joint row's prior weight, where its model lists candidates (stage2.joint.choose), is chosen per fold on
# the fold's held-out training scenes (rule choose_joint_weight, spc3d.choices); else it is stage2.joint's.
JOINT_CHOOSE = config["stage2"]["joint"].get("choose") or {}


def held_out_scenes(fold, method):
    """The fold's training scenes its ``method`` validates on and never trains on (stage1.validation.hold_out)."""
    n = translator_validation(config["stage1"], method).get("hold_out", 0)
    return FOLDS[fold][-n:] if n else []


def get_choice_inputs(wildcards):
    """The fold's model of the method, its display level, and its held-out training scenes with their frames."""
    held, budget = held_out_scenes(wildcards.fold, wildcards.method), get_choice_display(wildcards)[2]
    return {
        "model": f"results/models{wildcards.fold}/{wildcards.method}{wildcards.rep}",
        "calibration": f"results/calibration{wildcards.fold}/display-{budget}{wildcards.rep}.json",
        "scenes": expand("results/scenes/{scene}", scene=held),
        "spc": expand("results/spc/{scene}{rep}", scene=held, rep=wildcards.rep),
    }


def get_choice_display(wildcards):
    """(K, capture, budget) of the display the joint row reads."""
    budget = display_budget(f"joint-{wildcards.method}", config["stage2"]["frames"], config["stage1"]["frames"])
    return (1, True, budget) if budget == "capture" else (int(budget[1:]), False, budget)


def get_checkpoint_path(wildcards):
    """Outside the rule's output folder, so Snakemake's clean-up of a failed job keeps it."""
    combo = f"{wildcards.source}+{wildcards.model}{wildcards.poses}"
    return f"results/{overlay_of(wildcards)}checkpoints/{wildcards.scene}/{combo}{wildcards.rep}/checkpoint.pt"


def scene_spec(wildcards):
    """The scene's spec as configured (a sweep point's: the sweeps' scenes, tradeoff.scene / train_scenes)."""
    return (SWEEP_SPECS if overlay_of(wildcards) else SCENE_SPECS)[wildcards.scene]


def get_scene_spec(wildcards):
    """The scene's spec (a sweep point's: at its width, knob res)."""
    return POINTS.scene(overlay_of(wildcards), wildcards.scene) if overlay_of(wildcards) else SCENE_SPECS[wildcards.scene]


def get_scene_source(wildcards):
    """The files of a real scene or capture (every one read: an edit reruns it); none for built-ins."""
    spec = scene_spec(wildcards)
    if spec["kind"] == "llff":
        return llff_input_files(spec["path"], spec["factor"])
    hot = [spec["overrides"]["hot_pixels"]] if spec.get("overrides", {}).get("hot_pixels") else []
    return folder_files(spec["path"]) + hot if spec["kind"] in ("colmap", "capture") else []


def scene_sensor(scene):
    """"" for a simulated scene (the simulator's RGB sensor), "-<tag>" for a capture's sensor."""
    spec = SCENE_SPECS[scene]
    return f"-{spec['sensor_tag']}" if spec["kind"] == "capture" else ""


def get_spc_settings(wildcards):
    """A simulated scene's physics and seed; a capture's folder (its frames are read, one measurement for
    every seed); a sweep point's K frames and calibration target (knobs K, detection)."""
    if overlay_of(wildcards):
        return POINTS.spc(overlay_of(wildcards))
    spec = SCENE_SPECS[wildcards.scene]
    if spec["kind"] == "capture":
        return {"capture": spec["path"], "overrides": spec["overrides"]}
    return spc_settings(config["spc"], get_seed(wildcards))


def get_augment_count(wildcards):
    if overlay_of(wildcards):
        return POINTS.augment_count(wildcards.scene)
    return split_count(config["augment"]["count"], len(TRAIN_SCENES), TRAIN_SCENES.index(wildcards.scene))


def fold_of(wildcards):
    """The fold of a job's evaluation scene ("" for a sweep point: its own training scenes)."""
    return "" if overlay_of(wildcards) else scene_fold(wildcards.scene, TRAIN_SCENES, LEAVE_ONE_OUT)


def training_scenes(wildcards):
    """The training scenes of a fold's model folder or display level (a sweep point's: tradeoff.train_scenes)."""
    return POINTS.train if overlay_of(wildcards) else FOLDS[wildcards.fold]


def get_display_calibration(wildcards):
    """The display level of the scene's fold at the display's budget."""
    return f"results/{overlay_of(wildcards)}calibration{fold_of(wildcards)}/display-{wildcards.budget}{wildcards.rep}.json"


def get_display_training(wildcards):
    """Scene and SPC folders of the training scenes the display level is fitted on."""
    root, scenes = f"results/{overlay_of(wildcards)}", training_scenes(wildcards)
    return {"scenes": expand(f"{root}scenes/{{scene}}", scene=scenes),
            "spc": expand(f"{root}spc/{{scene}}{{rep}}", scene=scenes, rep=wildcards.rep)}


def get_colmap_images(wildcards):
    """The folder holding the image set a COLMAP run reads."""
    if wildcards.images == "rgb":
        return f"results/scenes/{wildcards.scene}"
    return f"results/spc/{wildcards.scene}"


def get_colmap_subdir(wildcards):
    return {"rgb": "images", "binary": "binary", "average": "average"}[wildcards.images]


def get_summary_colmap():
    """The COLMAP runs of the data summary (no RGB run on a capture without reference views)."""
    return [f"results/colmap/{scene}/{images}" for scene in ALL_SCENES for images in COLMAP_INPUTS
            if not (scene in NO_REFERENCE and images == "rgb")]


def get_summary_roles():
    """Each scene's role, in ALL_SCENES' order (leave-one-out: a scene both trains and is evaluated)."""
    return [" + ".join(r for r, names in (("train", TRAIN_SCENES), ("eval", EVAL_SCENES)) if s in names) for s in ALL_SCENES]


def get_translator_base(wildcards):
    """The method a model folder trains ("pix2pixhd" for "pix2pixhd-pub", whose settings say prior_sigma: 0)."""
    return parse_source(wildcards.method).base


def get_translator_settings(wildcards):
    """The method's model overrides (its config block without the 'train' block; a sweep point's width)."""
    settings, train = translator_settings(config["stage1"], wildcards.method)
    return POINTS.translator(overlay_of(wildcards), wildcards.method, settings, train)[0] if overlay_of(wildcards) else settings


def get_translator_train(wildcards):
    """stage1.train, overridden by the method's own 'train' block (a sweep point's steps and a crop that fits)."""
    settings, train = translator_settings(config["stage1"], wildcards.method)
    return POINTS.translator(overlay_of(wildcards), wildcards.method, settings, train)[1] if overlay_of(wildcards) else train


def get_translator_frames(wildcards):
    """stage1.frames: the binary frames a translator reads (a sweep point's K)."""
    return POINTS.frames(overlay_of(wildcards), wildcards.method) if overlay_of(wildcards) else config["stage1"]["frames"]


def get_translator_data_kind(wildcards):
    """stage1.data; a sweep point trains on its fixed augmented pairs."""
    return "fixed" if overlay_of(wildcards) else config["stage1"]["data"]


def get_translator_pretrained(wildcards):
    """Published weights the method starts from (an input: replacing the file retrains it); none by default."""
    path = get_translator_settings(wildcards).get("checkpoint")
    return [path] if path else []


def get_translator_data(wildcards):
    """The training data of a translator: the augmented pairs (stage1.data: fixed) and, for online
    samples or validation (on their held-out views), the training scenes and their SPC folders."""
    data, inputs = get_translator_data_kind(wildcards), {}
    root, scenes = f"results/{overlay_of(wildcards)}", training_scenes(wildcards)
    if data == "fixed":
        inputs["pairs"] = expand(f"{root}augment/{{scene}}{{rep}}", scene=scenes, rep=wildcards.rep)
    if data == "online" or get_translator_validation(wildcards)["every"] > 0:
        inputs["scenes"] = expand(f"{root}scenes/{{scene}}", scene=scenes)
        inputs["spc"] = expand(f"{root}spc/{{scene}}{{rep}}", scene=scenes, rep=wildcards.rep)
    return inputs


def get_translator_validation(wildcards):
    """stage1.validation, overridden by the method's own 'validation' block; a sweep point validates nothing."""
    return {"every": 0} if overlay_of(wildcards) else translator_validation(config["stage1"], wildcards.method)


def get_augment_ranges(wildcards):
    """The augmentation ranges online samples draw from (the augment block without its count)."""
    return {k: v for k, v in config["augment"].items() if k != "count"}


# The library code a translator's weights depend on (the scripts of its job and of the jobs upstream,
# its model's module, every spc3d module they import): a param, so it keys Snakemake's between-workflow
# cache (`--cache`) and reruns the training when that code changes (spc3d/provenance.py; comments,
# docstrings and formatting do not count).
TRAINING_SCRIPTS = [
    Path(workflow.basedir) / "workflow" / "scripts" / f"{name}.py"
    for name in ("prepare_scene", "simulate_scene", "augment_scene", "train_translator")
]


@functools.lru_cache(maxsize=None)
def translator_code(method):
    return closure_digest([*TRAINING_SCRIPTS, entry_file(STAGE1_SPECS[method].module)])


def get_translator_code(wildcards):
    return translator_code(get_translator_base(wildcards))


# The same key for a stage-2 fit: its script, its model's factory module and every spc3d module they
# import (the sources, the objectives, the trainers, the rasterizer): a change there reruns the fits.
RECONSTRUCT_SCRIPT = Path(workflow.basedir) / "workflow" / "scripts" / "reconstruct.py"


@functools.lru_cache(maxsize=None)
def reconstruct_code(model):
    return closure_digest([RECONSTRUCT_SCRIPT, entry_file(MODELS[model].factory.rpartition(":")[0])])


def get_reconstruct_code(wildcards):
    return reconstruct_code(wildcards.model)


def get_translator_sensor(wildcards):
    """The sensor a translator's inputs are recorded by ({"cfa", "white"}); None: the simulator's RGB."""
    return SENSORS.get(wildcards.sensor)


def get_translator_model(wildcards):
    """The model trained for the scene's sensor on the scene's fold of training scenes."""
    sensor = "" if overlay_of(wildcards) else scene_sensor(wildcards.scene)
    return f"results/{overlay_of(wildcards)}models{sensor}{fold_of(wildcards)}/{wildcards.method}{wildcards.rep}"


def get_stage1_images(wildcards):
    """The folder holding a source's images of a scene (stage-1 output, metered MLE, binary frame, ground truth)."""
    kind, root = get_stage1_kind(wildcards)[0], f"results/{overlay_of(wildcards)}"
    if kind == "translated":
        return f"{root}translate/{wildcards.scene}/{parse_source(wildcards.source).method}{wildcards.rep}"
    if kind == "display":
        return display_folder(wildcards)
    if kind == "scene":
        return f"{root}scenes/{wildcards.scene}"
    return f"{root}spc/{wildcards.scene}{wildcards.rep}"


def get_stage1_kind(wildcards):
    """(folder kind, subfolder) of the source's images; a sweep point's binary frame is frame 0 (S = 1)."""
    if overlay_of(wildcards):
        return SOURCE_IMAGES[parse_source(wildcards.source).base]
    return source_images(wildcards.source, config["stage2"]["frames"])


def get_stage1_subdir(wildcards):
    return get_stage1_kind(wildcards)[1]


def get_qualitative_inputs(wildcards):
    """The scene, its SPC folder and the reconstruction of every configured combination (first seed)."""
    return {"scene": f"results/scenes/{wildcards.scene}", "spc": f"results/spc/{wildcards.scene}",
            "recons": expand("results/recon/{scene}/{combo}", scene=wildcards.scene, combo=COMBINATIONS)}


def point_benchmarks(points):
    """Each point with the benchmark files of its jobs (spc3d.jobs.logged writes one beside each log)."""
    return [{k: v for k, v in p.items() if k != "jobs"}
            | {"benchmarks": [str(benchmark_path(apply_wildcards(workflow.get_rule(rule).log[0], wildcards)))
                              for rule, wildcards in p["jobs"]]}
            for p in points]


def get_translator_gpus(wildcards):
    """A network trains on CUDA when present; the untrained methods (prior, classical) need no GPU."""
    return int(STAGE1_SPECS[parse_source(wildcards.method).base].trained)


def get_stage2_gpus(wildcards):
    """GPUs a stage-2 job can use (its spec's ``gpu``): 3DGS runs on CPU threads here, the NeRFs use CUDA when present."""
    return int(MODELS[wildcards.model].gpu)


# --- SLURM: every distinct request is tried before anything is submitted -------------------------
import subprocess

from snakemake.exceptions import WorkflowError


onstart:
    check_slurm_requests()


SBATCH_FLAGS = {"slurm_partition": "--partition={}", "slurm_account": "--account={}", "mem_mb": "--mem={}",
                "runtime": "--time={}", "threads": "--cpus-per-task={}", "gpu": "--gpus={}"}


def check_slurm_requests():
    """With the SLURM executor: each distinct request of the jobs to run (the resources the plugin
    turns into sbatch options, first attempt) is tried with `sbatch --test-only`, so one the cluster
    cannot satisfy (an unknown partition, more memory, CPUs or GPUs than a node has) stops the run at
    once, naming the rule and the resource, instead of failing later with sbatch's vaguer answer."""
    if getattr(workflow.executor_plugin, "name", None) != "slurm":
        return
    requests = {}
    for job in workflow.dag.needrun_jobs():
        if not job.is_local:
            ask = {k: job.resources.get(k) for k in SBATCH_FLAGS if k != "threads"} | {"threads": job.threads}
            requests.setdefault(tuple((k, v) for k, v in ask.items() if v not in (None, "", 0)), []).append(job)
    problems = [p for ask, jobs in requests.items() if (p := slurm_problem(jobs, dict(ask)))]
    if problems:
        raise WorkflowError("SLURM cannot run these jobs, nothing was submitted:\n  " + "\n  ".join(problems))


def slurm_problem(jobs, ask):
    """None if SLURM accepts ``ask``, the request of ``jobs``; else a line naming rule and resource."""
    flags = [SBATCH_FLAGS[k].format(v) for k, v in ask.items()]
    test = subprocess.run(["sbatch", "--test-only", *flags, "--wrap", "true"], capture_output=True, text=True)
    if test.returncode == 0:
        return None
    part = ask.get("slurm_partition")
    sinfo = subprocess.run(["sinfo", "-N", "-h", "-o", "%P %c %m %G"], capture_output=True, text=True).stdout
    nodes = [line.split() for line in sinfo.splitlines()]  # partition (default: *), CPUs, MB, GRES
    mine = [n for n in nodes if n[0].rstrip("*") == part or (part is None and n[0].endswith("*"))]
    where = f"partition {part}" if part else "the default partition"
    cpus = max((int(n[1].rstrip("+")) for n in mine), default=0)
    mem = max((int(n[2].rstrip("+")) for n in mine), default=0)
    if not mine:
        what = f"slurm_partition={part}: no such partition (there are {', '.join(sorted({n[0] for n in nodes}))})"
    elif ask.get("mem_mb", 0) > mem:
        what = f"mem_mb={ask['mem_mb']}: more memory than any node in {where} has ({mem} MB)"
    elif ask["threads"] > cpus:
        what = f"threads={ask['threads']}: more CPUs than any node in {where} has ({cpus})"
    elif ask.get("gpu") and not any("gpu" in n[3] for n in mine):
        what = f"gpu={ask['gpu']}: no node in {where} has a GPU (ask for gpu=0, or a GPU partition)"
    else:
        what = "asks for " + ", ".join(f"{k}={v}" for k, v in ask.items())
    rules = sorted({job.rule.name for job in jobs})
    example = ", ".join(f"{k}={v}" for k, v in jobs[0].wildcards.items()) or "no wildcards"
    return (f"rule{'s' * (len(rules) > 1)} {', '.join(rules)} ({len(jobs)} jobs, e.g. {example}): {what}. "
            f"`sbatch --test-only {' '.join(flags)}` says: {' '.join(test.stderr.split())}")

"""The settings of the grid's jobs: each answer read from the configuration and the job's wildcards.

A method's ``w`` is the job's wildcards (any object with them as attributes: ``scene``, ``source``,
``model``, ``poses``, ``rep``, ``method``, ``fold``, ``budget``). :class:`spc3d.sweeps.plan.Point`
answers the same questions for a sweep point's jobs, so a rule asks whichever the job's overlay picks.
"""

from __future__ import annotations

import functools
from pathlib import Path

from spc3d.jobs import folder_files, llff_input_files, scene_fold
from spc3d.names import (
    display_budget,
    joint_settings,
    parse_source,
    reads_capture_frame,
    resolve_combinations,
    source_frames,
    source_images,
    spc_settings,
    stage2_row_settings,
    translator_settings,
    translator_validation,
    uses_display,
)
from spc3d.provenance import closure_digest, entry_file
from spc3d.settings.params import (
    AugmentParams,
    ChoiceParams,
    ColmapParams,
    DisplayParams,
    PosesParams,
    ReconstructParams,
    ScoreParams,
    TablesParams,
    TranslateParams,
    TranslatorParams,
)
from spc3d.settings.paths import Paths
from spc3d.specs import RECONSTRUCTORS
from spc3d.specs.translators import split_count

# The scripts a translator's weights depend on: its own job's and those upstream of it.
TRANSLATOR_SCRIPTS = ("prepare_scene", "simulate_scene", "augment_scene", "train_translator")


class Grid:
    """What a job of the grid runs with.

    ``config``: the checked configuration; ``specs``: every scene's spec (spc3d.jobs.scene_specs);
    ``folds``: each fold's training scenes ("" or "-without-{scene}": spc3d.jobs.training_folds);
    ``basedir``: the workflow's folder (its scripts are in workflow/scripts).
    """

    def __init__(self, config: dict, specs: dict[str, dict], folds: dict[str, list[str]], basedir: str = "."):
        self.config, self.specs, self.folds, self.basedir = config, specs, folds, str(basedir)
        self.paths = Paths("")
        self.train, self.eval = list(config["scenes"]["train"]), list(config["scenes"]["eval"])
        self.no_reference = [n for n, s in specs.items() if s["kind"] == "capture" and not s["reference"]]
        self.joint_choose = config["stage2"]["joint"].get("choose") or {}
        # Captured SPAD scenes' sensors: their translators train on inputs as that sensor records them
        # (one model folder per sensor, results/models-rggb/...).
        self.sensors = {f"-{s['sensor_tag']}": s["sensor"] for s in specs.values() if s["kind"] == "capture"}

    # --- the run --------------------------------------------------------------------------------
    def seed(self, w) -> int:
        """The seed of a run from its tag ('' = config ``seed``; "-seed{N}": N)."""
        return int(w.rep.removeprefix("-seed")) if w.rep else self.config["seed"]

    def frames(self, w) -> int | None:
        """Binary frames per view (K) the row's source consumes; None for the oracle."""
        return source_frames(w.source, self.config["stage1"]["frames"], self.config["stage2"]["frames"])

    def fold(self, w) -> str:
        """The fold of the job's evaluation scene ("" or "-without-{scene}")."""
        return scene_fold(w.scene, self.train, self.config["scenes"]["leave_one_out"])

    def training_scenes(self, w) -> list[str]:
        """The training scenes of a fold's model folder or display level."""
        return self.folds[w.fold]

    # --- scenes and their SPC frames -------------------------------------------------------------
    def scene_spec(self, w) -> dict:
        """The scene's spec as prepare_scene renders or imports it."""
        return self.specs[w.scene]

    def source_spec(self, w) -> dict:
        """The scene's spec as configured (where its files are)."""
        return self.specs[w.scene]

    def scene_files(self, w) -> list[str]:
        """The files of a real scene or capture (every one read: an edit reruns it); none for built-ins."""
        spec = self.source_spec(w)
        if spec["kind"] == "llff":
            return llff_input_files(spec["path"], spec["factor"])
        hot = [spec["overrides"]["hot_pixels"]] if spec.get("overrides", {}).get("hot_pixels") else []
        return folder_files(spec["path"]) + hot if spec["kind"] in ("colmap", "capture") else []

    def spc(self, w) -> dict:
        """A simulated scene's physics and seed; a capture's folder (its frames are read, one
        measurement for every seed)."""
        spec = self.specs[w.scene]
        if spec["kind"] == "capture":
            return {"capture": spec["path"], "overrides": spec["overrides"]}
        return spc_settings(self.config["spc"], self.seed(w))

    def capture_factor(self, w) -> int:
        """S of a source's images (S x S sensor pixels per working pixel): spc.capture_factor for the
        capture-resolution frame of a simulated scene (a capture has no finer frame), else 1."""
        simulated = self.specs[w.scene]["kind"] != "capture"
        reads = reads_capture_frame(w.source, self.config["stage2"]["frames"])
        return self.config["spc"]["capture_factor"] if simulated and reads else 1

    def sensor(self, w) -> str:
        """ "" for a simulated scene (the simulator's RGB sensor), "-<tag>" for a capture's sensor."""
        spec = self.specs[w.scene]
        return f"-{spec['sensor_tag']}" if spec["kind"] == "capture" else ""

    def augment_count(self, w) -> int:
        """Augmented pairs of one training scene (augment.count split over the training scenes)."""
        train = self.train
        return split_count(self.config["augment"]["count"], len(train), train.index(w.scene))

    def display_training(self, w) -> dict[str, list[str]]:
        """Scene and SPC folders of the training scenes a display level is fitted on."""
        scenes = self.training_scenes(w)
        return {"scenes": [self.paths.scene(s) for s in scenes], "spc": [self.paths.spc(s, w.rep) for s in scenes]}

    def display_calibration(self, w) -> str:
        """The display level of the scene's fold at the display's budget."""
        return self.paths.calibration(self.fold(w), w.budget, w.rep)

    def held_out_frames(self, w) -> str | list:
        """A scene without reference views is scored on its held-out frames (spc3d.evaluation.heldout)."""
        return self.paths.spc(w.scene) if w.scene in self.no_reference else []

    def colmap_images(self, w) -> str:
        """The folder holding the image set a COLMAP run reads ({images}: rgb, binary or average)."""
        return self.paths.scene(w.scene) if w.images == "rgb" else self.paths.spc(w.scene)

    # --- the metered MLE display -----------------------------------------------------------------
    def display(self, w) -> str:
        """The metered MLE images of the row's frame budget (mle / bernoulli rows); a capture has no
        finer frame (S = 1), so its capture-frame rows read frame 0's display."""
        budget = display_budget(w.source, self.config["stage2"]["frames"], self.config["stage1"]["frames"])
        if budget == "capture" and self.specs[w.scene]["kind"] == "capture":
            budget = "k1"
        return self.paths.display(w.scene, budget, w.rep)

    # --- stage 1 ---------------------------------------------------------------------------------
    def translator(self, w) -> tuple[dict, dict]:
        """(model overrides, training settings) of ``w.method`` (spc3d.names.translator_settings)."""
        return translator_settings(self.config["stage1"], w.method)

    def translator_settings(self, w) -> dict:
        """The method's model overrides (its config block without the 'train' block)."""
        return self.translator(w)[0]

    def translator_train(self, w) -> dict:
        """stage1.train, overridden by the method's own 'train' block."""
        return self.translator(w)[1]

    def translator_frames(self, w) -> int:
        """stage1.frames: the binary frames a translator reads."""
        return self.config["stage1"]["frames"]

    def translator_data(self, w) -> str:
        """stage1.data: "fixed" augmented pairs or "online" samples."""
        return self.config["stage1"]["data"]

    def translator_validation(self, w) -> dict:
        """stage1.validation, overridden by the method's own 'validation' block."""
        return translator_validation(self.config["stage1"], w.method)

    def translator_pretrained(self, w) -> list[str]:
        """Published weights the method starts from (an input: replacing the file retrains it); none by default."""
        path = self.translator_settings(w).get("checkpoint")
        return [path] if path else []

    def translator_inputs(self, w) -> dict[str, list[str]]:
        """A translator's training data: the augmented pairs (stage1.data: fixed) and, for online
        samples or validation (on their held-out views), the training scenes and their SPC folders."""
        scenes, inputs = self.training_scenes(w), {}
        if self.translator_data(w) == "fixed":
            inputs["pairs"] = [self.paths.augment(s, w.rep) for s in scenes]
        if self.translator_data(w) == "online" or self.translator_validation(w)["every"] > 0:
            inputs["scenes"] = [self.paths.scene(s) for s in scenes]
            inputs["spc"] = [self.paths.spc(s, w.rep) for s in scenes]
        return inputs

    def translator_base(self, w) -> str:
        """The method a model folder trains ("pix2pixhd" for "pix2pixhd-pub", whose settings say prior_sigma: 0)."""
        return parse_source(w.method).base

    def translator_model(self, w) -> str:
        """The model trained for the scene's sensor on the scene's fold of training scenes."""
        return self.paths.model(w.method, self.sensor(w), self.fold(w), w.rep)

    def source_kind(self, w) -> tuple[str, str]:
        """(folder kind, subfolder) of the source's images (spc3d.names.source_images)."""
        return source_images(w.source, self.config["stage2"]["frames"])

    def source_subdir(self, w) -> str:
        return self.source_kind(w)[1]

    def source_images(self, w) -> str:
        """The folder holding a source's images (stage-1 output, metered MLE, binary frame, ground truth)."""
        kind = self.source_kind(w)[0]
        if kind == "translated":
            return self.paths.translated(w.scene, parse_source(w.source).method, w.rep)
        if kind == "display":
            return self.display(w)
        if kind == "scene":
            return self.paths.scene(w.scene)
        return self.paths.spc(w.scene, w.rep)

    # --- stage 2 ---------------------------------------------------------------------------------
    def model_settings(self, w) -> dict:
        """The stage-2 model's settings for the row (spc3d.names.stage2_row_settings)."""
        return stage2_row_settings(self.config["stage2"], w.model, w.poses or None)

    def init(self, w) -> str | None:
        """stage2.init: where a 3DGS fit's points start ("colmap" or "random")."""
        return self.config["stage2"]["init"]

    def chooses_joint_weight(self, w) -> bool:
        """Whether a joint row's prior weight is chosen per fold (stage2.joint.choose lists the model)."""
        return parse_source(w.source).joint and w.model in self.joint_choose

    def reconstruct_inputs(self, w) -> dict[str, str]:
        """The scene, its SPC folder for the SPC-derived sources, the stage-1 images or the metered
        MLE display (mle: its images; bernoulli: its gain), COLMAP's points for a 3DGS init, the
        estimated poses and the fold's chosen joint weight, as the row reads them."""
        name = parse_source(w.source)
        inputs = {"scene": self.paths.scene(w.scene)}
        if name.base != "gt":
            inputs["spc"] = self.paths.spc(w.scene, w.rep)
        if name.method:
            inputs["translated"] = self.paths.translated(w.scene, name.method, w.rep)
        if uses_display(w.source):
            inputs["display"] = self.display(w)
        if RECONSTRUCTORS[w.model].accepts_points and self.init(w) == "colmap":
            inputs["colmap"] = self.paths.colmap(w.scene, "rgb")
        if w.poses:
            inputs["poses"] = self.paths.poses(w.scene, w.poses[1:], w.rep)
        if self.chooses_joint_weight(w):
            inputs["choice"] = self.paths.choice(self.fold(w), f"{w.source}+{w.model}", w.rep)
        return inputs

    def checkpoint(self, w) -> str:
        """Where a stage-2 fit keeps its checkpoint (outside its output folder)."""
        return self.paths.checkpoint(w.scene, f"{w.source}+{w.model}{w.poses}", w.rep)

    def joint(self, w) -> dict | None:
        """stage2.joint for a joint row's model (the prior term's schedule), None for every other row."""
        return joint_settings(self.config["stage2"]["joint"], w.model) if parse_source(w.source).joint else None

    # --- a fold's choice of a joint row's prior weight (rule choose_joint_weight: the grid's alone) ----
    def choice_display(self, w) -> tuple[int, bool, str]:
        """(K, capture, budget) of the display the joint row ``joint-{w.method}`` reads."""
        stage1, stage2 = self.config["stage1"]["frames"], self.config["stage2"]["frames"]
        budget = display_budget(f"joint-{w.method}", stage2, stage1)
        return (1, True, budget) if budget == "capture" else (int(budget[1:]), False, budget)

    def choice_frames(self, w) -> int | None:
        return source_frames(f"joint-{w.method}", self.config["stage1"]["frames"], self.config["stage2"]["frames"])

    def choice_settings(self, w) -> dict:
        """The model's settings as the joint row fits it (no estimated poses)."""
        return stage2_row_settings(self.config["stage2"], w.model, None)

    def choice_joint(self, w) -> dict:
        return joint_settings(self.config["stage2"]["joint"], w.model)

    def choice_candidates(self, w) -> list[float]:
        """The prior weights tried (stage2.joint.choose's list for the model)."""
        return self.joint_choose[w.model]

    def choice_inputs(self, w) -> dict:
        """The fold's model of the method, its display level, and the fold's training scenes the
        method validates on and never trains on (stage1.validation.hold_out), with their frames."""
        n = translator_validation(self.config["stage1"], w.method).get("hold_out", 0)
        held = self.folds[w.fold][-n:] if n else []
        return {
            "model": self.paths.model(w.method, "", w.fold, w.rep),
            "calibration": self.paths.calibration(w.fold, self.choice_display(w)[2], w.rep),
            "scenes": [self.paths.scene(s) for s in held],
            "spc": [self.paths.spc(s, w.rep) for s in held],
        }

    # --- code keys: a param, so a change of the code a job runs reruns it ------------------------------
    def translator_code(self, w) -> str:
        """The library code a translator's weights depend on (its job's and the upstream scripts, its
        model's module and every spc3d module they import; comments, docstrings and formatting do not
        count): a change reruns the training, and ``--cache`` keys on it (spc3d.provenance)."""
        from spc3d.specs import TRANSLATORS

        return job_code(self.basedir, TRANSLATOR_SCRIPTS, TRANSLATORS[self.translator_base(w)].module)

    def reconstruct_code(self, w) -> str:
        """The same key for a stage-2 fit: its script, its model's factory module and what they import."""
        return job_code(self.basedir, ("reconstruct",), RECONSTRUCTORS[w.model].factory.rpartition(":")[0])

    # --- each rule's params object (spc3d.settings.params), handed to its script whole -------------------
    def colmap_params(self, w) -> ColmapParams:
        subdir = {"rgb": "images", "binary": "binary", "average": "average"}[w.images]
        return ColmapParams(subdir, self.config["colmap"]["max_features"], self.config["seed"])

    def poses_params(self, w) -> PosesParams:
        return PosesParams(self.source_subdir(w), self.frames(w), self.config["colmap"]["max_features"], self.seed(w))

    def display_params(self, w) -> DisplayParams:
        """K of a metered display ("k16": 16; "capture": the one capture-resolution frame)."""
        capture = w.budget == "capture"
        return DisplayParams(1 if capture else int(w.budget[1:]), capture)

    def augment_params(self, w) -> AugmentParams:
        return AugmentParams(self.augment_count(w), self.config["augment"], self.seed(w))

    def translator_params(self, w) -> TranslatorParams:
        ranges = {k: v for k, v in self.config["augment"].items() if k != "count"}  # what online samples draw
        return TranslatorParams(
            self.translator_base(w),
            self.translator_settings(w),
            self.translator_train(w),
            self.translator_frames(w),
            self.translator_data(w),
            ranges,
            self.sensors.get(w.sensor),
            self.translator_validation(w),
            self.seed(w),
            self.translator_code(w),
        )

    def translate_params(self, w) -> TranslateParams:
        return TranslateParams(self.translator_frames(w), self.config["stage1"]["ensemble"])

    def score_params(self, w) -> ScoreParams:
        return ScoreParams(self.source_subdir(w), self.frames(w), self.capture_factor(w), self.seed(w))

    def reconstruct_params(self, w) -> ReconstructParams:
        return ReconstructParams(
            self.model_settings(w),
            self.seed(w),
            self.frames(w),
            self.init(w),
            self.config["stage2"]["observe_plateau"],
            self.checkpoint(w),
            self.config["checkpoints"],
            self.joint(w),
            self.reconstruct_code(w),
        )

    def choice_params(self, w) -> ChoiceParams:
        return ChoiceParams(
            self.choice_settings(w),
            self.choice_joint(w),
            self.choice_candidates(w),
            self.seed(w),
            self.choice_frames(w),
            self.choice_display(w),
        )

    def tables_params(self) -> TablesParams:
        """The findings' rivals: the rows each claim over "every" row compares with (findings.rivals;
        a listed rival that did not run makes its claim NOT RUN, spc3d.evaluation.findings)."""
        nerf, findings = self.config["stage2"]["nerf_variant"], self.config["findings"]
        rivals = {k: resolve_combinations(v, nerf, f"findings.rivals.{k}") for k, v in findings["rivals"].items()}
        return TablesParams(nerf, findings["smallest_effect_db"], rivals)


@functools.cache
def job_code(basedir: str, scripts: tuple[str, ...], module: str) -> str:
    """:func:`spc3d.provenance.closure_digest` of the workflow scripts ``scripts`` (names in
    ``basedir``/workflow/scripts) and of ``module``'s file."""
    files = [Path(basedir) / "workflow" / "scripts" / f"{name}.py" for name in scripts]
    return closure_digest([*files, entry_file(module)])

"""The settings each job runs with (spc3d.settings): the grid's answers from the configuration, a
sweep point's with its knobs applied (spc3d.sweeps.plan.Point), and the results layout, each path
of which is one a rule makes."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

import pytest
from test_parse_checks import parse

from spc3d.inputs.scenes import LAYOUTS
from spc3d.jobs import scene_specs, training_folds, training_scene_names
from spc3d.settings import Grid, Paths, Targets
from spc3d.settings.params import PARAMS, SweepReportParams
from spc3d.sweeps import plan

from conftest import REPO

POINT = "sweeps/tradeoff/iters~300/K~4/"


def wildcards(**given) -> SimpleNamespace:
    every = {"scene": "courtyard", "source": "mle", "model": "3dgs", "poses": "", "rep": "", "method": "pix2pixhd"}
    return SimpleNamespace(**(every | {"fold": "", "budget": "k1"} | given))


def grid_of(*changes) -> Grid:
    """The grid as common.smk builds it from the configuration (config.yaml with ``changes``)."""
    config = parse(*changes)
    config["scenes"]["train"] = training_scene_names(config)
    folds = training_folds(config["scenes"]["train"], config["scenes"]["eval"], config["scenes"]["leave_one_out"])
    return Grid(config, scene_specs(config, sorted(LAYOUTS)), folds, REPO)


@pytest.fixture(scope="module")
def grid() -> Grid:
    return grid_of()


@pytest.fixture(scope="module")
def settings(grid) -> plan.Settings:
    train = ["tabletop"]
    specs = scene_specs(grid.config | {"scenes": {"train": train, "eval": ["courtyard"]}}, sorted(LAYOUTS))
    return plan.Settings(grid, plan.PointSettings(grid.config, specs, "courtyard", train, {}))


def rule_patterns() -> list[re.Pattern]:
    """Every results/ path the rules name (their outputs), wildcards as ``.*``."""
    text = "\n".join(p.read_text() for p in (REPO / "workflow" / "rules").glob("*.smk"))
    found = set(re.findall(r'"(results/[^"]+)"', text))
    return [re.compile(re.sub(r"\\\{\w+\\\}", ".*", re.escape(p))) for p in found]


@pytest.mark.parametrize("overlay", ["", POINT])
def test_every_path_of_the_layout_is_one_a_rule_makes(overlay):
    paths, patterns = Paths(overlay), rule_patterns()
    made = [
        paths.scene("courtyard"),
        paths.spc("courtyard", "-seed1"),
        paths.augment("tabletop"),
        paths.display("courtyard", "k16"),
        paths.calibration("-without-courtyard", "capture"),
        paths.model("pix2pixhd", "-rggb", "", "-seed1"),
        paths.translated("courtyard", "restormer"),
        paths.stage1("courtyard", "mle-k16"),
        paths.recon("courtyard", "gt+3dgs"),
        paths.metrics("courtyard", "gt+3dgs", "-seed2"),
    ]
    if not overlay:  # the grid's alone
        made += [paths.colmap("courtyard", "rgb"), paths.poses("courtyard", "mle-k16"), paths.choice("", "joint-a+b")]
        made += [paths.table("two_stage", "md"), paths.figure("qualitative_courtyard")]
        made += [paths.summary("data_summary.md")]
    for path in made:
        assert path.startswith(f"results/{overlay}")
        assert any(p.fullmatch(path) for p in patterns), f"{path}: no rule makes it"


def test_the_grid_answers_from_the_configuration(grid):
    config = grid.config
    assert grid.seed(wildcards()) == config["seed"] and grid.seed(wildcards(rep="-seed7")) == 7
    assert grid.frames(wildcards(source="mle-k16")) == 16 and grid.frames(wildcards(source="gt")) is None
    assert grid.fold(wildcards()) == "" and grid.training_scenes(wildcards()) == config["scenes"]["train"]
    assert grid.init(wildcards()) == config["stage2"]["init"]
    assert grid.translator_data(wildcards()) == config["stage1"]["data"]
    assert grid.display(wildcards(source="mle-k16")) == "results/mle/courtyard/k16"
    inputs = grid.reconstruct_inputs(wildcards(source="pix2pixhd", poses="@mle-k16", rep="-seed1"))
    assert inputs == {
        "scene": "results/scenes/courtyard",
        "spc": "results/spc/courtyard-seed1",
        "translated": "results/translate/courtyard/pix2pixhd-seed1",
        "poses": "results/poses/courtyard/mle-k16-seed1",
    }
    assert grid.translator_model(wildcards(rep="-seed1")) == "results/models/pix2pixhd-seed1"


def test_a_leave_one_out_grid_trains_each_scene_without_it(grid):
    """Folds as the real-scene preset plans them (built-in scenes share content, so the preset's
    LLFF scenes are the ones configured so; the fold logic is the same)."""
    scenes = {"train": ["courtyard", "tabletop"], "eval": ["courtyard"], "leave_one_out": True}
    folds = training_folds(scenes["train"], scenes["eval"], True)
    loso = Grid(grid.config | {"scenes": scenes}, grid.specs, folds, REPO)
    assert loso.fold(wildcards()) == "-without-courtyard"
    assert loso.training_scenes(wildcards(fold="-without-courtyard")) == ["tabletop"]
    assert loso.translator_model(wildcards()) == "results/models-without-courtyard/pix2pixhd"
    calibration = loso.display_calibration(wildcards(budget="k16"))
    assert calibration == "results/calibration-without-courtyard/display-k16.json"


def test_a_sweep_point_answers_with_its_knobs_and_its_own_scenes(grid, settings):
    point = settings.at(POINT)
    assert settings.at("") is grid and settings.at(POINT) is point  # one object per overlay
    w = wildcards()
    assert point.frames(w) == 4 and point.capture_factor(w) == 1 and point.init(w) is None
    assert point.fold(w) == "" and point.training_scenes(w) == ["tabletop"] and point.sensor(w) == ""
    assert point.translator_data(w) == "fixed" and point.translator_validation(w) == {"every": 0}
    assert point.display(w) == f"results/{POINT}mle/courtyard/k4"
    assert point.model_settings(w)["iterations"] == 300 != grid.model_settings(w).get("iterations")
    assert point.translator_frames(w) == 4 and point.seed(w) == grid.seed(w)
    assert point.augment_count(wildcards(scene="tabletop")) == grid.config["augment"]["count"]  # its one training scene
    assert point.translator_model(w) == f"results/{POINT}models/pix2pixhd"
    assert not point.chooses_joint_weight(wildcards(source="joint-pix2pixhd"))
    assert point.reconstruct_code(w) == grid.reconstruct_code(w)  # the same code runs
    knobs = settings.at("sweeps/tradeoff/iters~300/K~4/width~12/steps~3/")
    assert knobs.translator_settings(w)["ngf"] == 12 and knobs.translator_train(w)["iterations"] == 3


def test_the_targets_are_every_row_on_every_evaluation_scene_for_every_seed():
    grid = grid_of({"seeds": 2})
    targets = Targets(grid)
    combos, scenes = targets.combinations, grid.eval
    assert targets.reps == ["", f"-seed{grid.config['seed'] + 1}"]
    assert len(targets.metrics()) == len(combos) * len(scenes) * 2 == len(set(targets.metrics()))
    assert targets.metrics()[0] == f"results/eval/{scenes[0]}/{combos[0]}/metrics.json"
    assert set(targets.final()) >= {"results/summary/data_summary.md", "results/tables/findings.json"}
    assert targets.roles() == [
        " + ".join(r for r, names in (("train", grid.train), ("eval", grid.eval)) if s in names) for s in targets.scenes
    ]


def every_params_object(grid, settings) -> list:
    """One object of each rule's params type, as the grid's and a sweep point's jobs get them."""
    w, point = wildcards(images="binary", sensor=""), settings.at(POINT)
    joint = {"stage2": grid.config["stage2"] | {"joint": grid.config["stage2"]["joint"] | {"choose": {"3dgs": [0.1]}}}}
    chooser = Grid(grid.config | joint, grid.specs, grid.folds, REPO)
    made = [grid.colmap_params(w), grid.tables_params(), chooser.choice_params(wildcards(method="pix2pixhd"))]
    for job in (grid, point):
        made += [job.poses_params(w), job.display_params(w), job.augment_params(wildcards(scene="tabletop"))]
        made += [job.translator_params(w), job.translate_params(w), job.score_params(w), job.reconstruct_params(w)]
    return made + [SweepReportParams([{"combination": "gt+3dgs"}], ["gt+3dgs"], "wall")]


def test_every_rule_gets_one_params_object_that_snakemake_compares(grid, settings):
    """A changed setting reruns its job only if Snakemake can compare the params (builtin types: a
    dataclass would be dropped from the comparison, silently) and --cache can hash them (JSON)."""
    from snakemake.persistence import UNREPRESENTABLE
    from snakemake.persistence import PersistenceBase as Persistence

    made = every_params_object(grid, settings)
    assert {type(p) for p in made} == set(PARAMS)
    for params in made:
        assert Persistence._serialize_param_builtin(None, params) is not UNREPRESENTABLE, type(params).__name__
        json.dumps(params)
        changed = params._replace(**{params._fields[0]: "changed"})
        assert Persistence._serialize_param_builtin(None, changed) != Persistence._serialize_param_builtin(None, params)
    rules = "\n".join(p.read_text() for p in (REPO / "workflow" / "rules").glob("*.smk"))
    for block in re.findall(r"\n    params:\n((?:        .*\n)+)", rules):
        names = re.findall(r"^        (\w+)=", block, re.M)
        assert names == ["job"] or len(names) == 1 or names[0] == "job", names  # one object (the tables rule: + files)


def test_a_jobs_params_object_holds_the_answers_it_is_built_from(grid, settings):
    w, point = wildcards(source="joint-pix2pixhd", rep="-seed3", sensor=""), settings.at(POINT)
    fit = grid.reconstruct_params(w)
    assert fit.settings == grid.model_settings(w) and fit.seed == 3 and fit.frames == grid.frames(w)
    assert fit.joint == grid.joint(w) is not None and fit.code == grid.reconstruct_code(w)
    assert fit.checkpoint == grid.checkpoint(w) and fit.observe == grid.config["stage2"]["observe_plateau"]
    assert fit.init == grid.config["stage2"]["init"] and point.reconstruct_params(w).init is None
    assert point.reconstruct_params(w).settings["iterations"] == 300
    trained = grid.translator_params(wildcards(method="pix2pixhd-pub", sensor=""))
    assert trained.method == "pix2pixhd" and trained.sensor is None and "count" not in trained.augment
    assert trained.settings == grid.translator_settings(wildcards(method="pix2pixhd-pub"))
    assert point.translator_params(w).data == "fixed" and point.translator_params(w).frames == 4
    assert grid.display_params(wildcards(budget="k16")) == (16, False)
    assert grid.display_params(wildcards(budget="capture")) == (1, True)
    assert grid.colmap_params(wildcards(images="rgb")).subdir == "images"
    assert grid.poses_params(wildcards(source="mle-k16")).frames == 16
    assert grid.score_params(w).seed == 3 and point.score_params(w).capture_factor == 1
    assert grid.tables_params().smallest_effect == grid.config["findings"]["smallest_effect_db"]
    rivals, nerf = grid.tables_params().rivals, grid.config["stage2"]["nerf_variant"]
    assert rivals["mle"] == ["mle-x1+3dgs", "mle-x1-mse+3dgs"] and rivals["two_stage"][0] == f"pix2pixhd+{nerf}"
    capture = {"kind": "capture", "reference": True, "sensor_tag": "rggb", "sensor": "cfa"}
    captured = Grid(grid.config, grid.specs | {"cap": capture}, grid.folds, REPO)
    assert captured.translator_params(wildcards(sensor="-rggb")).sensor == "cfa"

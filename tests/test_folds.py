"""Leave-one-scene-out: each evaluation scene's translators and display level are fitted on the
training scenes without it (spc3d.jobs.training_folds), and the real-scene preset refuses a missing
LLFF folder by name before any job."""

import pytest
from snakemake.utils import update_config, validate

from spc3d.config import check_config, read_yaml, resolve_paths
from spc3d.inputs.scenes import LAYOUTS
from spc3d.jobs import scene_fold, scene_specs, training_folds
from spc3d.names import ConfigError

from conftest import LLFF_ROOT, REPO, run_snakemake

SCHEMA_PATH = REPO / "workflow" / "schemas" / "config.schema.yaml"
PRESET = REPO / "workflow" / "presets" / "findings-llff.yaml"
LLFF = ("canclip", "fern", "flower", "fortress", "ollie", "trex")


def test_each_scene_is_evaluated_without_itself():
    folds = training_folds(list(LLFF), list(LLFF), True)
    assert folds[""] == list(LLFF)  # all of them: the sweeps' and the data summary's
    for scene in LLFF:
        assert scene_fold(scene, list(LLFF), True) == f"-without-{scene}"
        assert sorted(folds[f"-without-{scene}"]) == sorted(s for s in LLFF if s != scene)
    # the fold's last scene (held out by stage1.validation.hold_out: 1) is the one before the left-out
    # scene, cyclically: each scene is held out by exactly one fold
    last = [folds[f"-without-{scene}"][-1] for scene in LLFF]
    assert last == [LLFF[i - 1] for i in range(len(LLFF))] and sorted(last) == sorted(LLFF)
    # An evaluation scene outside scenes.train uses all of it; without leave_one_out there are no folds.
    assert scene_fold("courtyard", list(LLFF), True) == ""
    assert training_folds(["a", "b"], ["c"], False) == {"": ["a", "b"]}
    assert training_folds([], ["c"], False) == {"": []}  # no translator at all: allowed (oracle-only runs)
    with pytest.raises(ConfigError, match="evaluating 'a' leaves no training scene"):
        training_folds(["a"], ["a"], True)


def _config(*changes, base=REPO) -> dict:
    config = read_yaml(REPO / "config.yaml")
    for change in changes:
        update_config(config, change if isinstance(change, dict) else read_yaml(change))
    check_config(config, read_yaml(SCHEMA_PATH))
    validate(config, schema=str(SCHEMA_PATH))
    resolve_paths(config, base)
    return config


def test_an_overlap_needs_leave_one_out_and_content_stays_disjoint_per_fold():
    overlap = {"scenes": {"train": ["tabletop", "orchard"], "eval": ["tabletop"]}}
    with pytest.raises(ConfigError, match=r"share \['tabletop'\].*scenes.leave_one_out: true"):
        scene_specs(_config(overlap), sorted(LAYOUTS))
    # The built-in training layouts share textures with each other: leaving one out is refused too.
    loso = {"scenes": {"train": ["tabletop", "orchard"], "eval": ["tabletop"], "leave_one_out": True}}
    with pytest.raises(ConfigError, match="share content"):
        scene_specs(_config(loso), sorted(LAYOUTS))


def test_the_real_scene_preset_refuses_a_missing_llff_folder_by_name(tmp_path):
    """A clone without ../shared beside it: the parse stops naming the scene, the folder and the way out."""
    missing = r"llff_scenes\.canclip: the folder .*shared/data/llff/canclip does not exist"
    with pytest.raises(ConfigError, match=missing):
        scene_specs(_config(PRESET, base=tmp_path / "clone"), sorted(LAYOUTS))


@pytest.mark.skipif(not (LLFF_ROOT / "fern").is_dir(), reason="needs the LLFF scenes of ../shared")
def test_the_real_scene_preset_plans_one_fold_per_scene(tmp_path):
    """Dry run of the preset: six folds of translators and display levels, each scene evaluated once per seed."""
    proc = run_snakemake(tmp_path, "-n", "--quiet", "rules", "--cores", "1", "--configfile", str(PRESET))
    assert proc.returncode == 0, proc.stderr[-3000:]
    config = _config(PRESET)
    folds = training_folds(config["scenes"]["train"], config["scenes"]["eval"], config["scenes"]["leave_one_out"])
    assert sorted(folds) == ["", *sorted(f"-without-{s}" for s in LLFF)]
    assert len(config["scenes"]["eval"]) >= 6  # scenes per row: a verdict's minimum (seeds do not count)


def test_configured_llff_scenes_join_the_training_scenes_unless_evaluated_or_switched_off():
    from spc3d.jobs import training_scene_names

    config = {
        "scenes": {"train": ["tabletop"], "eval": ["fern", "courtyard"]},
        "llff_scenes": {"fern": "a", "trex": "b", "tabletop": "c"},
    }
    assert training_scene_names(config) == ["tabletop", "trex"]  # fern is evaluated; tabletop listed once
    config["scenes"]["train_llff"] = False
    assert training_scene_names(config) == ["tabletop"]
    assert training_scene_names({"scenes": {"train": [], "eval": ["x"]}}) == []


@pytest.mark.parametrize(
    "llff, captures, match",
    [
        ({"courtyard": "x"}, {}, r"llff_scenes: 'courtyard' is also a built-in scene"),
        ({}, {"tabletop": "x"}, r"captures: 'tabletop' is also a built-in scene"),
        ({"lab": "x"}, {"lab": "y"}, r"captures: 'lab' is also in llff_scenes"),
    ],
)
def test_a_scene_name_given_twice_is_refused_naming_both(llff, captures, match):
    from spc3d.jobs import check_scene_names

    with pytest.raises(ConfigError, match=match):
        check_scene_names(["courtyard", "tabletop"], llff, captures)
    check_scene_names(["courtyard"], {"fern": "x"}, {"lab": "y"})  # distinct names pass

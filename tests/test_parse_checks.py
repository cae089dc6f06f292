"""Parse-time checks of values a job would refuse minutes later: each raises ConfigError naming the
key, the value and what would be right (spc3d.config, called by workflow/rules/common.smk).

Each check is called here as the workflow calls it: :func:`parse` runs the top of common.smk on
config.yaml with changes merged over it as Snakemake merges ``--configfile`` files (deep update).
"""

import inspect
import re
import subprocess
import sys

import pytest
import torch
from snakemake.utils import update_config, validate

from spc3d import config as spc_config
from spc3d import llff, specs
from spc3d.config import (
    check_config,
    check_settings,
    non_finite,
    read_yaml,
    resolve_paths,
    training_image_sizes,
    upgrade_keys,
)
from spc3d.inputs.augment import AugmentSettings
from spc3d.inputs.scenes import LAYOUTS, write_builtin_scene
from spc3d.jobs import scene_specs
from spc3d.names import ConfigError, parse_combination, resolve_combinations, stage1_sources
from spc3d.reconstruct.nerf_grid import GridNeRF
from spc3d.specs.reconstructors import reconstructor_config
from spc3d.specs.translators import model_config
from spc3d.translate.data import PairSampler
from spc3d.translate.model_io import MODULES, build_translator

from conftest import LLFF_ROOT, REPO, TINY_TRANSLATORS, run_snakemake

SCHEMA_PATH = REPO / "workflow" / "schemas" / "config.schema.yaml"
SCHEMA = read_yaml(SCHEMA_PATH)
PRESETS = sorted((REPO / "workflow" / "presets").glob("*.yaml"))
SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"


def merged(*changes) -> dict:
    """config.yaml with each change (a dict or a YAML file) deep-merged over it, as Snakemake merges
    ``--configfile`` files over the Snakefile's ``configfile:`` (snakemake.utils.update_config)."""
    config = read_yaml(REPO / "config.yaml")
    for change in changes:
        update_config(config, change if isinstance(change, dict) else read_yaml(change))
    return config


def parse(*changes) -> dict:
    """The top of workflow/rules/common.smk: schema (and finiteness), defaults, paths, scenes, then
    every settings block the combinations use (check_settings); the parsed config."""
    config = merged(*changes)
    upgrade_keys(config)
    check_config(config, SCHEMA)
    validate(config, schema=str(SCHEMA_PATH))  # fills in the schema's defaults, as common.smk does
    resolve_paths(config, REPO)
    scene_specs(config, sorted(LAYOUTS))
    combos = resolve_combinations(config["stage2"]["combinations"], config["stage2"]["nerf_variant"])
    check_settings(config, stage1_sources(combos), sorted({parse_combination(c)[1] for c in combos}), combos)
    return config


def only(*combinations: str) -> dict:
    return {"stage2": {"combinations": list(combinations)}}


# --- every preset passes every check -----------------------------------------------------------


@pytest.mark.parametrize("preset", [None, *PRESETS], ids=lambda p: p.stem if p else "config.yaml")
def test_default_config_and_every_preset_pass(preset):
    if preset and "../shared/data/llff" in preset.read_text() and not (LLFF_ROOT / "fern").is_dir():
        pytest.skip("the preset reads the LLFF scenes of ../shared")
    config = parse(*([preset] if preset else []))
    assert non_finite(config) == []


# --- every number finite -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text,message",
    [
        ("spc: {q: .nan}", r"spc\.q = nan: must be a finite number"),
        ("spc: {exposure_s: .inf}", r"spc\.exposure_s = inf: must be a finite number"),
        ("spc: {flux_scale: .inf}", r"spc\.flux_scale = inf: must be a finite number"),
        ("augment: {zoom: [0.8, .inf]}", r"augment\.zoom\.1 = inf: must be a finite number"),
        ("photon_level: {detection: [0.5, .nan]}", r"photon_level\.detection\.1 = nan: must be a finite number"),
        # free-form blocks the schema does not type: only this check sees them before a job
        ("stage2: {3dgs: {lr_means: -.inf}}", r"stage2\.3dgs\.lr_means = -inf: must be a finite number"),
        ("stage1: {pix2pix: {train: {decay_from: .nan}}}", r"stage1\.pix2pix\.train\.decay_from = nan: must be"),
        ("stage2: {nerf-grid: {res_schedule: [[0, 32], [.inf, 64]]}}", r"res_schedule\.1\.0 = inf: must be"),
    ],
)
def test_non_finite_numbers_are_named_by_their_key_path(tmp_path, text, message):
    path = tmp_path / "case.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError, match=message):
        check_config(merged(path), SCHEMA)


def test_non_finite_is_named_once_and_every_one_is_listed():
    config = merged({"spc": {"tau_d": float("-inf"), "q": float("nan")}, "checkpoints": {"minutes": float("inf")}})
    with pytest.raises(ConfigError) as e:
        check_config(config, SCHEMA)
    text = str(e.value)
    assert "spc.tau_d = -inf: must be a finite number" in text and "must be >= 0" not in text  # not twice
    assert "spc.q = nan" in text and "checkpoints.minutes = inf" in text


def test_non_finite_walks_lists_and_leaves_other_values_alone():
    node = {"a": [1, 2.5, {"b": float("nan")}], "c": True, "d": "inf", "e": None, "f": [[0, float("-inf")]]}
    assert [(path, repr(v)) for path, v in non_finite(node)] == [(("a", 2, "b"), "nan"), (("f", 0, 1), "-inf")]


def test_the_config_checker_cli_reports_non_finite_values(tmp_path, capsys):
    bad = tmp_path / "nan.yaml"
    bad.write_text("spc: {q: .nan}\n")
    assert spc_config.main([str(bad)]) == 1
    assert "spc.q = nan: must be a finite number" in capsys.readouterr().out


# --- augmentation ranges -------------------------------------------------------------------------


@pytest.mark.parametrize("combos", [["pix2pix+3dgs"], ["gt+3dgs"]], ids=["translator", "no-translator"])
def test_a_range_given_high_to_low_stops_the_parse(combos):
    with pytest.raises(ConfigError, match=r"augment\.zoom=\[2, 1\]: need 0 < min <= max"):
        parse(SMOKE, {"augment": {"zoom": [2, 1]}}, only(*combos))


def test_a_hold_out_that_leaves_no_scene_to_train_on_stops_the_parse():
    with pytest.raises(
        ConfigError,
        match=r"stage1\.validation\.hold_out = 3 \(pix2pix\) keeps all 3 training scene\(s\) of scenes\.train",
    ):
        parse({"stage1": {"validation": {"hold_out": 3}}}, only("pix2pix+3dgs"))
    parse({"stage1": {"validation": {"hold_out": 2}}}, only("pix2pix+3dgs"))
    parse({"stage1": {"validation": {"hold_out": 3, "every": 0}}}, only("pix2pix+3dgs"))  # no validation: unused


def test_the_parse_builds_the_augment_ranges_as_the_jobs_do():
    """Every key of the augment block but its count is a field of the settings the jobs build
    (spc3d.translate.train.training_data, workflow/scripts/augment_scene.py): the parse checks them all."""
    keys = set(SCHEMA["properties"]["augment"]["properties"]) - {"count"}
    assert keys == set(AugmentSettings.__dataclass_fields__)
    parse(SMOKE, {"augment": {"zoom": [1, 1]}}, only("pix2pix+3dgs"))  # one zoom: a valid range


# --- translator crops against the training images --------------------------------------------------


def test_a_crop_larger_than_the_builtin_images_stops_the_parse():
    with pytest.raises(
        ConfigError,
        match=r"stage1\.train\.crop = 64: larger than the smallest training image side, 48 px \(scene "
        r"'tabletop' is 64x48 at resolution\.width = 64\).*use stage1\.train\.crop <= 48",
    ):
        parse(SMOKE, {"stage1": {"train": {"crop": 64}}}, only("pix2pix+3dgs"))
    parse(SMOKE, {"stage1": {"train": {"crop": 48}}}, only("pix2pix+3dgs"))  # the whole height fits


def test_a_method_crop_is_named_by_its_own_key():
    change = {"stage1": {"diffusion": {"train": {"crop": 112}}}}
    with pytest.raises(ConfigError, match=r"stage1\.diffusion\.train\.crop = 112: larger than .* 96 px"):
        parse(change, only("diffusion+3dgs"))
    parse(change, only("pix2pix+3dgs"))  # a method the run does not train is not checked


@pytest.mark.parametrize("data", ["fixed", "online"])
def test_the_crop_check_applies_to_both_data_modes(data):
    with pytest.raises(ConfigError, match=r"stage1\.train\.crop = 56: larger than"):
        parse(SMOKE, {"stage1": {"data": data, "train": {"crop": 56}}}, only("restormer+3dgs"))


def test_an_llff_training_scene_is_cropped_at_its_own_aspect(tmp_path):
    """A 48x36 LLFF folder at resolution.width = 40 is 40x30; the parse knows it from the first
    image's header, and the sampler of the job agrees on the size and the limit."""
    mini = tmp_path / "mini"
    write_builtin_scene("observatory", mini, height=36, width=48, views=10, supersample=1)
    scene = {"llff_scenes": {"mini": str(mini)}, "scenes": {"train": ["mini"]}, "resolution": {"llff_factor": 1}}
    change = {**scene, "resolution": {"width": 40, "llff_factor": 1}}
    with pytest.raises(ConfigError, match=r"stage1\.train\.crop = 32: larger than .* 30 px \(scene 'mini' is 40x30"):
        parse(SMOKE, change, only("restormer+3dgs"))
    config = parse(SMOKE, change, {"stage1": {"train": {"crop": 24}}}, only("restormer+3dgs"))
    images = llff.load_llff(mini, factor=1, width=40).images
    assert training_image_sizes(config) == {"mini": images.shape[1:3]}
    views = torch.from_numpy(images).permute(0, 3, 1, 2)
    PairSampler(views, views, 2, 30, 0)  # the job's own condition: 30 fits, 31 does not
    with pytest.raises(ValueError, match=r"crop=31 exceeds the smallest training image side \(30 px\)"):
        PairSampler(views, views, 2, 31, 0)


# --- translator crops against the networks -------------------------------------------------------------


def test_a_crop_that_is_no_multiple_of_the_network_stops_the_parse():
    with pytest.raises(
        ConfigError,
        match=r"stage1\.train\.crop = 36: pix2pix needs crops whose side is a multiple of 8 "
        r"\(2\*\*\(num_downs\) = 2\*\*\(3\) in stage1\.pix2pix\); use a multiple of 8 \(e\.g\. 32\)",
    ):
        parse(SMOKE, {"stage1": {"train": {"crop": 36}}}, only("pix2pix+3dgs"))
    parse(SMOKE, {"stage1": {"train": {"crop": 36}}}, only("restormer+3dgs", "diffusion+3dgs"))  # they pad


def test_pix2pixhd_counts_its_local_enhancers():
    """36 is a multiple of the smoke preset's 2**2 but not of 2**(2 + 1) with one local enhancer."""
    parse(SMOKE, {"stage1": {"train": {"crop": 36}}}, only("pix2pixhd+3dgs"))
    change = {"stage1": {"train": {"crop": 36}, "pix2pixhd": {"n_local_enhancers": 1}}}
    with pytest.raises(
        ConfigError, match=r"multiple of 8 \(2\*\*\(n_downsample_global \+ n_local_enhancers\) = 2\*\*\(2 \+ 1\)"
    ):
        parse(SMOKE, change, only("pix2pixhd+3dgs"))


@pytest.mark.parametrize(
    "method,changes",
    [
        ("pix2pix", [{}, {"num_downs": 2}, {"num_downs": 5}]),
        ("pix2pixhd", [{}, {"n_local_enhancers": 1}, {"n_downsample_global": 1}]),
        ("cyclegan", [{}, {"n_downsampling": 3}]),
    ],
)
def test_the_crop_multiples_are_the_networks_own(method, changes):
    """The specs' crop_halvings restate each network's ``multiple``: the built models must agree."""
    for change in changes:
        cfg = model_config(method, {**TINY_TRANSLATORS[method], **change})
        assert specs.crop_multiple(method, cfg) == build_translator(method, cfg, torch.device("cpu")).multiple


def test_only_the_networks_that_check_their_crops_are_listed():
    """The built-in translators whose train_step checks its crops are those with crop_halvings."""
    builtin = {m: module for m, module in MODULES.items() if module.__name__.startswith("spc3d.translate.")}
    checked = {m for m, module in builtin.items() if "check_multiple(" in inspect.getsource(module)}
    assert checked == {m for m in builtin if specs.TRANSLATORS[m].crop_halvings}


# --- the grid schedule ------------------------------------------------------------------------------


def test_a_grid_schedule_that_starts_late_stops_the_parse():
    change = {"stage2": {"nerf-grid": {"res_schedule": [[10, 16], [20, 24]]}}}
    with pytest.raises(
        ConfigError,
        match=r"stage2\.nerf-grid\.res_schedule = \[\[10, 16\], \[20, 24\]\]: its first iteration is 10.*"
        r"start it at iteration 0",
    ):
        parse(SMOKE, change, only("gt+3dgs", "gt+nerf"))
    cfg = reconstructor_config("nerf-grid", change["stage2"]["nerf-grid"])
    with pytest.raises(ValueError):  # what the job would meet at its first step
        GridNeRF(cfg).res_for_step(1)
    parse(SMOKE, {"stage2": {"nerf-grid": {"res_schedule": [[1, 16], [20, 24]]}}}, only("gt+nerf"))
    parse(SMOKE, change, only("gt+3dgs"))  # no grid NeRF in the run


# --- a YAML syntax error in a --configfile ----------------------------------------------------------


def test_yaml_syntax_error_in_a_configfile_is_named(tmp_path):
    """Snakemake reads --configfile files itself (snakemake.settings.types.ConfigSettings, from
    its command line) before the Snakefile runs, so no code of this workflow sees them first. Its
    message names neither file nor line; its --verbose traceback (PyYAML's) names both, and so
    does ``python -m spc3d.config FILE``, which docs/configuration.md points to."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("spc:\n  frames: 4\n\tq: 0.5\n")
    plain = run_snakemake(tmp_path, "-n", "--configfile", str(bad), timeout=60)
    out = plain.stdout + plain.stderr
    assert plain.returncode != 0 and "Config file is not valid JSON or YAML" in out, out[-2000:]
    assert "Building DAG" not in out
    if str(bad) in out:  # a later Snakemake names the file itself: the notes above can go
        return
    verbose = run_snakemake(tmp_path, "-n", "--verbose", "--configfile", str(bad), timeout=60)
    assert re.search(rf'in "{re.escape(str(bad))}", line 3, column 1', verbose.stdout + verbose.stderr)
    cli = subprocess.run([sys.executable, "-m", "spc3d.config", str(bad)], capture_output=True, text=True)
    assert cli.returncode == 1 and f"{bad}:3:1: not valid YAML" in cli.stdout, cli.stdout + cli.stderr


def test_every_default_and_published_setting_lies_in_its_range():
    """The range rule (spc3d.specs.build.check_range) holds for every registered model's defaults and
    published sizes: it refuses only what no model means."""
    import dataclasses

    from spc3d.specs.build import check_range
    from spc3d.specs.translators import TrainSettings

    configs = [("train", TrainSettings())]
    for name, spec in specs.TRANSLATORS.items():
        module = specs.import_module(spec.module)
        configs += [(name, module.Config()), (f"{name}-paper", module.Config(**module.PAPER))]
    configs += [(name, specs.load(spec.config)({})) for name, spec in specs.RECONSTRUCTORS.items()]
    for where, cfg in configs:
        for f in dataclasses.fields(cfg):
            check_range(where, f.name, getattr(cfg, f.name))


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("lr", 0.0, "must be > 0"),
        ("lr_means_final", -1e-6, "must be > 0"),
        ("beta1", 1.0, r"must be in \[0, 1\)"),
        ("adam_betas", (0.9, 1.5), r"must be in \[0, 1\)"),
        ("lambda_A", -0.5, "must be >= 0"),
        ("prior_sigma", -1.0, "must be >= 0"),
        ("channel_mults", (1, -2), "must be >= 0"),
    ],
)
def test_the_range_rule_names_key_value_and_range(key, value, match):
    from spc3d.specs.build import check_range

    with pytest.raises(ValueError, match=rf"stage1\.m\.{key} = .*{match}"):
        check_range("stage1.m", key, value)
    check_range("stage1.m", "name", "text")  # not a number: not its business


def test_a_fixed_exposure_that_shows_no_image_is_warned_and_a_calibrated_one_is_not():
    from spc3d.config import check_exposure

    base = read_yaml(REPO / "config.yaml")
    assert check_exposure(base) == []  # calibrated to 0.5: reachable, nothing to say
    for flux, words in ((1e9, "every bit is 1"), (10.0, "show (almost) no image"), (3e4, None)):
        cfg = {**base, "spc": {**base["spc"], "flux_scale": flux}}
        warnings = check_exposure(cfg)
        assert (words in warnings[0]) if words else warnings == [], (flux, warnings)
    starved = {**base, "photon_level": {"detection": [0.005, 0.5]}}  # below the 1 % dark-count floor
    with pytest.raises(ConfigError, match=r"photon_level\.detection = 0\.005: dark counts alone fire 0\.00995"):
        check_exposure(starved)


def test_llff_images_narrower_than_the_working_width_are_named_as_upsampled(tmp_path, capsys):
    from spc3d.jobs import real_scene_spec

    write_builtin_scene("observatory", tmp_path / "mini", height=36, width=48, views=10, supersample=1)
    real_scene_spec("mini", tmp_path / "mini", {"width": 48, "llff_factor": 1})
    assert "upsampled" not in capsys.readouterr().err
    real_scene_spec("mini", tmp_path / "mini", {"width": 64, "llff_factor": 1})
    assert "resolution.width = 64 is wider than the images of llff_scenes.mini at llff_factor 1 (48 px)" in (
        capsys.readouterr().err
    )


def test_tuple_settings_have_the_shape_their_annotation_says():
    from spc3d.specs.build import check_shape

    pairs = tuple[tuple[int, int], ...]
    check_shape("k", ((0, 16), (20, 24)), pairs)
    check_shape("k", (1, 2, 2, 4), tuple[int, ...])
    check_shape("k", 3, int)  # not a tuple setting: not its business
    with pytest.raises(ValueError, match=r"k\[1\] = \[\[0, 16\], \[20\]\]: expected \[int, int\], got 1 item"):
        check_shape("k", ((0, 16), (20,)), pairs, ((0, 16), (20,)))
    with pytest.raises(ValueError, match=r"k = \[0.9\]: expected \[float, float\], got 1 item"):
        check_shape("k", (0.9,), tuple[float, float], (0.9,))
    with pytest.raises(ValueError, match=r"expected a list \(a list of \[int, int\]s\)"):
        check_shape("k", 5, pairs, 5)


def test_a_seed_numpy_and_torch_cannot_take_is_refused_by_the_schema():
    config = read_yaml(REPO / "config.yaml") | {"seed": 2**32}
    with pytest.raises(ConfigError, match=r"seed = 4294967296: must be <= 4294967295"):
        check_config(config, read_yaml(REPO / "workflow" / "schemas" / "config.schema.yaml"))

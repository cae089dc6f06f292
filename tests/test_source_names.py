"""The stage-2 source names (spc3d.names.SourceName): the suffixes -x1, -pub, -mse and -k<K>,
what each row reads and consumes, the published networks' settings, and the untrained prior as a
stage-1 method of its own."""

import re

import numpy as np
import pytest
import torch

from spc3d import names
from spc3d.config import read_yaml, workflow_config
from spc3d.names import (
    ConfigError,
    SourceName,
    display_budget,
    display_budgets,
    parse_source,
    reads_capture_frame,
    resolve_combinations,
    source_frames,
    source_images,
    source_label,
    stage1_sources,
    translator_settings,
)
from spc3d.translate import MODULES
from spc3d.translate.apply import translate_scene
from spc3d.translate.train import TranslatorJob, train_translator, training_data

from conftest import REPO


@pytest.mark.parametrize(
    "name,parsed",
    [
        ("none", SourceName("none")),
        ("none-x1-mse", SourceName("none", x1=True, mse=True)),
        ("mle-k16", SourceName("mle", 16)),
        ("mle-x1", SourceName("mle", x1=True)),
        ("pix2pixhd-pub", SourceName("pix2pixhd", pub=True)),
        ("prior", SourceName("prior")),
        ("bernoulli-k4", SourceName("bernoulli", 4)),
    ],
)
def test_names_round_trip(name, parsed):
    assert parse_source(name) == parsed and str(parsed) == name


def test_what_each_source_reads_and_consumes():
    assert parse_source("pix2pixhd-pub").method == "pix2pixhd-pub" and parse_source("prior").method == "prior"
    assert parse_source("none-x1-mse").method is None and parse_source("none-x1-mse").images == "none-x1"
    # The paper-faithful single stage reads the capture-resolution frame at K = 1, its -x1 form frame 0.
    assert reads_capture_frame("none", 1) and reads_capture_frame("mle", 1) and reads_capture_frame("none-mse", 1)
    assert not reads_capture_frame("none-x1", 1) and not reads_capture_frame("mle-k16", 1)
    assert not reads_capture_frame("mle", 4)  # stage2.frames = 4: four frames at the working resolution
    assert not reads_capture_frame("bernoulli", 1) and not reads_capture_frame("pix2pixhd", 1)
    assert source_images("none", 1) == ("spc", "capture") and source_images("none-x1-mse", 1) == ("spc", "binary")
    assert source_images("mle-x1", 1) == ("display", "images") and source_images("prior", 1)[0] == "translated"
    assert display_budget("mle", 1) == "capture" and display_budget("mle-x1-mse", 1) == "k1"
    assert display_budget("bernoulli", 1) == "k1" and display_budget("mle-k16", 1) == "k16"
    combos = ["mle+3dgs", "mle-x1-mse+3dgs", "bernoulli+3dgs", "mle-k16+3dgs", "none+3dgs"]
    assert display_budgets(combos, 1) == ["k1", "k16", "capture"]
    assert source_frames("none-x1", 1, 1) == 1 and source_frames("prior", 2, 1) == 2
    assert source_frames("pix2pix-pub", 1, 1) == 1 and source_frames("gt", 1, 1) is None


def test_stage1_sources_list_each_model_folder_once():
    combos = ["pix2pixhd+3dgs", "pix2pixhd-pub+nerf-grid", "prior+3dgs", "bernoulli+3dgs@pix2pix"]
    assert stage1_sources(combos) == ["pix2pixhd", "pix2pixhd-pub", "pix2pix", "prior"]


def test_published_networks_are_their_method_without_the_prior():
    stage1 = {
        "train": {"iterations": 10},
        "pix2pix": {"ngf": 8, "train": {"batch_size": 2}, "validation": {"every": 5}},
    }
    settings, train = translator_settings(stage1, "pix2pix-pub")
    assert settings == {"ngf": 8, "prior_sigma": 0.0} and train == {"iterations": 10, "batch_size": 2}
    assert translator_settings(stage1, "pix2pix")[0] == {"ngf": 8}
    assert names.translator_validation(stage1, "pix2pix-pub") == {"every": 5}


@pytest.mark.parametrize(
    "bad,match",
    [
        ("gt-x1+3dgs", "'-x1'"),
        ("mle-k16-x1+3dgs", "'-x1'"),
        ("prior-pub+3dgs", "'-pub'"),
        ("pix2pix-mse+3dgs", "'-mse'"),
        ("none-k4+3dgs", "frame budget"),
        ("none-mse-x1+3dgs", "unknown source"),
        ("blur+3dgs", "unknown source 'blur'"),
    ],
)
def test_bad_source_names_are_named(bad, match):
    with pytest.raises(ConfigError, match=match):
        resolve_combinations([bad], "nerf-grid")


def test_labels_say_what_each_suffix_means():
    assert source_label("none-x1-mse").startswith("binary frame (no stage 1); the frame at the working resolution")
    assert "MSE" in source_label("none-x1-mse") and source_label("mle-k16") == "MLE; K = 16"
    assert source_label("pix2pix-pub") == "Pix2Pix; the published network"


def test_registry_and_workflow_agree_on_the_prior():
    assert "prior" in MODULES and "prior" in names.STAGE1_METHODS
    assert "prior" not in names.TRAINED_METHODS and not MODULES["prior"].Translator.trainable


def test_the_prior_method_trains_nothing_and_translates_like_the_residuals_start(tmp_path):
    """``prior``: 0 steps, its gain fitted on the training pairs as a residual translator fits its
    prior's; its output equals the prior alone a trained residual model writes beside its images."""
    from spc3d.inputs.augment import AugmentSettings, augment_scene
    from spc3d.inputs.build import simulate_scene
    from spc3d.inputs.scenes import write_builtin_scene
    from spc3d.physics import spc

    from conftest import TINY_TRANSLATORS

    for name in ("tabletop", "courtyard"):
        write_builtin_scene(name, tmp_path / "scenes" / name, height=24, width=32, views=9, supersample=1)
        simulate_scene(tmp_path / "scenes" / name, tmp_path / "spc" / name, spc.SPCParams(frames=2), seed=0)
    augment_scene(tmp_path / "scenes" / "tabletop", tmp_path / "spc" / "tabletop", tmp_path / "pairs", 4,
                  AugmentSettings(), seed=0)  # fmt: skip
    train = {"iterations": 2, "batch_size": 2, "crop": 16, "log_every": 1}
    torch.set_num_threads(1)
    pairs = training_data("fixed", [tmp_path / "pairs"])
    rec = train_translator(TranslatorJob("prior", pairs, tmp_path / "m_prior", {}, train, seed=0))
    assert rec["iterations"] == 0 and rec["train"]["iterations"] == 0 and rec["parameters"] == {"prior": 0}
    assert rec["prior"]["sigma"] == 2.0 and all(g > 0 for g in rec["prior"]["gain"])
    tiny = TINY_TRANSLATORS["pix2pix"]
    other = train_translator(TranslatorJob("pix2pix", pairs, tmp_path / "m_p2p", tiny, train, seed=0))
    assert other["prior"]["gain"] == pytest.approx(rec["prior"]["gain"])  # the same data: the same gain
    args = (tmp_path / "spc" / "courtyard", tmp_path / "scenes" / "courtyard")
    translate_scene(tmp_path / "m_prior", *args, tmp_path / "t_prior", threads=1)
    translate_scene(tmp_path / "m_p2p", *args, tmp_path / "t_p2p", threads=1)
    assert not (tmp_path / "t_prior" / "prior").exists()  # its images are the prior: not written twice
    from spc3d import io

    for view in ("image000", "image004"):
        mine = io.read_rgb(tmp_path / "t_prior" / "images" / f"{view}.png")
        start = io.read_rgb(tmp_path / "t_p2p" / "prior" / f"{view}.png")
        np.testing.assert_array_equal(mine, start)


def test_a_capture_runs_single_frame_rows_as_their_working_resolution_variant(tmp_path):
    """A capture has no capture-resolution frame: its ``none`` / ``mle`` runs at K = 1 (S = 1) count
    as ``-x1`` rows, so a table over a simulated scene (S = 4) and a capture never mixes budgets."""
    from spc3d import io
    from spc3d.evaluation import tables
    from spc3d.names import as_read

    assert as_read("none+3dgs", 1, 1) == "none-x1+3dgs" and as_read("none-mse+3dgs", 1, 1) == "none-x1-mse+3dgs"
    assert as_read("none+3dgs", 1, 4) == "none+3dgs" and as_read("mle+3dgs", 16, 1) == "mle+3dgs"
    assert as_read("mle+3dgs", 1, None) == "mle+3dgs" and as_read("pix2pix+nerf", 1, 1) == "pix2pix+nerf"
    files = []
    for scene, S, psnr in (("sim", 4, 18.0), ("cap", 1, 9.0)):
        path = tmp_path / f"{scene}.json"
        io.write_json(path, {"scene": scene, "combination": "none+3dgs", "seed": 0, "frames": 1, "capture_factor": S,
                             "mean": {"psnr": psnr, "ssim": 0.5, "lpips_alex": 0.5, "lpips_vgg": 0.5}})  # fmt: skip
        files.append(str(path))
    summary = tables.summarise(tables.collect(files))
    assert summary.loc["none+3dgs", "S"] == 4 and summary.loc["none-x1+3dgs", "S"] == 1
    assert summary.loc["none+3dgs", "psnr_mean"] == 18.0 and summary.loc["none-x1+3dgs", "runs"] == 1


# --- the row grammar: one home (spc3d.names), read alike by the schema and the workflow --------------

PRESETS = ["config.yaml", *sorted(p.name for p in (REPO / "workflow" / "presets").glob("*.yaml"))]


def preset_rows(preset: str) -> tuple[set[str], set[str]]:
    """(rows of stage 2 and the findings' rivals, rows of the sweeps) a preset configures."""
    cfg = workflow_config() if preset == "config.yaml" else workflow_config(REPO / "workflow" / "presets" / preset)
    rivals = (cfg.get("findings") or {}).get("rivals") or {}
    rows = set(cfg["stage2"]["combinations"]).union(*rivals.values())
    sweeps = set().union(*((cfg.get(s) or {}).get("combinations") or [] for s in ("tradeoff", "photon_level")))
    return rows, sweeps


def test_the_schema_copies_the_row_grammar_of_spc3d_names():
    schema = read_yaml(REPO / "workflow" / "schemas" / "config.schema.yaml")["properties"]
    assert schema["stage2"]["properties"]["combinations"]["items"]["pattern"] == names.COMBINATION_PATTERN
    for sweep in ("tradeoff", "photon_level"):
        assert schema[sweep]["properties"]["combinations"]["items"]["pattern"] == names.SWEEP_COMBINATION_PATTERN


def test_the_workflow_constrains_its_wildcards_with_the_row_grammar():
    common = (REPO / "workflow" / "rules" / "common.smk").read_text()
    assert "source=SOURCE_PATTERN," in common and "poses=POSES_PATTERN," in common


@pytest.mark.parametrize("preset", PRESETS)
def test_every_row_of_every_preset_reads_alike_in_the_grammar_and_the_parser(preset):
    rows, sweeps = preset_rows(preset)
    assert rows, preset
    for combo in rows | sweeps:
        row = names.parse_row(combo)
        assert str(row) == combo  # parsed and printed back, character for character
        assert re.match(names.COMBINATION_PATTERN, combo), combo
        source = combo.partition("+")[0]
        assert re.fullmatch(names.SOURCE_PATTERN, source) and str(row.source) == source, combo
        assert re.fullmatch(names.POSES_PATTERN, f"@{row.poses}" if row.poses else ""), combo
        assert re.fullmatch(names.MODEL_PATTERN, row.model), combo
    for combo in sweeps:
        assert re.match(names.SWEEP_COMBINATION_PATTERN, combo), combo


@pytest.mark.parametrize(
    "combo",
    ["joint-pix2pix-pub+nerf-grid", "bernoulli-k4+3dgs@mle-k16", "none-x1-mse+3dgs", "gt+nerf@gt", "mle-k16+nerf"],
)
def test_a_row_name_round_trips_and_matches(combo):
    row = names.parse_row(combo)
    assert str(row) == combo and re.match(names.COMBINATION_PATTERN, combo)
    assert str(names.parse_row(str(row))) == combo


@pytest.mark.parametrize("combo", ["none-mse-x1+3dgs", "gt", "gt+3dgs@", "Gt+3dgs", "gt+3dgs@mle-k"])
def test_misspelt_rows_fail_the_grammar_or_the_round_trip(combo):
    row = names.parse_row(combo)
    assert not re.match(names.COMBINATION_PATTERN, combo) or str(row) != combo

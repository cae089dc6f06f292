"""Bad input, second round: one in-process test per class of mistake (docs/testing.md, "Bad input").

YAML 1.1 numbers read as another value, ranges with both ends, settings that contradict each other
(main configuration and sweep points), data that read fine but cannot be right (LLFF poses, capture
folders), per-part messages for combination names, command-line targets and config files answered
in the project's words, and no --directory left by a refused run. Each case is the library function
the Snakefile calls at parse time (or the job that records a warning), so nothing here runs
Snakemake's workflow.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from test_parse_checks import SMOKE, merged, only, parse

from spc3d import config as spc_config
from spc3d import io, llff
from spc3d.captures import folders as captures
from spc3d.checks.crosscheck import check_capture_frames, check_point, unused_blocks
from spc3d.checks.targets import check_targets, command_line_targets, explain_target, is_fresh_folder, remove_if_unused
from spc3d.config import read_yaml
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.names import ConfigError, combination_problem, resolve_combinations
from spc3d.physics import spc
from spc3d.sweeps import plan

from conftest import LLFF_ROOT, run_snakemake

# --- YAML 1.1 numbers that are another value ----------------------------------------------------


@pytest.mark.parametrize(
    "text,message",
    [
        (
            "resolution:\n  width: 0064\n",
            r"case\.yaml:2:10: 0064 is read by YAML 1\.1 as the octal number 52, not 64; "
            r"write 64 \(no leading zero\)",
        ),
        (
            "checkpoints:\n  minutes: 1:30\n",
            r"case\.yaml:2:12: 1:30 is read by YAML 1\.1 as a base-60 number \(90\), "
            r"not a time; write one number in the key's unit: 1\.5",
        ),
        ("spc: {frames: -0_17}\n", r"case\.yaml:1:15: -0_17 is read by YAML 1\.1 as the octal number -15"),
        ("checkpoints: {minutes: 1:30.5}\n", r"base-60 number \(90\.5\)"),
    ],
)
def test_octal_and_base_60_numbers_are_refused_with_file_line_and_spelling(tmp_path, text, message):
    path = tmp_path / "case.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        read_yaml(path)


def test_ordinary_numbers_and_quoted_text_still_read(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_text("a: 0\nb: 64\nc: 1e-3\nd: '0064'\ne: '1:30'\nf: 0x40\ng: 1_000\nh: 0.5\n")
    assert read_yaml(path) == {"a": 0, "b": 64, "c": "1e-3", "d": "0064", "e": "1:30", "f": 64, "g": 1000, "h": 0.5}
    assert spc_config.yaml_number("0128") is None  # not octal: YAML reads it as text, the schema names it


def test_a_missing_folder_or_empty_config_file_is_one_line_naming_it(tmp_path, capsys):
    (tmp_path / "empty.yaml").write_text("# only a comment\n")
    (tmp_path / "folder").mkdir()
    for name, words in (("empty.yaml", "is empty"), ("folder", "is a folder"), ("nope.yaml", "does not exist")):
        with pytest.raises(ConfigError, match=rf"config file .*{name} {words}"):
            read_yaml(tmp_path / name)
        assert spc_config.main([str(tmp_path / name)]) == 1
        out = capsys.readouterr().out
        assert words in out and len(out.strip().splitlines()) == 1, out
    assert read_yaml(tmp_path / "empty.yaml", empty_ok=True) == {}


# --- ranges with both ends ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change,combos,message",
    [
        (
            {"stage2": {"3dgs": {"ssim_weight": 2.0}}},
            ["gt+3dgs"],
            r"stage2\.3dgs\.ssim_weight = 2\.0: must be in \[0, 1\]",
        ),
        (
            {"stage2": {"3dgs": {"percent_dense": 1}}},
            ["gt+3dgs"],
            r"percent_dense = 1: must be in \[0, 1\) .*0\.01 is 1 %",
        ),
        (
            {"stage2": {"3dgs": {"background": [255, 255, 255]}}},
            ["gt+3dgs"],
            r"background = \[255, 255, 255\]: must be in \[0, 1\] \(a colour .*not 255\)",
        ),
        (
            {"stage2": {"nerf-grid": {"occupancy_thres": 2.0}}},
            ["gt+nerf"],
            r"occupancy_thres = 2\.0: must be in \[0, 1\)",
        ),
        ({"stage2": {"nerf-grid": {"lr_decay": 10.0}}}, ["gt+nerf"], r"lr_decay = 10\.0: must be in \[0, 1\]"),
        ({"stage1": {"train": {"decay_from": 1.5}}}, ["pix2pix+3dgs"], r"decay_from = 1\.5: must be in \[0, 1\]"),
        ({"stage1": {"restormer": {"betas": [0.9, 1.2]}}}, ["restormer+3dgs"], r"betas = .*must be in \[0, 1\)"),
        ({"augment": {"zoom": [0.01, 100.0]}}, ["gt+3dgs"], r"augment\.zoom\.0 = 0\.01: must be >= 0\.25"),
    ],
)
def test_fractions_weights_colours_and_thresholds_have_both_ends(change, combos, message):
    with pytest.raises(ConfigError, match=message):
        parse(SMOKE, change, only(*combos))


# --- settings that contradict each other -------------------------------------------------------------


@pytest.mark.parametrize(
    "change,combos,message",
    [
        (
            {"stage2": {"3dgs": {"pose_from": 1000}}},
            ["gt+3dgs@gt"],
            r"stage2\.3dgs\.pose_from = 1000: at or after the run's last step \(iterations = 40\)",
        ),
        (
            {"stage2": {"3dgs": {"densify_from": 50, "densify_until": 60}}},
            ["gt+3dgs"],
            r"densify_from = 50: at or after the run's last step \(iterations = 40\), so densification would never run",
        ),
        (
            {"stage2": {"3dgs": {"lr_means_final": 1e-3}}},
            ["gt+3dgs"],
            r"lr_means_final = 0\.001 is above lr_means = 0\.00016: .*set lr_means_final <= lr_means",
        ),
        (
            {"stage2": {"nerf_variant": "nerf-mlp", "nerf-mlp": {"lr_final": 1e-2}}},
            ["gt+nerf"],
            r"stage2\.nerf-mlp\.lr_final = 0\.01 is above lr = 0\.0005",
        ),
        (
            {"stage2": {"nerf-grid": {"res_schedule": [[0, 16], [60, 24]]}}},
            ["gt+nerf"],
            r"res_schedule = \[\[0, 16\], \[60, 24\]\]: the step\(s\) \[60\] are at or after .*n_iters = 40",
        ),
        ({"stage1": {"diffusion": {"sample_steps": 0}}}, ["diffusion+3dgs"], r"diffusion\.sample_steps = 0: DDIM"),
        (
            {"stage1": {"diffusion": {"sample_steps": 2000}}},
            ["diffusion+3dgs"],
            r"sample_steps = 2000: DDIM samples with 1 to timesteps = 1000 steps",
        ),
        (
            {"stage1": {"diffusion": {"clean_kernel": 4}}},
            ["diffusion+3dgs"],
            r"clean_kernel = 4: .*odd side \(e\.g\. 5\)",
        ),
        (
            {"stage1": {"restormer": {"dim": 6, "heads": [4, 1, 1, 1]}}},
            ["restormer+3dgs"],
            r"stage1\.restormer\.dim = 6, heads = \[4, 1, 1, 1\]: level 1 has dim x 1 = 6 channels, which 4",
        ),
        (
            {"stage2": {"joint": {"likelihood": False, "weight": 0.0, "weight_final": 0.0, "models": {}}}},
            ["joint-prior+3dgs"],
            r"likelihood = false and weight = weight_final = 0 turn off both terms",
        ),
    ],
)
def test_settings_that_contradict_each_other_stop_the_parse(change, combos, message):
    with pytest.raises(ConfigError, match=message):
        parse(SMOKE, change, only(*combos))


def test_a_feature_the_run_does_not_use_is_not_judged():
    parse(SMOKE, {"stage2": {"3dgs": {"pose_from": 1000}}}, only("gt+3dgs"))  # no row refines its cameras
    parse(SMOKE, {"stage1": {"diffusion": {"sample_steps": 0}}}, only("gt+3dgs"))  # no diffusion row


def sweep_points(config, table_row: str, combos: list[str], budget=None):
    specs = {
        "courtyard": {
            "kind": "builtin",
            "layout": "courtyard",
            "height": 48,
            "width": 64,
            "views": 9,
            "supersample": 1,
            "seed": 0,
        }
    }
    points = plan.PointSettings(config, specs, "courtyard", [], budget or {})
    return points, plan.overlay("photon_level" if budget else "tradeoff", table_row)


def test_every_sweep_point_is_cross_checked_with_its_knobs():
    """The tradeoff table's and photon_level's caps below init_points, and a schedule of the point
    outside its run, are named with the point (not silently lowered: spc3d.sweeps.budget)."""
    config = parse(SMOKE, only("gt+3dgs"))  # init_points 500
    points, value = sweep_points(config, "iters~20/cap~100", ["gt+3dgs"])
    with pytest.raises(
        ConfigError,
        match=r"sweeps/tradeoff/iters~20/cap~100 \(gt\+3dgs, .*cap = 100 is below "
        r"stage2\.3dgs\.init_points = 500: .*raise the cap column of tradeoff\.table to at least 500",
    ):
        check_point(points, "gt+3dgs", value)
    check_point(points, "gt+3dgs", plan.overlay("tradeoff", "iters~20/cap~500"))
    photon, value = sweep_points(config, "detection~0.5/K~1", ["gt+3dgs"], {"cap": 100})
    with pytest.raises(ConfigError, match=r"raise photon_level\.budget\.cap to at least 500"):
        check_point(photon, "mle+3dgs", value)
    late = parse(SMOKE, {"stage2": {"refine_poses": "all"}}, only("gt+3dgs"))  # pose_from 10 of 40 steps
    points, value = sweep_points(late, "iters~8", ["gt+3dgs"])  # iters scale the schedules, not pose_from
    with pytest.raises(ConfigError, match=r"iters~8 .*stage2\.3dgs\.pose_from = 10: at or after .*iterations = 8"):
        check_point(points, "gt+3dgs", value)
    planned = plan.sweep_points(
        "tradeoff",
        __import__("pandas").DataFrame({"cap": [100]}),
        ["cap~100"],
        ["gt+3dgs"],
        sweep_points(config, "cap~100", [])[0],
        "courtyard",
    )
    assert planned[0]["outputs"] == [] and "below stage2.3dgs.init_points" in planned[0]["error"]  # asked: raised


def test_an_unused_settings_block_is_a_warning_naming_it():
    given = {
        "stage1": {"cyclegan": {"ngf": 8}, "restormer": {}},
        "stage2": {"nerf-mlp": {"n_iters": 5}, "joint": {"weight": 1}},
    }
    warnings = unused_blocks(given, ["gt+3dgs", "pix2pix+nerf-grid"], "nerf-grid")
    assert [w.split(" is set")[0] for w in warnings] == ["stage1.cyclegan", "stage2.nerf-mlp", "stage2.joint"]
    assert "no row uses the method 'cyclegan'" in warnings[0] and "stage2.nerf_variant = 'nerf-grid'" in warnings[1]
    assert unused_blocks(given, ["cyclegan+nerf", "joint-cyclegan+3dgs"], "nerf-mlp") == []


def test_the_mlp_nerfs_old_names_run_as_the_new_ones_with_a_warning(tmp_path):
    """stage2.nerf (the MLP NeRF's block before it became nerf-mlp), nerf_variant: nerf and the
    joint rows' per-model keys still run: moved to the new names, one warning each."""
    old = {
        "stage2": {
            "nerf_variant": "nerf",
            "nerf": {"n_iters": 5},
            "joint": {"models": {"nerf": {"weight": 2.0}}, "choose": {"nerf": [1.0, 3.0]}},
        }
    }
    config = merged(old)
    warnings = spc_config.upgrade_keys(config)
    stage2 = config["stage2"]
    assert "nerf" not in stage2 and stage2["nerf-mlp"] == {**merged()["stage2"]["nerf-mlp"], "n_iters": 5}
    assert stage2["nerf_variant"] == "nerf-mlp"
    assert stage2["joint"]["models"] == {"nerf-grid": {"weight": 3.0, "weight_final": 3.0}, "nerf-mlp": {"weight": 2.0}}
    assert stage2["joint"]["choose"] == {"nerf-mlp": [1.0, 3.0]}
    assert [w.split(" is now")[0] for w in warnings] == [
        "stage2.nerf",
        "stage2.nerf_variant = 'nerf'",
        "stage2.joint.models.nerf",
        "stage2.joint.choose.nerf",
    ]
    assert "the MLP NeRF is 'nerf-mlp'" in warnings[0] and spc_config.upgrade_keys(config) == []
    parsed = parse({"stage2": {"nerf_variant": "nerf", "nerf": {"n_iters": 5}}}, only("gt+nerf"))
    assert parsed["stage2"]["nerf-mlp"]["n_iters"] == 5
    case = tmp_path / "old.yaml"
    case.write_text("stage2:\n  nerf_variant: nerf\n  nerf: {n_iters: 5}\n  combinations: [gt+nerf]\n")
    checker = subprocess.run([sys.executable, "-m", "spc3d.config", str(case)], capture_output=True, text=True)
    assert checker.returncode == 0 and "spc3d warning: stage2.nerf is now stage2.nerf-mlp" in checker.stdout
    assert checker.stdout.rstrip().endswith(f"{case}: ok"), checker.stdout
    out = run_snakemake(tmp_path / "work", "-n", "--configfile", str(case), timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stderr.count("spc3d warning: stage2.nerf is now stage2.nerf-mlp") == 1, out.stderr[-3000:]
    assert "gt+nerf-mlp" in out.stdout and "gt+nerf/" not in out.stdout


# --- combination names: per part ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "combo,message",
    [
        (
            "restormer+nerf_grid",
            "unknown model 'nerf_grid'; did you mean 'nerf-grid'? valid: 3dgs, nerf-mlp, nerf-grid, nerf",
        ),
        ("pix2pix_hd+3dgs", "unknown source 'pix2pix_hd'; did you mean 'pix2pixhd'? valid: gt, none, mle, bernoulli,"),
        ("gt+3dgs@colmp", "unknown pose source after '@' 'colmp'"),
        ("pix2pixhd", "a row is 'source+model' and has no '+' here (e.g. 'pix2pixhd+3dgs'"),
    ],
)
def test_a_combination_name_is_judged_part_by_part(combo, message):
    assert message in combination_problem(combo)
    if "@" not in combo:  # the schema's pattern error says the same (it admits any word after '@')
        with pytest.raises(ConfigError) as schema:
            spc_config.check_config(merged(only(combo)), read_yaml(spc_config.SCHEMA))
        assert message in str(schema.value) and "must match" not in str(schema.value)
    with pytest.raises(ConfigError, match="stage2.combinations: "):
        resolve_combinations([combo], "nerf-grid")
    assert combination_problem("joint-restormer-pub+3dgs@mle-k16") is None


# --- command-line targets, config files, the --directory ---------------------------------------------

NAMED, SCENES, ROWS = ["all", "tables", "tradeoff", "photon_level"], ["tabletop", "courtyard"], ["gt+3dgs"]


@pytest.mark.parametrize(
    "target,message",
    [
        ("tradeof", "unknown target 'tradeof'; did you mean 'tradeoff'? named targets: all, tables, tradeoff"),
        ("results/eval/mars/gt+3dgs/metrics.json", "unknown scene 'mars'; valid: tabletop, courtyard"),
        ("results/sweeps/tradeoff/iters~300/eval/courtyrd/gt+3dgs/metrics.json", "did you mean 'courtyard'?"),
        ("results/recon/courtyard/gt+nerf_grid", "unknown model 'nerf_grid'; did you mean 'nerf-grid'?"),
        ("results/figures/qualitative_mars.png", "unknown scene 'mars'"),
        ("results/tables/two_stag.md", "no rule makes this file; named targets: all, tables"),
        ("write_sumary", "did you mean 'write_summary'? named targets: all"),
    ],
)
def test_an_unknown_target_is_answered_with_the_configured_names(target, message):
    rules = [*NAMED, "write_summary", "evaluate"]
    assert message in explain_target(target, NAMED, SCENES, ROWS, rules)
    with pytest.raises(ConfigError, match="target|unknown"):
        check_targets([target], lambda t: False, NAMED, SCENES, ROWS, rules)
    check_targets(["tradeoff", "write_summary", "results/x"], lambda t: t == "results/x", NAMED, SCENES, ROWS, rules)


def test_the_targets_are_read_from_a_snakemake_command_line_only():
    argv = ["/venv/bin/snakemake", "tradeof", "results/x", "--cores", "2", "-n", "--configfile", "a.yaml"]
    assert command_line_targets(argv) == ["tradeof", "results/x"]
    assert command_line_targets(["/usr/bin/python", "-m", "pytest", "tradeof"]) == []


def test_a_refused_run_leaves_no_new_directory_and_keeps_an_old_one(tmp_path):
    started = time.time()
    old = tmp_path / "old"
    old.mkdir()
    os.utime(old, (started - 60, started - 60))
    assert not is_fresh_folder(old, started)  # made by the user before the command: kept
    new = tmp_path / "new"
    time.sleep(0.01)
    new.mkdir()
    assert is_fresh_folder(new, started)
    (new / ".snakemake" / "log").mkdir(parents=True)
    assert remove_if_unused(new) and not new.exists()  # only empty folders in it: gone
    kept = tmp_path / "kept"
    (kept / "results").mkdir(parents=True)
    (kept / "results" / "a.txt").write_text("x")
    assert not remove_if_unused(kept) and (kept / "results" / "a.txt").exists()  # a file: nothing removed


# --- data that read fine but cannot be right: LLFF poses ---------------------------------------------


def opencv_axes(pb: np.ndarray) -> np.ndarray:
    """LLFF [down, right, back] columns rewritten as OpenCV's [right, down, forward] (a rotation too)."""
    out = pb.copy()
    poses = out[:, :15].reshape(-1, 3, 5).copy()
    rot = poses[:, :, :3].copy()
    poses[:, :, 0], poses[:, :, 1], poses[:, :, 2] = rot[:, :, 1], rot[:, :, 0], -rot[:, :, 2]
    out[:, :15] = poses.reshape(-1, 15)
    return out


def test_translations_in_another_unit_than_the_bounds_are_warned(tmp_path):
    write_builtin_scene("observatory", tmp_path / "mini", height=36, width=48, views=10, supersample=1)
    pb = io.load_npy(tmp_path / "mini" / "poses_bounds.npy")
    assert llff.rig_warnings(pb) == []
    mm = pb.copy()
    poses = mm[:, :15].reshape(-1, 3, 5)
    poses[:, :, 3] *= 1000  # translations in mm, bounds in m
    mm[:, :15] = poses.reshape(-1, 15)
    assert "look like another unit than the bounds (mm against m?)" in llff.rig_warnings(mm)[0]
    far = pb.copy()
    far[:, 15:] *= 1000  # bounds in mm, translations in m
    assert "the bounds look like another unit" in llff.rig_warnings(far)[0]


@pytest.mark.skipif(not (LLFF_ROOT / "fortress").is_dir(), reason="needs ../shared/data/llff/fortress")
def test_opencv_axes_and_reversed_pose_rows_are_warned_from_the_images():
    """The images' sideways motion against the poses (fortress, 42 views): the real poses pass,
    OpenCV axes and reversed rows are named. The warnings reach the captions through the scene's
    records (prepare_scene's scene.json, then spc.json: test_scene_warnings_reach_the_captions)."""
    files, pb = llff.llff_contents(LLFF_ROOT / "fortress", 8)
    assert llff.rig_warnings(pb, files) == []
    assert "look like OpenCV axes" in llff.rig_warnings(opencv_axes(pb), files)[0]
    assert "pose rows look reversed" in llff.rig_warnings(pb[::-1].copy(), files)[0]


def test_scene_warnings_reach_the_captions(tmp_path):
    from spc3d.evaluation.tables import photon_note

    write_builtin_scene("courtyard", tmp_path / "scene", height=12, width=16, views=9, supersample=1)
    meta = io.read_json(tmp_path / "scene" / "scene.json")
    io.write_json(tmp_path / "scene" / "scene.json", meta | {"warnings": ["the pose rows look reversed"]})
    record = simulate_scene(tmp_path / "scene", tmp_path / "courtyard", spc.SPCParams(frames=2), seed=0)
    assert record["warnings"][0] == "the pose rows look reversed"
    assert "courtyard: the pose rows look reversed" in photon_note([tmp_path / "courtyard"])


# --- data that read fine but cannot be right: captures ------------------------------------------------


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("plausible")
    write_builtin_scene("courtyard", root / "scene", height=16, width=24, views=9, supersample=1, seed=0)
    simulate_scene(root / "scene", root / "spc", spc.SPCParams(frames=4), target_detection=0.3, seed=1)
    captures.export_simulated(root / "spc", root / "cap", "mono", "png", scene_dir=root / "scene")
    return root / "cap"


def capture_spec_of(folder, overrides=None):
    from spc3d.jobs import capture_spec

    config = read_yaml(SMOKE.parent.parent.parent / "config.yaml")
    return capture_spec("cap", {"path": str(folder), **(overrides or {})}, "eval", config)


def test_a_capture_that_cannot_be_right_is_refused(capture, tmp_path, capsys):
    import shutil

    assert capture_spec_of(capture)["frames"] == 4
    with pytest.raises(
        ConfigError,
        match=r"exposure_s = 10 s .*dark counts alone would fire 1\.0000 of the bits.*"
        r"is exposure_s in seconds\? 10 µs is 1e-05 s",
    ):
        capture_spec_of(capture, {"exposure_s": 10.0})
    with pytest.raises(ConfigError, match=r"frames fire .* but dark counts alone would fire"):
        capture_spec_of(capture, {"exposure_s": 0.01})  # 10 ms: every bit a dark count would be 1 - e^-1
    bad = tmp_path / "cap"
    shutil.copytree(capture, bad)
    hot = np.ones((16, 24), bool)
    hot[0, 0] = False
    io.save_npy(bad / "hot.npy", hot)
    with pytest.raises(ConfigError, match=r"hot\.npy: the hot-pixel map marks 100% of the sensor.*inverted"):
        capture_spec_of(bad, {"hot_pixels": "hot.npy"})
    some = np.zeros((16, 24), bool)
    some[:3] = True
    io.save_npy(bad / "some.npy", some)
    capture_spec_of(bad, {"hot_pixels": "some.npy"})
    assert "the hot-pixel map some.npy marks 18.8% of the sensor" in capsys.readouterr().err
    pb = io.load_npy(bad / "poses_bounds.npy")
    pb[2, 0:3] *= 2.0  # a scaled first row: not a rotation
    io.save_npy(bad / "poses_bounds.npy", pb)
    with pytest.raises(ConfigError, match=r"poses_bounds\.npy: the 3x3 part of view\(s\) 2 is not a rotation"):
        capture_spec_of(bad)


def test_png_frames_of_0_and_1_are_refused(capture, tmp_path):
    import shutil

    bad = tmp_path / "cap"
    shutil.copytree(capture, bad)
    first = sorted((bad / "frames").iterdir())[0]
    for png in sorted(first.glob("*.png")):
        bits = io.read_image(png)
        io.write_image(png, (bits / 255.0).astype(np.float32))  # 0/1 of 255
    with pytest.raises(ConfigError, match=r"a binary frame of 0 and 1 \(of 255\): .*write them as 0/255"):
        capture_spec_of(bad)


def test_a_row_reading_more_frames_than_a_capture_holds_is_refused(capture):
    specs = {"cap": capture_spec_of(capture)}
    config = parse(SMOKE, only("gt+3dgs"))
    check_capture_frames(specs, ["mle-k4+3dgs", "pix2pix+3dgs"], config)
    with pytest.raises(
        ConfigError, match=r"captures\.cap: holds 4 frames per view .* row 'mle-k16\+3dgs' reads K = 16"
    ):
        check_capture_frames(specs, ["gt+3dgs", "mle-k16+3dgs"], config)

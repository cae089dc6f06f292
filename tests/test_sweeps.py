"""Budget sweeps: Pareto fronts, knobs and tables, a point's settings overlay, a tiny sweep through
Snakemake end to end (the grid's rules under the overlay), reports, the rules."""

import json
import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import yaml
from snakemake.utils import Paramspace

from spc3d import io, names
from spc3d.jobs import BENCHMARK_COLUMNS
from spc3d.sweeps import knobs, plan
from spc3d.sweeps.budget import WIDTH_KEYS
from spc3d.sweeps.pareto import front_steps, pareto_mask

from conftest import REPO, exclusive, run_snakemake, session_folder

TABLE = REPO / "workflow" / "tradeoff.tsv"
SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
TINY_3DGS = {"iterations": 12, "densify_from": 4, "densify_until": 10, "densify_every": 4, "init_points": 300}
SPEC = {"kind": "builtin", "height": 36, "width": 48, "views": 9, "supersample": 1, "seed": 0}
CONFIG = {  # the config values PointSettings reads
    "seed": 0,
    "spc": {
        "mode": "bernoulli",
        "q": 0.45,
        "tau_d": 1.5e-7,
        "exposure_s": 1e-4,
        "dark_count_rate": 100.0,
        "frames": 4,
        "flux_scale": None,
        "target_detection": 0.5,
        "capture_factor": 4,
    },
    "augment": {"count": 4},
    "stage1": {"frames": 1},
    "stage2": {"frames": 1},
}


def point_settings(budget=None):
    specs = {"courtyard": SPEC | {"layout": "courtyard"}, "tabletop": SPEC | {"layout": "tabletop"}}
    return plan.PointSettings(CONFIG, specs, "courtyard", ["tabletop"], budget or {})


def test_a_sweep_that_cannot_run_stops_only_when_its_report_is_asked_for():
    """No training scene (an LLFF-only config): the Snakefile still parses, planning its sweeps;
    asking for the translator's points names why they cannot run."""
    specs = {"courtyard": SPEC | {"layout": "courtyard"}}
    points = plan.PointSettings(CONFIG, specs, "courtyard", [], {})
    table = pd.DataFrame({"iters": [10]})
    planned = plan.sweep_points("tradeoff", table, ["iters~10"], ["gt+3dgs", "pix2pix+3dgs"], points, "courtyard")
    assert planned[0]["outputs"] and "error" not in planned[0]
    assert planned[1]["outputs"] == [] and "needs training scenes" in planned[1]["error"]
    assert plan.point_inputs(planned[:1])  # the gt point alone is fine
    with pytest.raises(ValueError, match=r"sweeps/tradeoff/iters~10/: pix2pix\+3dgs: source 'pix2pix' needs training"):
        plan.point_inputs(planned)


# ---- Pareto front ----------------------------------------------------------------------------------
def test_pareto_front_drops_dominated_points():
    t = [10, 20, 15, 30, 5]
    q = [20, 25, 19, 25, 10]  # (15, 19) is slower and worse than (10, 20); (30, 25) only slower than (20, 25)
    assert pareto_mask(t, q).tolist() == [True, True, False, False, True]
    steps_t, steps_q = front_steps(t, q)
    assert steps_t.tolist() == [5, 10, 20] and steps_q.tolist() == [10, 20, 25]


def test_pareto_front_ties_single_point_and_nan():
    assert pareto_mask([10, 10, 10], [20, 20, 18]).tolist() == [True, True, False]  # exact ties both stay
    assert pareto_mask([10, 12], [20, 20]).tolist() == [True, False]  # same quality, slower: dominated
    assert pareto_mask([7.0], [3.0]).tolist() == [True]
    assert pareto_mask([1, 2], [np.nan, 5]).tolist() == [False, True]
    assert pareto_mask([1, 2], [np.inf, 5]).tolist() == [True, False]  # identical images: inf dB is the best


# ---- knobs, tables, combinations ---------------------------------------------------------------------
def test_models_and_widths_match_the_registries():
    """The torch-free vocabulary of spc3d.names (used by the rules and the sweeps) names exactly
    the registered models; every translator with a network has a width knob."""
    from spc3d.reconstruct import RECONSTRUCTORS
    from spc3d.translate import MODULES

    assert tuple(RECONSTRUCTORS) == names.STAGE2_MODELS
    assert set(WIDTH_KEYS) == {m for m, module in MODULES.items() if module.Translator.trainable}
    for method, key in WIDTH_KEYS.items():
        assert hasattr(MODULES[method].Config(), key)


def test_knobs_a_combination_uses():
    assert knobs.used_knobs("gt+3dgs") == ["iters", "res", "cap"]
    assert knobs.used_knobs("pix2pixhd+nerf-grid") == ["iters", "res", "K", "width", "steps", "grid", "detection"]
    assert knobs.used_knobs("bernoulli+3dgs") == ["iters", "res", "K", "cap", "detection"]
    table = pd.DataFrame({"iters": [10, 10, 20], "res": [32, 32, 32], "width": [8, 16, 8]})
    assert knobs.distinct_rows(table, "gt+3dgs") == [True, False, True]  # width changes nothing for gt
    assert knobs.distinct_rows(table, "pix2pix+3dgs") == [True, True, True]


def test_paramspace_paths_round_trip_to_the_settings():
    table = knobs.read_table(TABLE)
    assert len(table) >= 4 and list(table.columns) == [k for k in knobs.KNOBS if k in table.columns]
    for space, frame in ((Paramspace(table), table), (Paramspace(knobs.photon_table([0.02, 0.5], [1, 16])), None)):
        frame = space.dataframe if frame is None else frame
        regex = re.sub(r"\\\{(\w+)\\\}", r"(?P<\1>[^/]+)", re.escape(space.wildcard_pattern))
        for path, row in zip(space.instance_patterns, frame.to_dict("records"), strict=True):
            wildcards = re.fullmatch(regex, path).groupdict()
            assert knobs.check_setting(space.instance(wildcards), "t") == knobs.check_setting(row, "t")
    first = next(Paramspace(table).instance_patterns)
    assert first.startswith("iters~300/res~64/K~1/")


def test_bad_tables_settings_and_combinations_are_named(tmp_path):
    bad = tmp_path / "bad.tsv"
    bad.write_text("iters\tres\titters\n10\t32\t5\n")
    with pytest.raises(ValueError, match=r"bad.tsv: unknown knob column 'itters'; valid knobs: iters"):
        knobs.read_table(bad)
    bad.write_text("iters\tres\n10\t32\n10\t32\n")
    with pytest.raises(ValueError, match=r"rows \[2\] repeat"):
        knobs.read_table(bad)
    bad.write_text("iters\tdetection\n10\t1.5\n")
    with pytest.raises(ValueError, match=r"row 1: knob detection=1.5 must lie strictly between 0 and 1"):
        knobs.read_table(bad)
    with pytest.raises(ValueError, match=r"where: knob iters=2.5 must be a positive integer"):
        knobs.check_setting({"iters": 2.5}, "where")
    sources = names.PLAIN_SOURCES + names.STAGE1_METHODS
    with pytest.raises(
        ValueError, match=r"tradeoff.combinations: 'sketch\+3dgs': unknown source 'sketch'; valid: gt, none"
    ):
        knobs.parse_combinations(["sketch+3dgs"], "nerf-grid", sources, "tradeoff.combinations")
    with pytest.raises(
        ValueError, match=r"photon_level.combinations: combination 'gt\+mesh': unknown model 'mesh'; valid: 3dgs"
    ):
        knobs.parse_combinations(["gt+mesh"], "nerf-grid", sources, "photon_level.combinations")
    assert knobs.parse_combinations(["gt+nerf", "gt+nerf-grid"], "nerf-grid", sources, "k") == ["gt+nerf-grid"]
    with pytest.raises(ValueError, match=r"photon_level.budget: knob 'K' is swept by photon_level.frames"):
        plan.photon_budget({"iters": 10, "K": 4})
    with pytest.raises(ValueError, match=r"tradeoff.scene: unknown scene 'mars'"):
        plan.sweep_scenes("mars", None, ["courtyard"], ["tabletop"], ["courtyard", "tabletop"])


# ---- a point's settings overlay -----------------------------------------------------------------------
def test_overlay_names_the_sweep_and_its_setting():
    value = plan.overlay("tradeoff", "iters~300/res~64/detection~0.05")
    assert value == "sweeps/tradeoff/iters~300/res~64/detection~0.05/"
    assert plan.parse_overlay(value) == ("tradeoff", {"iters": 300, "res": 64, "detection": 0.05})
    assert plan.parse_overlay("") == ("", {})
    assert re.fullmatch(plan.OVERLAY_PATTERN, "") and re.fullmatch(plan.OVERLAY_PATTERN, value)
    for bad in ("sweeps/grid/iters~3/", "sweeps/tradeoff/", "sweeps/tradeoff/speed~3/", "scenes/"):
        assert not re.fullmatch(plan.OVERLAY_PATTERN, bad)
        with pytest.raises(ValueError, match="is not a sweep overlay"):
            plan.parse_overlay(bad)
    with pytest.raises(ValueError, match="knob res='0' must be a positive integer"):
        plan.parse_overlay("sweeps/tradeoff/res~0/")
    for pattern in Paramspace(knobs.read_table(TABLE)).instance_patterns:  # every table row is an overlay
        assert re.fullmatch(plan.OVERLAY_PATTERN, plan.overlay("tradeoff", pattern))


def test_knobs_reach_every_rule():
    points = point_settings()
    value = plan.overlay("tradeoff", "iters~6/res~64/K~2/width~12/steps~3/cap~100/detection~0.1")
    assert points.scene(value, "courtyard")["width"] == 64 and points.scene(value, "tabletop")["height"] == 48
    spc = points.spc(value)
    assert spc["physics"]["frames"] == 2 and spc["target_detection"] == 0.1 and spc["flux_scale"] is None
    assert spc["capture_factor"] == 1  # a point simulates no finer capture frame
    assert points.frames(value, "pix2pix") == 2 and points.frames(value, "gt") is None
    assert points.frames(value, "none") == 1  # a point's augment count: tests/test_settings.py
    settings, train = points.translator(value, "pix2pix", {"ngf": 8, "num_downs": 3}, {"iterations": 50, "crop": 256})
    assert settings["ngf"] == 12 and train["iterations"] == 3 and train["crop"] == 48  # the 48-px-high images
    with pytest.raises(ValueError, match="64-pixel crops"):  # 6 halvings: no 64-px crop fits a 64x48 image
        points.translator(value, "pix2pix", {"num_downs": 6}, {})
    s = points.stage2(value, "3dgs", TINY_3DGS)
    assert s["iterations"] == 6 and s["densify_until"] == 5 and s["densify_every"] == 2  # schedules scale 6/12
    assert s["max_gaussians"] == 100 and s["init_points"] == 300  # below the cap: spc3d.checks.crosscheck refuses it
    grid = points.stage2(
        plan.overlay("tradeoff", "iters~100/grid~48"),
        "nerf-grid",
        {"n_iters": 200, "res_schedule": [[0, 32], [70, 64], [140, 96]]},
    )
    assert grid["res_schedule"] == [[0, 16], [35, 32], [70, 48]] and grid["n_iters"] == 100
    photon = point_settings({"iters": 10, "res": 48})
    value = plan.overlay("photon_level", "detection~0.02/K~16")
    assert photon.setting(value) == {"iters": 10, "res": 48, "detection": 0.02, "K": 16}
    assert photon.frames(value, "mle") == 16 and point_settings().frames(plan.overlay("tradeoff", "res~48"), "mle") == 1
    with pytest.raises(ValueError, match="res=12: images are too small"):
        points.translator(plan.overlay("tradeoff", "res~12"), "pix2pix", {}, {})


def test_a_point_lists_what_its_jobs_make():
    value = plan.overlay("tradeoff", "iters~10")
    root = f"results/{value}"
    outputs = lambda combo: plan.point_outputs(combo, value, "courtyard", ["tabletop"], 4)  # noqa: E731
    assert outputs("gt+3dgs") == [
        f"{root}scenes/courtyard",
        f"{root}recon/courtyard/gt+3dgs",
        f"{root}eval/courtyard/gt+3dgs/metrics.json",
    ]
    made = [path.removeprefix(root) for path in outputs("pix2pix+3dgs")]
    assert made == [
        "scenes/courtyard",
        "scenes/tabletop",
        "spc/courtyard",
        "spc/tabletop",
        "augment/tabletop",
        "models/pix2pix",
        "translate/courtyard/pix2pix",
        "stage1/courtyard/pix2pix.json",
        "recon/courtyard/pix2pix+3dgs",
        "eval/courtyard/pix2pix+3dgs/metrics.json",
    ]
    assert outputs("mle+3dgs")[4:6] == [f"{root}calibration/display-k4.json", f"{root}mle/courtyard/k4"]
    assert not any("stage1/" in path for path in outputs("bernoulli+3dgs"))
    assert f"{root}models/pix2pixhd" in outputs("joint-pix2pixhd+3dgs")  # the prior term's translator
    with pytest.raises(ValueError, match="needs training scenes"):
        plan.point_outputs("mle+3dgs", value, "courtyard", [], 1)


def test_rule_side_modules_import_without_torch():
    code = (
        "import sys; import spc3d.sweeps.knobs, spc3d.sweeps.plan, spc3d.sweeps.pareto, spc3d.sweeps.report; "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---- a tiny sweep through Snakemake, end to end ----------------------------------------------------------
TRADEOFF_ROW = "iters~10/res~48/K~1/width~8/steps~2/cap~500"
PHOTON_ROWS = ("detection~0.2/K~2", "detection~0.6/K~2")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, lpips_cache):
    """`snakemake tradeoff photon_level` on the smoke preset: gt+3dgs and pix2pix+3dgs at one
    budget, mle+3dgs at two exposures (K = 2). Run once per test session: the xdist worker that
    asks first builds it, another waits for it (the tests only read it)."""
    root = session_folder(tmp_path_factory, "sweep")
    with exclusive(root / "build.lock"):
        if not (root / "built.json").exists():
            (root / "t.tsv").write_text("iters\tres\tK\twidth\tsteps\tcap\n10\t48\t1\t8\t2\t500\n")
            config = {
                "metrics": {"lpips_source": str(lpips_cache)},
                "tradeoff": {"combinations": ["gt+3dgs", "pix2pix+3dgs"], "table": str(root / "t.tsv")},
                "photon_level": {
                    "combinations": ["mle+3dgs"],
                    "detection": [0.2, 0.6],
                    "frames": [2],
                    "budget": {"iters": 10, "res": 48, "cap": 500},  # smoke's init_points
                },
            }
            (root / "sweep.yaml").write_text(yaml.safe_dump(config))
            args = ("--cores", "2", "tradeoff", "photon_level", "--configfile", str(SMOKE), str(root / "sweep.yaml"))
            proc = run_snakemake(root, *args)
            (root / "built.json").write_text(json.dumps({"rc": proc.returncode, "err": proc.stderr[-4000:]}))
    built = json.loads((root / "built.json").read_text())
    assert built["rc"] == 0, built["err"]
    return root


def test_a_sweep_runs_the_grid_rules_under_its_overlay(sweep):
    point = sweep / "results" / "sweeps" / "tradeoff" / TRADEOFF_ROW
    for combo in ("gt+3dgs", "pix2pix+3dgs"):
        rec = io.read_json(point / "eval" / "courtyard" / combo / "metrics.json")
        assert rec["combination"] == combo and rec["iterations"] == 10 and rec["capacity"]["gaussians"] > 0
        assert rec["settings"]["max_gaussians"] == 500 and len(rec["per_view"]) == 2
    assert io.read_rgb(next((point / "scenes" / "courtyard" / "images").glob("*.png"))).shape[1] == 48
    model = io.read_json(point / "models" / "pix2pix" / "train.json")
    assert model["settings"]["ngf"] == 8 and model["iterations"] == 2 and model["validation"] is None
    assert io.read_json(point / "spc" / "courtyard" / "spc.json")["params"]["frames"] == 1
    assert not (sweep / "results" / "eval").exists()  # nothing of the grid ran
    for value in PHOTON_ROWS:
        photon = sweep / "results" / "sweeps" / "photon_level" / value
        spc = io.read_json(photon / "spc" / "courtyard" / "spc.json")
        assert spc["params"]["frames"] == 2 and (photon / "mle" / "courtyard" / "k2").is_dir()
        assert io.read_json(photon / "eval" / "courtyard" / "mle+3dgs" / "metrics.json")["frames"] == 2
        assert io.read_json(photon / "stage1" / "courtyard" / "mle.json")["mean"]["psnr"] > 0
    benchmarks = list((sweep / "benchmarks").rglob("*.tsv"))
    jobs = {b.relative_to(sweep / "benchmarks").parts[1] for b in benchmarks}  # every job under its overlay
    assert jobs == {"sweeps", "lpips_weights.tsv", "tradeoff_report.tsv", "photon_level_report.tsv"}


def test_reports_sum_the_benchmarks_of_each_points_jobs(sweep):
    table = pd.read_csv(sweep / "results" / "tables" / "tradeoff.csv")
    assert list(table["combination"]) == ["gt+3dgs", "pix2pix+3dgs"] and table["pareto"].all()
    for column in ("iters", "res", "cap", "wall_time_s", "peak_memory_mb", "psnr", "ssim", "lpips_alex", "cpu_time_s"):
        assert table[column].notna().all(), column
    point = f"sweeps/tradeoff/{TRADEOFF_ROW}"
    gt = [f"prepare_scene/{point}/courtyard", f"reconstruct/{point}/courtyard/gt+3dgs"]
    gt.append(f"evaluate/{point}/courtyard/gt+3dgs")
    rows = [pd.read_csv(sweep / "benchmarks" / f"{job}.tsv", sep="\t") for job in gt]
    assert all(list(r.columns) == list(BENCHMARK_COLUMNS) for r in rows)
    row = table.iloc[0]
    assert row["wall_time_s"] == pytest.approx(sum(r["s"].iloc[0] for r in rows), rel=1e-3)
    assert row["cpu_time_s"] == pytest.approx(sum(r["user_s"].iloc[0] + r["sys_s"].iloc[0] for r in rows), rel=1e-3)
    assert row["peak_memory_mb"] == pytest.approx(max(r["max_rss_mb"].iloc[0] for r in rows), rel=1e-3)
    scores = io.read_json(sweep / "results" / point / "eval" / "courtyard" / "gt+3dgs" / "metrics.json")["mean"]
    assert row["psnr"] == pytest.approx(scores["psnr"], rel=1e-3)
    p2p = table.iloc[1]  # its own ten jobs: the scenes, SPC, pairs, translator, translation, scores before 3D
    assert p2p["wall_time_s"] > row["wall_time_s"] and np.isfinite(p2p["stage1_psnr"]) and p2p["label"] != ""
    photon = pd.read_csv(sweep / "results" / "tables" / "photon_level.csv")
    assert photon[["K", "detection"]].values.tolist() == [[2, 0.2], [2, 0.6]]
    assert photon["stage1_psnr"].notna().all() and photon["measured_detection"].between(0, 1).all()
    for png in ("tradeoff.png", "photon_level.png"):
        assert (sweep / "results" / "figures" / png).stat().st_size > 10_000


# ---- the rules ---------------------------------------------------------------------------------------
def test_dry_run_of_both_sweeps(tmp_path):
    from test_workflow import snakemake

    table = tmp_path / "t.tsv"  # rows 1 and 2 differ only in width: one point for gt, two for pix2pix
    table.write_text("iters\tres\twidth\n100\t64\t8\n100\t64\t16\n200\t64\t8\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "tradeoff": {"combinations": ["gt+3dgs", "pix2pix+nerf"], "table": str(table)},
                "stage1": {"pix2pix": {"num_downs": 3}},  # 8-px multiples: crops fit the 64x48 images
                "photon_level": {"detection": [0.1, 0.9], "frames": [1, 4]},
            }
        )
    )
    proc = snakemake(
        tmp_path, "-n", "tradeoff", "photon_level", "--configfile", str(REPO / "config.yaml"), str(cfg), timeout=120
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "results/sweeps/tradeoff/iters~100/res~64/width~16/eval/courtyard/pix2pix+nerf-grid/metrics.json" in out
    assert "results/sweeps/tradeoff/iters~100/res~64/width~16/eval/courtyard/gt+3dgs/metrics.json" not in out
    counts = {m[0]: int(m[1]) for m in re.findall(r"^(\w+)\s+(\d+)$", out, re.M)}
    # 5 trade-off points + 8 photon-level points (mle+3dgs, bernoulli+3dgs at 4 settings), one stage 2 each;
    # a setting's scenes are shared by its combinations: 3 trade-off + 4 photon-level settings x 4 scenes
    assert counts["reconstruct"] == 13 and counts["evaluate"] == 13 and counts["tradeoff"] == 1
    assert counts["prepare_scene"] == 7 * 4 and counts["train_translator"] == 3 and counts["calibrate_display"] == 4
    assert "tradeoff_point" not in counts and "photon_level_point" not in counts
    point = "results/sweeps/photon_level/detection~0.1/K~4/eval/courtyard/bernoulli+3dgs/metrics.json"
    one = snakemake(tmp_path, "-n", point, "--configfile", str(REPO / "config.yaml"), str(cfg), timeout=120)
    counts = {m[0]: int(m[1]) for m in re.findall(r"^(\w+)\s+(\d+)$", one.stdout + one.stderr, re.M)}
    # a point as a file target: 4 scenes and their SPC data, the display, stage 2, scores, LPIPS weights
    assert one.returncode == 0 and counts["total"] == 13, one.stdout[-3000:]
    cfg.write_text(yaml.safe_dump({"tradeoff": {"combinations": ["sketch+3dgs"]}}))
    bad = snakemake(tmp_path, "-n", "tradeoff", "--configfile", str(REPO / "config.yaml"), str(cfg), timeout=120)
    assert bad.returncode != 0 and "tradeoff.combinations: 'sketch+3dgs': unknown source" in bad.stdout + bad.stderr

"""Budget sweeps: Pareto fronts, knobs and tables, a point's mini pipeline end to end, reports, the rules."""

import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import yaml
from snakemake.utils import Paramspace

from spc3d import io, names
from spc3d.sweeps import knobs, plan
from spc3d.sweeps.budget import WIDTH_KEYS, resolve_point
from spc3d.sweeps.pareto import front_steps, pareto_mask
from spc3d.sweeps.report import photon_level_report, tradeoff_report

from conftest import REPO

TABLE = REPO / "workflow" / "tradeoff.tsv"
SPEC = {"kind": "builtin", "height": 36, "width": 48, "views": 9, "supersample": 1, "seed": 0}
SPC = {
    "mode": "bernoulli",
    "q": 0.45,
    "tau_d": 1.5e-7,
    "exposure_s": 1e-4,
    "dark_count_rate": 100.0,
    "frames": 4,
    "flux_scale": None,
    "target_detection": 0.5,
}
TINY_3DGS = {"iterations": 12, "densify_from": 4, "densify_until": 10, "densify_every": 4, "init_points": 300}
TINY_PIX2PIX = {
    "settings": {"ngf": 8, "ndf": 8, "num_downs": 3, "n_layers_D": 2},
    "train": {"iterations": 2, "batch_size": 2, "crop": 16, "log_every": 1},
    "frames": 1,
}


def base(translator=None, model_settings=TINY_3DGS):
    return {
        "seed": 0,
        "scene_name": "courtyard",
        "scene": SPEC | {"layout": "courtyard"},
        "train_scenes": {"tabletop": SPEC | {"layout": "tabletop"}},
        "spc": SPC,
        "augment": {"count": 4, "zoom": [0.8, 1.25], "rotation_deg": 15.0, "shear_deg": 10.0, "flip_prob": 0.5},
        "translator": translator,
        "stage2": {"settings": model_settings, "frames": 1},
    }


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
    from spc3d.translate import TRANSLATORS

    assert tuple(RECONSTRUCTORS) == names.STAGE2_MODELS
    assert set(WIDTH_KEYS) == {m for m, module in TRANSLATORS.items() if module.Translator.trainable}
    for method, key in WIDTH_KEYS.items():
        assert hasattr(TRANSLATORS[method].Config(), key)


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
    with pytest.raises(ValueError, match=r"tradeoff.combinations: 'sketch\+3dgs' has unknown source 'sketch'"):
        knobs.parse_combinations(["sketch+3dgs"], "nerf-grid", sources, "tradeoff.combinations")
    with pytest.raises(ValueError, match=r"photon_level.combinations: combination 'gt\+mesh' must be"):
        knobs.parse_combinations(["gt+mesh"], "nerf-grid", sources, "photon_level.combinations")
    assert knobs.parse_combinations(["gt+nerf", "gt+nerf-grid"], "nerf-grid", sources, "k") == ["gt+nerf-grid"]
    with pytest.raises(ValueError, match=r"photon_level.budget: knob 'K' is swept by photon_level.frames"):
        plan.photon_budget({"iters": 10, "K": 4})
    with pytest.raises(ValueError, match=r"tradeoff.scene: unknown scene 'mars'"):
        plan.sweep_scenes("mars", None, ["courtyard"], ["tabletop"], ["courtyard", "tabletop"])


# ---- a point's settings ------------------------------------------------------------------------------
def test_knobs_reach_every_stage():
    p = resolve_point(
        base(TINY_PIX2PIX), {"iters": 6, "res": 64, "K": 2, "width": 12, "steps": 3, "cap": 100}, "pix2pix+3dgs"
    )
    assert p["scene"]["width"] == 64 and p["scene"]["height"] == 48  # 4:3 kept
    assert p["train_scenes"]["tabletop"]["height"] == 48 and p["spc"]["physics"]["frames"] == 2 and p["frames"] == 2
    assert p["translator"]["settings"]["ngf"] == 12 and p["translator"]["train"]["iterations"] == 3
    assert p["translator"]["train"]["crop"] == 16
    s = p["stage2"]
    assert s["iterations"] == 6 and s["densify_until"] == 5 and s["densify_every"] == 2  # schedules scale 6/12
    assert s["max_gaussians"] == 100 and s["init_points"] == 100
    grid = resolve_point(
        base(model_settings={"n_iters": 200, "res_schedule": [[0, 32], [70, 64], [140, 96]]}),
        {"iters": 100, "grid": 48, "detection": 0.1},
        "mle+nerf-grid",
    )
    assert grid["stage2"]["res_schedule"] == [[0, 16], [35, 32], [70, 48]] and grid["stage2"]["n_iters"] == 100
    assert grid["spc"]["target_detection"] == 0.1 and grid["spc"]["flux_scale"] is None and grid["frames"] == 1
    assert list(grid["train_scenes"]) == ["tabletop"] and grid["augment"]["counts"] == {}  # display level only
    with pytest.raises(ValueError, match="no translator settings"):
        resolve_point(base(), {}, "pix2pix+3dgs")
    with pytest.raises(ValueError, match="res=12: images are too small"):
        resolve_point(base(TINY_PIX2PIX), {"res": 12}, "pix2pix+3dgs")


# ---- the mini pipeline end to end --------------------------------------------------------------------
@pytest.fixture(scope="module")
def points(tmp_path_factory, lpips_cache, one_torch_thread):
    from spc3d.sweeps.point import run_point

    root = tmp_path_factory.mktemp("sweeps")
    runs = {
        "gt+3dgs": (base(), {"iters": 10, "res": 48, "cap": 400}),
        "pix2pix+3dgs": (base(TINY_PIX2PIX), {"iters": 10, "res": 48, "K": 1, "width": 8, "steps": 2, "cap": 400}),
    }
    for combo, (b, setting) in runs.items():
        run_point(root / combo, combo, setting, b, lpips_dir=lpips_cache)
    return root


def test_point_writes_metrics_with_every_field(points):
    for combo in ("gt+3dgs", "pix2pix+3dgs"):
        rec = io.read_json(points / combo / "metrics.json")
        assert rec["combination"] == combo and rec["seed"] == 0 and rec["scene"] == "courtyard"
        assert set(rec["mean"]) == {"psnr", "ssim", "lpips_alex", "lpips_vgg"} and len(rec["per_view"]) == 2
        assert set(rec["times_s"]) == {
            "prepare",
            "simulate",
            "augment",
            "train",
            "translate",
            "reconstruct",
            "evaluate",
        }
        assert rec["wall_s"] + 0.01 >= sum(rec["times_s"].values()) > 0 and rec["cpu_s"] > 0 and rec["peak_rss_mb"] > 50
        assert rec["iterations"] == 10 and rec["capacity"]["gaussians"] > 0
        assert rec["resolved"]["scene"]["width"] == 48 and rec["resolved"]["stage2"]["iterations"] == 10
        assert (points / combo / "recon" / "renders" / "image000.png").exists()
        assert not (points / combo / "work").exists()  # intermediate data removed
    gt = io.read_json(points / "gt+3dgs" / "metrics.json")
    assert gt["stage1"] is None and gt["times_s"]["train"] == 0 and gt["used_knobs"] == ["iters", "res", "cap"]
    assert gt["resolved"]["stage2"]["max_gaussians"] == 400
    p2p = io.read_json(points / "pix2pix+3dgs" / "metrics.json")
    assert p2p["times_s"]["train"] > 0 and p2p["times_s"]["augment"] > 0 and np.isfinite(p2p["stage1"]["psnr"])
    assert p2p["translator"]["settings"]["ngf"] == 8 and p2p["translator"]["train"]["iterations"] == 2
    assert p2p["spc_record"]["params"]["frames"] == 1


def test_reports_write_tables_and_figures(points, tmp_path):
    paths = [points / "gt+3dgs" / "metrics.json", points / "pix2pix+3dgs" / "metrics.json"]
    table = tradeoff_report(paths, ["pix2pix+3dgs", "gt+3dgs"], tmp_path / "t.csv", tmp_path / "t.png")
    csv = pd.read_csv(tmp_path / "t.csv")
    assert list(csv["combination"]) == ["pix2pix+3dgs", "gt+3dgs"] and csv["pareto"].all()
    assert csv["setting"].tolist() == [2, 1]  # settings numbered in input order, shown in the figure's legend
    for column in ("iters", "res", "cap", "wall_time_s", "peak_memory_mb", "psnr", "ssim", "lpips_alex", "lpips_vgg"):
        assert csv[column].notna().all(), column
    assert table.loc[0, "label"] == "10it 48px K1 w8 2st cap400"
    assert (tmp_path / "t.png").stat().st_size > 10_000
    photon = []  # the same point at several exposures and K (the report only reads the records)
    rec = io.read_json(paths[0])
    for i, (d, k) in enumerate([(0.1, 1), (0.5, 1), (0.1, 4), (0.5, 4)]):
        rec.update(
            combination="mle+3dgs",
            setting={"detection": d, "K": k},
            used_knobs=["detection", "K"],
            stage1={"psnr": 10.0 + i},
            mean=rec["mean"] | {"psnr": 12.0 + i},
        )
        io.write_json(tmp_path / f"p{i}.json", rec)
        photon.append(tmp_path / f"p{i}.json")
    out = photon_level_report(photon, ["mle+3dgs"], tmp_path / "p.csv", tmp_path / "p.png")
    assert out[["K", "detection"]].values.tolist() == [[1, 0.1], [1, 0.5], [4, 0.1], [4, 0.5]]
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_rule_side_modules_import_without_torch():
    code = (
        "import sys; import spc3d.sweeps.knobs, spc3d.sweeps.plan, spc3d.sweeps.pareto, spc3d.sweeps.report; "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---- the rules ---------------------------------------------------------------------------------------
def test_dry_run_of_both_sweeps(tmp_path):
    if "tradeoff.smk" not in (REPO / "Snakefile").read_text():
        pytest.skip("the Snakefile does not include workflow/rules/tradeoff.smk yet")
    from test_workflow import snakemake

    table = tmp_path / "t.tsv"  # rows 1 and 2 differ only in width: one point for gt, two for pix2pix
    table.write_text("iters\tres\twidth\n100\t64\t8\n100\t64\t16\n200\t64\t8\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "tradeoff": {"combinations": ["gt+3dgs", "pix2pix+nerf"], "table": str(table)},
                "photon_level": {"detection": [0.1, 0.9], "frames": [1, 4]},
            }
        )
    )
    proc = snakemake(
        tmp_path, "-n", "tradeoff", "photon_level", "--configfile", str(REPO / "config.yaml"), str(cfg), timeout=120
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "results/tradeoff/pix2pix+nerf-grid/iters~100/res~64/width~16/metrics.json" in out
    assert "results/tradeoff/gt+3dgs/iters~100/res~64/width~16/metrics.json" not in out
    counts = {m[0]: int(m[1]) for m in re.findall(r"^(\w+)\s+(\d+)$", out, re.M)}
    assert counts["tradeoff_point"] == 5 and counts["photon_level_point"] == 8 and counts["tradeoff"] == 1
    cfg.write_text(yaml.safe_dump({"tradeoff": {"combinations": ["sketch+3dgs"]}}))
    bad = snakemake(tmp_path, "-n", "tradeoff", "--configfile", str(REPO / "config.yaml"), str(cfg), timeout=120)
    assert bad.returncode != 0 and "tradeoff.combinations: 'sketch+3dgs' has unknown source" in bad.stdout + bad.stderr

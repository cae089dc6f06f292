"""Every script in benchmarks/ runs, at a tiny size, in seconds: a renamed setting, a changed
library signature or a moved config key (``KeyError: 'seeds'`` in paper_budget.py) fails here
instead of at the next measurement.

Each script runs as its user runs it (``python benchmarks/X.py``), in a subprocess: the
standalone ones with ``--smoke`` (their own tiny sizes), the ones that read a finished run on a
results folder built here at a tiny size (a training scene with its photons and augmented pairs,
an evaluation scene, hand-made score records, a fit's record with its job). Those that need a
whole workflow run of their own (Snakemake trainings, clones) are in :data:`NEEDS_A_RUN`, with the
test of their functions on hand-made records.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spc3d import io

from conftest import REPO

BENCHMARKS = REPO / "benchmarks"

# The scripts that need a workflow run of their own (Snakemake trainings or fresh clones, minutes
# at the smallest): their functions are tested on hand-made records in the named test file.
NEEDS_A_RUN = {
    "default_run.py": "tests/test_default_run_benchmark.py",
    "learning_curves.py": "tests/test_learning_curves_benchmark.py",
    "scene_holdout_curves.py": "tests/test_scene_holdout_benchmark.py",
    "stage1_data.py": "tests/test_benchmarks_smoke.py::test_stage1_data_rows_from_records",
    "joint_weight.py": "tests/test_benchmarks_smoke.py::test_joint_weight_table_and_sample_kind_from_records",
}


@pytest.fixture(scope="module")
def run(tmp_path_factory, lpips_cache) -> Path:
    """A finished run's folder at a tiny size: results/ with a training scene (tabletop: scene,
    photons, four augmented pairs), an evaluation scene (courtyard: scene, photons), hand-made
    metrics of two rows on two scenes, a translator's record with its validation curve, and a
    fit's record with the job that made it."""
    from spc3d.inputs.augment import AugmentSettings, augment_scene
    from spc3d.inputs.build import simulate_scene
    from spc3d.inputs.scenes import write_builtin_scene
    from spc3d.physics import spc

    root = tmp_path_factory.mktemp("bench_run")
    res = root / "results"
    for name in ("tabletop", "courtyard"):
        write_builtin_scene(name, res / "scenes" / name, height=36, width=48, views=9, supersample=1)
        simulate_scene(res / "scenes" / name, res / "spc" / name, spc.SPCParams(frames=2), seed=0)
    tabletop = (res / kind / "tabletop" for kind in ("scenes", "spc", "augment"))
    augment_scene(*tabletop, 4, AugmentSettings())
    (res / "cache").mkdir()
    (res / "cache" / "lpips").symlink_to(lpips_cache)
    rng = np.random.default_rng(0)
    for scene in ("courtyard", "observatory"):
        for combo in ("gt+3dgs", "bernoulli+3dgs"):
            for seed in (0, 1):
                folder = combo if seed == 0 else f"{combo}-seed{seed}"
                psnr = float(20 + rng.normal())
                io.write_json(
                    res / "eval" / scene / folder / "metrics.json",
                    {
                        "scene": scene,
                        "combination": combo,
                        "seed": seed,
                        "frames": 1,
                        "init": {"setting": "random", "used": "random"},
                        "per_view": [{"view": "image000", "psnr": psnr}],
                        "mean": {"psnr": psnr, "ssim": 0.5, "lpips_alex": 0.4, "lpips_vgg": 0.4},
                    },
                )
    for name, best_at in (("pix2pix", 2), ("pix2pix-seed1", 3)):
        curve = [{"iteration": 25 * i, "val_psnr": 18.0 + i - max(0, i - best_at) * 1.5} for i in range(6)]
        io.write_json(
            res / "models" / name / "train.json",
            {"validation": {"curve": curve, "patience": 0}, "stopped": {"of": 125, "step": 125}},
        )
    job = {
        "scene_dir": "results/scenes/courtyard",
        "source": "gt",
        "model": "3dgs",
        "settings": {"iterations": 6, "densify_until": 0, "init_points": 200, "plateau_window": 2, "backend": "native"},
        "frames": None,
    }
    io.write_json(res / "recon" / "courtyard" / "gt+3dgs" / "train.json", {"job": job})
    return root


def smoke_args(script: str, run: Path, tmp: Path) -> list[str]:
    """The arguments of a script's smoke run."""
    res = run / "results"
    return {
        "classical_denoisers.py": ["--results", res, "--scenes", "tabletop", "--families", "gaussian"],
        "stage1_prior.py": [res, "--train", "tabletop", "--sigmas", "2"],
        "poses_sources.py": [res, "--scene", "courtyard"],
        "stopping_trade.py": [run, "--rows", "gt+3dgs", "--seeds", "0", "--jobs", "1", "--out", tmp / "trade"],
        "scene_gap.py": [res, "--scene", "courtyard", "--out", tmp / "gap.md"],
        "machine_spread.py": [res, res, "--seeds", res],
        "translator_patience.py": [res / "models", "--patience", "1", "2"],
        "nerf_grid_quality.py": ["--smoke", "--cache", tmp / "scenes"],
        "plateau_rule.py": ["--smoke", "--cache", tmp / "scenes"],
        "record.py": [tmp / "bench", "--", "spc_simulator.py", "--smoke"],
    }.get(script, ["--smoke"])


SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if p.name not in NEEDS_A_RUN)


def test_every_benchmark_is_run_here_or_named_with_its_test():
    """A new script joins :data:`SCRIPTS` (and runs here) unless it is listed as needing a run."""
    assert set(SCRIPTS) | set(NEEDS_A_RUN) == {p.name for p in BENCHMARKS.glob("*.py")}
    for test in NEEDS_A_RUN.values():
        assert (REPO / test.split("::")[0]).is_file()


@pytest.mark.parametrize("script", SCRIPTS)
def test_benchmark_runs_at_a_tiny_size(script, run, tmp_path):
    args = [str(a) for a in smoke_args(script, run, tmp_path)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "workflow"), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, str(BENCHMARKS / script), *args]
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{script} {' '.join(args)}:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    assert done.stdout.strip(), f"{script} printed nothing"


def test_stage1_data_rows_from_records(tmp_path):
    sys.path.insert(0, str(BENCHMARKS))
    from stage1_data import row

    work = tmp_path / "fixed"
    curve = [{"iteration": 0, "val_psnr": 15.0}, {"iteration": 25, "val_psnr": 17.5}]
    validation = {"curve": curve, "best_psnr": 17.5, "best_step": 25}
    io.write_json(
        work / "results" / "models" / "pix2pix" / "train.json",
        {"validation": validation, "data": {"distinct_samples": 8}},
    )
    io.write_json(work / "results" / "stage1" / "courtyard" / "pix2pix.json", {"mean": {"psnr": 16.234, "ssim": 0.51}})
    bench = work / "benchmarks" / "train_translator" / "pix2pix.tsv"
    bench.parent.mkdir(parents=True)
    bench.write_text("s\tuser_s\tsys_s\tmax_rss_mb\tstatus\n10.0\t7.5\t0.5\t300\tok\n")
    assert row(work, "fixed", "pix2pix") == {
        "mode": "fixed",
        "method": "pix2pix",
        "eval_psnr": 16.23,
        "eval_ssim": 0.51,
        "val_best": 17.5,
        "best_step": 25,
        "val_last": 17.5,
        "distinct_samples": 8,
        "cpu_s": 8.0,
    }


def test_joint_weight_table_and_sample_kind_from_records(tmp_path):
    sys.path.insert(0, str(BENCHMARKS))
    from joint_weight import sample_kind, table

    runs = [
        {"schedule": name, "scene": scene, "seed": 0, "psnr": psnr + (scene == "orchard"), "cpu_s": 10.0}
        for name, psnr in (("likelihood", 20.0), ("prior only", 19.0), ("w=0.1", 21.0))
        for scene in ("tabletop", "orchard")
    ]
    runs = [r | {"method": "prior"} for r in runs]
    lines = table(runs, "3dgs").splitlines()
    assert lines[0].startswith("joint-prior+3dgs: held-out PSNR (dB) on the training scenes, n = 2")
    row = lines[-1].split()
    assert row[0] == "w=0.1" and row[3:6] == ["21.50", "+1.00", "+2.00"]  # mean, Δ likelihood, Δ prior only
    io.write_json(
        tmp_path / "models" / "restormer" / "train.json",
        {"validation": {"hold_out": 1, "views": ["orchard/image000", "orchard/image001"]}},
    )
    assert sample_kind(tmp_path, "restormer", "orchard") == "out of sample"
    assert sample_kind(tmp_path, "restormer", "tabletop") == "in-sample"
    assert sample_kind(tmp_path, "prior", "tabletop") == "no network"


def test_record_keeps_a_scripts_output_verbatim_and_nothing_when_it_fails(tmp_path):
    """benchmarks/record.py writes the printed table with its command under OUT/tables, and a
    failing script leaves no file behind (docs must not quote a half-written measurement)."""
    env = os.environ | {"PYTHONPATH": str(REPO / "workflow")}
    record = [sys.executable, str(BENCHMARKS / "record.py"), str(tmp_path)]
    ok = subprocess.run(
        [*record, "--name", "sim", "--", "spc_simulator.py", "--smoke"], env=env, capture_output=True, text=True
    )
    assert ok.returncode == 0, ok.stderr
    direct = subprocess.run(
        [sys.executable, str(BENCHMARKS / "spc_simulator.py"), "--smoke"],
        env=env,
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    text = (tmp_path / "tables" / "sim.md").read_text()
    assert text.startswith("# sim\n") and "`python benchmarks/spc_simulator.py --smoke` at commit" in text
    fenced = text.split("```text\n", 1)[1].rsplit("\n```", 1)[0].splitlines()
    # same lines as a direct run, timings aside: the header rows match exactly
    assert fenced[0] == direct.stdout.splitlines()[0] and len(fenced) == len(direct.stdout.splitlines())
    bad = subprocess.run(
        [*record, "--", "spc_simulator.py", "--no-such-option"], env=env, capture_output=True, text=True
    )
    assert bad.returncode != 0 and "nothing recorded" in bad.stderr
    assert not (tmp_path / "tables" / "spc_simulator.md").exists()
    assert not list((tmp_path / "tables").glob(".*"))  # no temporary file left

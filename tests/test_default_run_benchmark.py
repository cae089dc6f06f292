"""benchmarks/default_run.py's parsing and accounting, on synthetic files (no clone, no Snakemake)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from conftest import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "default_run.py"


@pytest.fixture(scope="module")
def drun():
    return load_script(SCRIPT)


# Captured from benchmarks/rasterizer.py --sizes 10000 --repeats 3 (a loaded 2-core machine).
RASTERIZER_OUTPUT = """\
numba first call: 21.4 s with an empty cache, 0.93 s from the cache (torch threads 2)
gaussians    size   native  native raster  reference  speedup   (iterations/s; speedup = native / reference)
    10000  64x64      21.3           15.2       1.52    14.0x
    10000 128x96      16.7           12.1       0.91    18.4x
speedup_10k_128x96: 18.4
"""

# The end of `snakemake -n --cores 2 --quiet rules` (default config of 28a55a7, shortened).
DRY_RUN_OUTPUT = """\

Job stats:
job                   count
------------------  -------
lpips_weights             1
reconstruct              18
evaluate                 18
all                       1
total                    38

Reasons:
    (check individual jobs above for details)
"""


def write_tsv(path: Path, header: str, *rows: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join((header, *rows)) + "\n")


def test_rasterizer_reference_is_the_native_rate_at_10k_128x96(drun):
    assert drun.parse_rasterizer(RASTERIZER_OUTPUT) == 16.7
    assert drun.parse_rasterizer(RASTERIZER_OUTPUT, size="64x64") == 21.3
    assert drun.parse_rasterizer("speedup_10k_128x96: n/a\n") is None


def test_job_stats_of_the_dry_run(drun):
    assert drun.parse_job_stats(DRY_RUN_OUTPUT) == {"lpips_weights": 1, "reconstruct": 18, "evaluate": 18, "all": 1}
    assert drun.parse_job_stats("Nothing to be done.\n") == {}


def test_job_cpu_sums_each_rules_tsvs_at_any_depth(drun, tmp_path):
    """spc3d's own TSVs (user_s + sys_s) and Snakemake's (cpu_time), nested under overlays; the rule is
    the first folder; top-level files, hidden files and unreadable values are left out."""
    bench = tmp_path / "benchmarks"
    own = "s\tuser_s\tsys_s\tmax_rss_mb\tstatus"
    write_tsv(bench / "reconstruct/courtyard/gt+3dgs.tsv", own, "60.0\t50.5\t1.5\t900.0\tok")
    write_tsv(bench / "reconstruct/sweeps/tradeoff/iters~100/courtyard/gt+3dgs.tsv", own, "9\t8.0\t1.0\t500\tok")
    write_tsv(bench / "evaluate/courtyard.tsv", own, "3\tNA\t0.5\t100\tfailed")
    snake = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time"
    write_tsv(bench / "train_translator/pix2pix.tsv", snake, "80\t0:01:20\t1\t1\t1\t1\t0\t0\t190\t75.25")
    write_tsv(bench / "loose.tsv", own, "1\t100\t100\t1\tok")
    write_tsv(bench / "reconstruct/.partial.tsv", own, "1\t100\t100\t1\tok")
    (bench / "rasterizer.py").write_text("")
    assert drun.tsv_cpu(bench / "reconstruct/courtyard/gt+3dgs.tsv") == pytest.approx(52.0)
    jobs = drun.job_cpu(bench)
    assert jobs["reconstruct/courtyard/gt+3dgs.tsv"] == pytest.approx(52.0) and len(jobs) == 4
    assert drun.job_cpu_by_rule(jobs) == {
        "reconstruct": {"jobs": 2, "cpu_s": 61.0},
        "evaluate": {"jobs": 1, "cpu_s": 0.5},
        "train_translator": {"jobs": 1, "cpu_s": 75.25},
    }
    assert drun.job_cpu(tmp_path / "missing") == {}


def test_the_jobs_both_runs_did_compare_the_same_work(drun, capsys):
    """A newer default with more rows: the jobs of both (same TSV path) give the like-for-like ratio."""
    base = {"commit": "a" * 40, "jobs": {"reconstruct/c/gt+3dgs.tsv": 80.0, "evaluate/c/gt+3dgs.tsv": 4.0}}
    new = {
        "commit": "b" * 40,
        "jobs": {
            "reconstruct/c/gt+3dgs.tsv": 40.0,
            "evaluate/c/gt+3dgs.tsv": 2.0,
            "reconstruct/c/prior+3dgs.tsv": 50.0,
        },
    }
    for x in (base, new):
        x["rules"] = drun.job_cpu_by_rule(x["jobs"])
    r = drun.ratios(base, new)
    assert r["job_cpu"] == pytest.approx(92 / 84)
    assert r["same_jobs"] == {"jobs": 2, "base_cpu_s": 84.0, "new_cpu_s": 42.0, "ratio": pytest.approx(0.5)}
    drun.print_summary(base, new, r)
    assert "jobs both runs did (2): job CPU base 84.0 s, new 42.0 s, new/base 0.500" in capsys.readouterr().out
    assert drun.same_jobs({"rules": {}}, new) is None  # an --out file from before per-job records


def test_ratios_and_the_machine_readable_last_line(drun, capsys):
    """New / base of job CPU and wall; normalised: x reference_new / reference_base."""
    base = {
        "commit": "a" * 40,
        "run": {"wall_s": 1000.0},
        "ref_before": 240.0,
        "ref_after": 260.0,
        "rules": {"reconstruct": {"jobs": 18, "cpu_s": 1500.0}, "evaluate": {"jobs": 18, "cpu_s": 100.0}},
    }
    new = {
        "commit": "b" * 40,
        "run": {"wall_s": 600.0},
        "ref_before": 200.0,
        "ref_after": 200.0,
        "rules": {"reconstruct": {"jobs": 25, "cpu_s": 700.0}, "evaluate": {"jobs": 25, "cpu_s": 100.0}},
    }
    r = drun.ratios(base, new)
    assert r["job_cpu"] == pytest.approx(0.5) and r["wall"] == pytest.approx(0.6)
    assert r["wall_normalised"] == pytest.approx(0.6 * 200 / 250)
    drun.print_summary(base, new, r)
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "job_cpu_ratio: 0.500"
    assert lines[1].split() == ["evaluate", "18/25", "100.0", "100.0", "1.00"]
    assert lines[3].split() == ["total", "36/50", "1600.0", "800.0", "0.50"]
    assert drun.ratios({"rules": {}}, new)["job_cpu"] is None


def test_run_measured_counts_the_child_and_its_children(drun, tmp_path):
    busy = "import time; t = time.process_time() + 0.2\nwhile time.process_time() < t: pass\nprint('done')"
    child = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {busy!r}], check=True)"
    res = drun.run_measured([sys.executable, "-c", child], tmp_path, None, tmp_path / "log")
    assert res["rc"] == 0 and res["user_s"] + res["sys_s"] >= 0.2 and res["wall_s"] >= 0.2
    assert res["max_rss_mb"] > 1 and (tmp_path / "log").read_text() == "done\n"
    assert drun.run_measured([sys.executable, "-c", "raise SystemExit(3)"], tmp_path, None, tmp_path / "log")["rc"] == 3

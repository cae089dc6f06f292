"""The SLURM profiles (workflow/profiles/slurm, and slurm-local on top of it): a dry run through
snakemake-executor-plugin-slurm submits nothing and shows what every job would ask SLURM for.
tests/test_slurm.py runs them on a real (local) cluster."""

import re
import subprocess

import yaml

from conftest import REPO, run_snakemake

PROFILE = REPO / "workflow" / "profiles" / "slurm"
LOCAL = REPO / "workflow" / "profiles" / "slurm-local"

# The profile deploys per-rule conda environments; a dry run only asks `conda info --json`,
# `conda --version` and `conda config --get channel_priority --json`, so a stand-in answers where
# conda is not installed (nothing is created).
FAKE_CONDA = """#!/bin/sh
case "$*" in
  --version) echo "conda 25.1.1" ;;
  *) echo '{"conda_prefix": "%s", "platform": "linux-64", "get": {"channel_priority": "strict"}}' ;;
esac
"""


def snakemake(workdir, *args, timeout=300, **kw):
    return run_snakemake(workdir, *args, timeout=timeout, **kw)


def conda_stand_in(folder):
    """Write the stand-in ``folder``/bin/conda; returns the bin folder."""
    bin_dir = folder / "bin"
    bin_dir.mkdir()
    conda = bin_dir / "conda"
    conda.write_text(FAKE_CONDA % (folder / "conda"))
    conda.chmod(0o755)
    return bin_dir


def job_blocks(text: str) -> dict[str, list[str]]:
    """Dry-run output -> rule name -> the text block of each of its jobs."""
    blocks: dict[str, list[str]] = {}
    for block in re.split(r"\n(?=\[[^\]]+\]\n(?:local)?rule )", text):
        match = re.search(r"^(?:local)?rule (\w+):", block, re.M)
        if match:
            blocks.setdefault(match.group(1), []).append(block)
    return blocks


def resources(block: str) -> dict[str, str]:
    line = re.search(r"^\s+resources: (.*)$", block, re.M).group(1)
    return dict(item.split("=", 1) for item in line.split(", "))


def test_profile_is_valid_yaml_with_the_slurm_executor():
    text = (PROFILE / "config.yaml").read_text()
    profile = yaml.safe_load(text)
    assert profile["executor"] == "slurm" and profile["jobs"] > 0 and profile["retries"] >= 1
    assert {"train_translator", "reconstruct", "evaluate"} <= set(profile["set-resources"])
    assert "runtime" in profile["default-resources"] and "mem_mb" in profile["default-resources"]
    # No placeholder to fill in before a first run: partition and account are the cluster's defaults.
    assert "EDIT" not in text
    assert all("slurm_partition" not in r for r in [profile["default-resources"], *profile["set-resources"].values()])


def test_slurm_profile_dry_run(tmp_path):
    bin_dir = None if _has_conda() else conda_stand_in(tmp_path)
    proc = snakemake(tmp_path, "--profile", str(PROFILE), "-n", path_prefix=bin_dir)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert "This was a dry-run" in out and "envs/spc3d-gpu.yaml" in out  # the profile's conda_env=gpu
    jobs = job_blocks(out)
    assert len(jobs["train_translator"]) == 7 and len(jobs["evaluate"]) >= 14
    for rule in ("train_translator", "reconstruct"):  # GPU jobs: --gpus=1 on the GPU partition, more memory
        for block in jobs[rule]:
            res = resources(block)
            # 3DGS rasterizes on CPU threads; the untrained stage-1 methods have no network
            gpus = "0" if re.search(r"model=3dgs|method=(prior|classical)\b", block) else "1"
            assert res["gpu"] == gpus and "slurm_partition" not in res, (rule, res)
            assert int(res["mem_mb"]) == 32000 and int(res["runtime"]) >= 720, (rule, res)
    res = resources(jobs["evaluate"][0])
    assert "gpu" not in res and int(res["mem_mb"]) == 8000 and int(res["runtime"]) == 30
    res = resources(jobs["prepare_scene"][0])  # the defaults
    assert "slurm_partition" not in res and int(res["mem_mb"]) == 4000 and int(res["runtime"]) == 60
    # A dry run counts as 1 core (threads are capped by --cores); with more, set-threads shows.
    threads = snakemake(tmp_path, "--profile", str(PROFILE), "-n", "--cores", "8", path_prefix=bin_dir)
    assert threads.returncode == 0, threads.stderr[-3000:]
    blocks = job_blocks(threads.stdout + threads.stderr)
    assert all(re.search(r"^\s+threads: 4$", b, re.M) for b in blocks["train_translator"] + blocks["reconstruct"])
    assert not any(re.search(r"^\s+threads:", b, re.M) for b in blocks["evaluate"])  # 1 thread is not printed


def test_local_profile_on_top_dry_run(tmp_path):
    """slurm-local replaces what a laptop cluster needs and keeps the rest of the slurm profile."""
    proc = snakemake(tmp_path, "--profile", str(PROFILE), "--profile", str(LOCAL), "-n", "--cores", "8")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert "This was a dry-run" in out and "envs/spc3d" not in out  # no conda: the installed environment
    jobs = job_blocks(out)
    for rule in ("train_translator", "reconstruct"):  # no GPU, one thread, memory the node has
        for block in jobs[rule]:
            res = resources(block)
            assert res["gpu"] == "0" and int(res["mem_mb"]) == 1000 and int(res["runtime"]) == 30, (rule, res)
            assert not re.search(r"^\s+threads:", block, re.M), block
    assert resources(jobs["evaluate"][0])["mem_mb"] == "1000"  # the slurm profile's 8000 is replaced
    profile = yaml.safe_load((LOCAL / "config.yaml").read_text())
    assert profile["slurm-status-command"] == "squeue" and "retries" not in profile  # retries: the slurm profile's


def _has_conda() -> bool:
    return subprocess.run(["sh", "-c", "command -v conda"], capture_output=True).returncode == 0

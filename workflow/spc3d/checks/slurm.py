"""SLURM requests tried before anything is submitted: each distinct request of the jobs to run (the
resources the executor plugin turns into sbatch options, first attempt) goes to ``sbatch
--test-only``, so one the cluster cannot satisfy (an unknown partition, more memory, CPUs or GPUs
than a node has) stops the run at once, naming the rule and the resource, instead of failing later
with sbatch's vaguer answer. Called by the workflow's ``onstart`` (workflow/rules/common.smk)."""

from __future__ import annotations

import subprocess

SBATCH_FLAGS = {
    "slurm_partition": "--partition={}",
    "slurm_account": "--account={}",
    "mem_mb": "--mem={}",
    "runtime": "--time={}",
    "threads": "--cpus-per-task={}",
    "gpu": "--gpus={}",
}


def slurm_problems(jobs) -> list[str]:
    """A line per request of ``jobs`` (Snakemake jobs to run) that SLURM refuses; [] if it takes them all."""
    requests = {}
    for job in jobs:
        if not job.is_local:
            ask = {k: job.resources.get(k) for k in SBATCH_FLAGS if k != "threads"} | {"threads": job.threads}
            requests.setdefault(tuple((k, v) for k, v in ask.items() if v not in (None, "", 0)), []).append(job)
    return [p for ask, jobs in requests.items() if (p := slurm_problem(jobs, dict(ask)))]


def slurm_problem(jobs, ask: dict) -> str | None:
    """None if SLURM accepts ``ask``, the request of ``jobs``; else a line naming rule and resource."""
    flags = [SBATCH_FLAGS[k].format(v) for k, v in ask.items()]
    test = subprocess.run(["sbatch", "--test-only", *flags, "--wrap", "true"], capture_output=True, text=True)
    if test.returncode == 0:
        return None
    rules = sorted({job.rule.name for job in jobs})
    example = ", ".join(f"{k}={v}" for k, v in jobs[0].wildcards.items()) or "no wildcards"
    return (
        f"rule{'s' * (len(rules) > 1)} {', '.join(rules)} ({len(jobs)} jobs, e.g. {example}): {refused(ask)}. "
        f"`sbatch --test-only {' '.join(flags)}` says: {' '.join(test.stderr.split())}"
    )


def refused(ask: dict) -> str:
    """What of ``ask`` no node of its partition has (sinfo's nodes: partition, CPUs, MB, GRES)."""
    part = ask.get("slurm_partition")
    sinfo = subprocess.run(["sinfo", "-N", "-h", "-o", "%P %c %m %G"], capture_output=True, text=True).stdout
    nodes = [line.split() for line in sinfo.splitlines()]  # partition (default: *), CPUs, MB, GRES
    mine = [n for n in nodes if n[0].rstrip("*") == part or (part is None and n[0].endswith("*"))]
    where = f"partition {part}" if part else "the default partition"
    cpus = max((int(n[1].rstrip("+")) for n in mine), default=0)
    mem = max((int(n[2].rstrip("+")) for n in mine), default=0)
    if not mine:
        return f"slurm_partition={part}: no such partition (there are {', '.join(sorted({n[0] for n in nodes}))})"
    if ask.get("mem_mb", 0) > mem:
        return f"mem_mb={ask['mem_mb']}: more memory than any node in {where} has ({mem} MB)"
    if ask["threads"] > cpus:
        return f"threads={ask['threads']}: more CPUs than any node in {where} has ({cpus})"
    if ask.get("gpu") and not any("gpu" in n[3] for n in mine):
        return f"gpu={ask['gpu']}: no node in {where} has a GPU (ask for gpu=0, or a GPU partition)"
    return "asks for " + ", ".join(f"{k}={v}" for k, v in ask.items())

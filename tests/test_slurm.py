"""The workflow on a real SLURM cluster: one node on this machine (workflow/tools/slurm_local.sh),
driven through workflow/profiles/slurm (+ slurm-local). The smoke preset runs as SLURM jobs; a
training cancelled mid-way is resubmitted by Snakemake's retry and resumes from its checkpoint; the
tables equal a local one-thread run; a request the cluster cannot satisfy stops the run before
anything is submitted. Skipped where SLURM is not installed (`apt-get install slurm-wlm munge`;
.ci/run installs it and sets SPC3D_REQUIRE_SLURM=1, which turns the skip into a failure)."""

import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import torch
import yaml

from spc3d import io

from conftest import REPO

pytestmark = [pytest.mark.slurm, pytest.mark.slow]

SCRIPT = REPO / "workflow" / "tools" / "slurm_local.sh"
SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
PROFILES = [
    "--profile",
    str(REPO / "workflow" / "profiles" / "slurm"),
    "--profile",
    str(REPO / "workflow" / "profiles" / "slurm-local"),
]
TOOLS = ("munged", "slurmctld", "slurmd", "sbatch", "srun", "squeue", "scancel", "sinfo")
TABLES = [f"results/tables/{name}.csv" for name in ("two_stage", "single_stage", "stage1")]
LONG = 200  # Restormer iterations: long enough to cancel it mid-way (a checkpoint every 20)
# The plugin's job comment: the wildcards sensor ("" for the simulator's RGB), method, rep joined by "_".
# The Restormer training's SLURM comment: "rule_train_translator_wildcards_" + its wildcard values
# joined by "_" (the empty overlay and sensor first, then the method).
RESTORMER = re.compile(r"rule_train_translator_wildcards_+restormer(_|$)")


def _free_port_pair() -> int:
    """A port p with p and p + 1 free (slurmctld, slurmd) for a private cluster."""
    for _ in range(100):
        with socket.socket() as a, socket.socket() as b:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            try:
                b.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
            return port
    raise RuntimeError("no two adjacent free ports")


@pytest.fixture(scope="module")
def cluster():
    """Environment for SLURM clients: the shared local cluster when one runs (.ci/run starts it),
    else a private one in a temporary folder, stopped afterwards."""
    path = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin"])
    missing = [t for t in TOOLS if not shutil.which(t, path=path)]
    if missing:
        why = f"SLURM is not installed ({', '.join(missing)} not found): apt-get install slurm-wlm munge"
        if os.environ.get("SPC3D_REQUIRE_SLURM") == "1":
            pytest.fail(why + " (SPC3D_REQUIRE_SLURM=1)")
        pytest.skip(why)
    env = dict(os.environ, PATH=path)
    shared = subprocess.run([SCRIPT, "status"], env=env, capture_output=True).returncode == 0
    folder = None if shared else Path(tempfile.mkdtemp(prefix="spc3d-slurm-"))  # short: a socket lives there
    if folder:
        env["SPC3D_SLURM_PORT"] = str(_free_port_pair())
    where = [str(folder)] if folder else []
    start = subprocess.run([SCRIPT, "start", *where], env=env, capture_output=True, text=True, timeout=120)
    assert start.returncode == 0, f"the local SLURM cluster did not start:\n{start.stderr}"
    conf, bin_dir = re.search(r"SLURM_CONF=(\S+) PATH=(\S+?):", start.stdout).groups()
    env.update(SLURM_CONF=conf, PATH=f"{bin_dir}{os.pathsep}{path}", PYTHONUNBUFFERED="1")
    yield env
    if folder:
        subprocess.run([SCRIPT, "stop", *where], env=env, capture_output=True, timeout=60)
        shutil.rmtree(folder, ignore_errors=True)


def _snakemake(env, workdir: Path, *args, log: Path):
    """Start snakemake on the repository's Snakefile in ``workdir``; output goes to ``log``."""
    workdir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir), *args]
    with open(log, "w") as out:
        return subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=workdir)


def _finish(proc, log: Path, timeout=900) -> str:
    proc.wait(timeout=timeout)
    text = log.read_text()
    assert proc.returncode == 0, text[-4000:]
    return text


def _jobs(env, run_id: str) -> dict[str, dict]:
    """SLURM's record of every job of one Snakemake run (its jobs are named by the run id)."""
    out = subprocess.run(
        ["squeue", "--states=all", "--noheader", "--name", run_id, "--format=%i|%T|%m|%k"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    rows = (line.split("|", 3) for line in out.splitlines())
    return {jid: {"state": state, "mem": mem, "comment": comment} for jid, state, mem, comment in rows}


def _cancel_when_checkpointed(env, proc, work: Path, log: Path) -> tuple[str, int]:
    """scancel the Restormer training once it has written a checkpoint: (SLURM job id, the
    checkpoint's iteration then, a lower bound for where the retry resumes)."""
    ckpt = work / "results" / "checkpoints" / "models" / "restormer" / "checkpoint.pt"
    deadline = time.monotonic() + 600  # a guard against a hang, not a timing
    running = []
    while not running and proc.poll() is None:
        assert time.monotonic() < deadline, "the Restormer training never wrote a checkpoint"
        time.sleep(0.2)
        if ckpt.exists():
            jobs = _jobs(env, re.search(r"SLURM run ID: (\S+)", log.read_text()).group(1))
            running = [i for i, j in jobs.items() if RESTORMER.match(j["comment"]) and j["state"] == "RUNNING"]
    assert proc.poll() is None, "the SLURM run ended before the training could be cancelled"
    subprocess.run(["scancel", running[0]], env=env, check=True)
    return running[0], int(torch.load(ckpt, weights_only=True)["iteration"])


def test_smoke_preset_on_slurm_with_a_cancelled_training(cluster, tmp_path, lpips_cache):
    """The smoke preset's tables for one two-stage combination (about a dozen SLURM jobs: 2 CPUs
    here, and every job starts Snakemake twice), its translator trained long enough to be cancelled
    mid-way."""
    extra = tmp_path / "extra.yaml"
    extra.write_text(
        yaml.safe_dump(
            {
                "metrics": {"lpips_source": str(lpips_cache)},
                "checkpoints": {"fraction": 0.1, "minutes": 0},
                "stage1": {"restormer": {"train": {"iterations": LONG}}},
                "stage2": {"combinations": ["restormer+3dgs"]},
            }
        )
    )
    configs = [*TABLES, "--configfile", str(SMOKE), str(extra)]
    work, ref = tmp_path / "slurm", tmp_path / "local"
    # The reference runs alongside: uninterrupted, local, one thread (as every SLURM job is).
    local = _snakemake(cluster, ref, "--cores", "1", *configs, log=tmp_path / "local.log")
    slurm = _snakemake(cluster, work, *PROFILES, *configs, log=tmp_path / "slurm.log")
    try:
        cancelled, checkpointed = _cancel_when_checkpointed(cluster, slurm, work, tmp_path / "slurm.log")
        out = _finish(slurm, tmp_path / "slurm.log")
        _finish(local, tmp_path / "local.log")
    finally:
        for proc in (slurm, local):  # on a failure: Snakemake cancels its SLURM jobs on SIGTERM
            if proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=60)

    # Every job but the local rules was a SLURM job; all completed but the cancelled one.
    run_id = re.search(r"SLURM run ID: (\S+)", out).group(1)
    jobs = _jobs(cluster, run_id)
    submitted = re.findall(r"Job \d+ has been submitted with SLURM jobid (\d+)", out)
    remote = re.findall(r"^rule (\w+):", out, re.M)  # the local rule lpips_weights prints as `localrule`
    assert {"train_translator", "translate_scene", "reconstruct", "evaluate", "write_all_tables"} <= set(remote)
    assert len(remote) == len(submitted) == len(jobs), (remote, submitted, jobs)
    assert set(submitted) == set(jobs)
    assert {j["state"] for i, j in jobs.items() if i != cancelled} == {"COMPLETED"}
    assert jobs[cancelled]["state"] == "CANCELLED"

    # Snakemake's retry resubmitted the training with the attempt-scaled memory...
    restormer = sorted((i for i, j in jobs.items() if RESTORMER.match(j["comment"])), key=int)
    assert restormer[0] == cancelled and len(restormer) == 2, restormer
    assert [jobs[i]["mem"] for i in restormer] == ["1000M", "2000M"]
    # ...and it resumed from the checkpoint the cancelled job left, mid-way.
    rec = io.read_json(work / "results" / "models" / "restormer" / "train.json")
    assert checkpointed <= rec["resumed_from"] < LONG and rec["resumed_from"] % (LONG // 10) == 0, rec
    assert rec["checkpoint"]["discarded"] is None and rec["train"]["iterations"] == LONG
    assert "resuming from" in (work / "logs" / "train_translator" / "restormer.log").read_text()
    assert io.read_json(ref / "results" / "models" / "restormer" / "train.json")["resumed_from"] == 0

    # The same numbers as the uninterrupted local run: tables and every metric, exactly.
    for table in TABLES:
        assert (work / table).read_text() == (ref / table).read_text(), table
    assert "restormer+3dgs,paper,1," in (work / TABLES[0]).read_text()
    metrics = sorted((ref / "results" / "eval").glob("*/*/metrics.json"))
    assert len(metrics) == 1
    for path in metrics:
        mine = io.read_json(work / path.relative_to(ref))
        assert mine["mean"] == io.read_json(path)["mean"], path
    assert not (ref / ".snakemake" / "slurm_logs").exists()  # the reference did not use SLURM


@pytest.mark.parametrize(
    "args,expected",
    [
        (
            ["--set-resources", "reconstruct:mem_mb=10000000", "train_translator:gpu=0", "reconstruct:gpu=0"],
            ["rule reconstruct (", "mem_mb=10000000: more memory than any node in the default partition has ("],
        ),
        (
            [
                "--default-resources",
                "slurm_partition=nosuch",
                "mem_mb=1000",
                "runtime=30",
                "--set-resources",
                "train_translator:gpu=0",
                "reconstruct:gpu=0",
            ],
            ["slurm_partition=nosuch: no such partition (there are local*)"],
        ),
    ],
    ids=["memory", "partition"],
)
def test_a_request_the_cluster_cannot_satisfy_stops_before_any_submission(
    cluster, tmp_path, lpips_cache, args, expected
):
    extra = tmp_path / "extra.yaml"
    extra.write_text(yaml.safe_dump({"metrics": {"lpips_source": str(lpips_cache)}}))
    log = tmp_path / "snakemake.log"
    proc = _snakemake(cluster, tmp_path / "w", *PROFILES, *args, "--configfile", str(SMOKE), str(extra), log=log)
    proc.wait(timeout=300)
    out = log.read_text()
    assert proc.returncode == 1, out[-3000:]
    assert "SLURM cannot run these jobs, nothing was submitted" in out
    for text in expected:
        assert text in out, out[-3000:]
    run_id = re.search(r"SLURM run ID: (\S+)", out).group(1)
    assert _jobs(cluster, run_id) == {}
    assert not (tmp_path / "w" / ".snakemake" / "slurm_logs").exists()
    assert not (tmp_path / "w" / "results" / "scenes").exists()


def _alive_in_bash(script: str, folder: Path) -> subprocess.CompletedProcess:
    """Run `script` in bash under the script's own `set -euo pipefail`, with its `alive` defined."""
    source = f"set -euo pipefail\nsource <(sed -n '/^alive()/,/^}}/p' {SCRIPT})\n"
    env = {**os.environ, "DIR": str(folder)}
    return subprocess.run(["bash", "-c", source + script], env=env, capture_output=True, text=True, timeout=120)


def test_alive_reads_pid_files(tmp_path):
    """`alive` answers "not alive" for a missing, empty or stale pid file or another program's pid,
    and gives the pid of a live process of that name."""
    (tmp_path / "empty.pid").write_text("")
    (tmp_path / "stale.pid").write_text("999999999\n")
    run = _alive_in_bash(
        'for f in missing empty stale; do alive $DIR/$f.pid munged >/dev/null || echo "$f: not alive"; done\n'
        "sleep 30 & echo $! > $DIR/sleep.pid\n"
        "[[ $(alive $DIR/sleep.pid sleep) == $! ]] && echo 'sleep: alive'\n"
        "alive $DIR/sleep.pid munged >/dev/null || echo 'sleep as munged: not alive'\n"
        "kill $!\n",
        tmp_path,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == [
        "missing: not alive",
        "empty: not alive",
        "stale: not alive",
        "sleep: alive",
        "sleep as munged: not alive",
    ]


def test_alive_survives_a_pid_file_deleted_while_it_reads(tmp_path):
    """`slurm_local.sh stop` races the daemons, which delete their pid files as they exit. A pid file
    created and deleted in a tight loop while `alive` asks 1,500 times must never end the script (a
    failed `$(<file)` did, inside `||`, and failed CI after its tests had passed)."""
    run = _alive_in_bash(
        "( while true; do echo 999999999 > $DIR/flip.pid; rm -f $DIR/flip.pid; done ) & flipper=$!\n"
        "trap 'kill $flipper' EXIT\n"
        "for i in $(seq 1500); do alive $DIR/flip.pid munged >/dev/null || true; done\n"
        "echo survived\n",
        tmp_path,
    )
    assert (run.returncode, run.stdout) == (0, "survived\n"), run.stderr

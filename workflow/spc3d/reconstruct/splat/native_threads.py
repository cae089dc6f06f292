"""Worker threads for the native splat kernels: torch's own OpenMP team where possible.

After every parallel torch op, torch's OpenMP (libgomp) workers spin-wait for the next parallel
region (GOMP_SPINCOUNT) before they sleep. In a training step torch ops (loss, projection glue)
run between the numba kernels, so separate kernel threads always competed with a spinning
OpenMP thread for the cores, and a step took markedly longer than with torch's workers passive
(``OMP_WAIT_POLICY=PASSIVE``; the numbers are in docs/benchmarks.md). Running the kernels
*inside* an OpenMP parallel region of torch's libgomp hands the work to exactly those spinning
threads instead; nothing global is changed (no environment variable, no thread count).

How: ``GOMP_parallel(fn, data, n, 0)`` of the libgomp that torch loaded, called through ctypes
(which releases the GIL); ``fn`` is a ctypes callback that takes the GIL for a moment, asks
``omp_get_thread_num()`` which share of tiles it owns and calls a ``nogil`` numba kernel. Where
torch does not use libgomp (other platforms / builds) a ``ThreadPoolExecutor`` is used instead.

Dynamic scheduling: ``next_item`` (an atomic fetch-and-add in numba) lets the workers of one
region take tiles from a shared counter, so a worker that started late or runs slower takes
fewer tiles; results must then not depend on which worker took what (the kernels write per
tile or per tile-list record, never into per-worker sums).
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
from numba import njit, types
from numba.core import cgutils
from numba.core.extending import intrinsic

_CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p)


def _find_torch_gomp():
    """torch's libgomp (a ctypes library) if this process uses it, else None."""
    if not sys.platform.startswith("linux") or "OpenMP" not in torch.__config__.parallel_info():
        return None
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split()[-1] for line in f if "libgomp" in line}
    except OSError:
        return None
    torch_dir = os.path.dirname(torch.__file__)
    paths = sorted(paths, key=lambda p: not p.startswith(torch_dir))  # torch's own copy first
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
            lib.GOMP_parallel.argtypes = [_CALLBACK, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint]
            lib.GOMP_parallel.restype = None
            for name in ("omp_get_thread_num", "omp_get_num_threads"):
                getattr(lib, name).restype, getattr(lib, name).argtypes = ctypes.c_int, []
            return lib
        except (OSError, AttributeError):
            continue
    return None


_GOMP = _find_torch_gomp()
_POOL: list = [None, 0]  # fallback: [ThreadPoolExecutor, its worker count]


def n_workers(n_tasks: int) -> int:
    """Workers used for ``n_tasks`` independent tasks: torch.get_num_threads(), at most n_tasks."""
    return max(1, min(torch.get_num_threads(), n_tasks))


def run_parallel(work, n: int) -> None:
    """Calls ``work(w)`` for w in range(n) concurrently (``work`` must release the GIL for the
    calls to overlap: numba ``nogil`` kernels) and re-raises the first exception."""
    if n == 1:
        work(0)
        return
    if _GOMP is not None:
        _run_gomp(work, n)
        return
    if _POOL[1] != n:
        _POOL[0], _POOL[1] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="splat"), n
    for future in [_POOL[0].submit(work, w) for w in range(n)]:
        future.result()


def in_chunks(kernel, n: int, inputs: tuple, outputs: tuple, grain: int = 2048) -> None:
    """``kernel(*inputs, counter, n, *outputs)`` on every worker (at most one per ``grain`` items:
    smaller shares are not worth a thread); the kernel takes chunks of the n items with
    ``next_chunk(counter, n, size)`` until none is left, so a worker that starts late takes fewer
    (the first OpenMP thread to enter a region can run for a while before the others get the GIL),
    and writes only the outputs of its chunks."""
    counter = np.zeros(1, np.int64)
    run_parallel(lambda w: kernel(*inputs, counter, n, *outputs), n_workers(max(1, n // grain)))


@intrinsic
def next_items(typingctx, counter, n):
    """Atomically ``counter[0] += n`` (int64 array) and return the old value: the first of the
    next n work items of a dynamically scheduled loop. Relaxed ordering: the counter only deals
    out indices; the end of the parallel region orders everything the workers wrote."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and isinstance(n, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, [context.get_constant(types.intp, 0)])
        inc = context.cast(builder, args[1], signature.args[1], types.int64)
        return builder.atomic_rmw("add", ptr, inc, "monotonic")

    return types.int64(counter, n), codegen


@njit(inline="always")
def next_item(counter):
    """``next_items(counter, 1)``: the next work item."""
    return next_items(counter, 1)


@njit(inline="always")
def next_chunk(counter, n, size):
    """(first item, item count) of the next chunk of ``size`` of n items; count <= 0: none left."""
    c0 = next_item(counter) * size
    return c0, min(size, n - c0)


_KEPT: set = set()  # idents of OpenMP worker threads whose Python thread state is kept


def _keep_thread_state() -> None:
    """Keep this OpenMP worker thread's Python thread state alive between regions.

    A ctypes callback on a thread Python did not create makes a new thread state on entry
    (PyGILState_Ensure) and deletes it on exit, which took most of a two-thread region's time
    (~5 such regions per training step). One extra PyGILState_Ensure, never released,
    keeps it: the callback's own release then only gives back the GIL. The states
    belong to torch's OpenMP threads, which live as long as the process."""
    ident = threading.get_ident()
    if ident not in _KEPT:
        ctypes.pythonapi.PyGILState_Ensure()
        _KEPT.add(ident)


def _run_gomp(work, n: int) -> None:
    """``work(w)`` on the n threads of an OpenMP team of torch's libgomp (thread 0: this one).
    libgomp may give a team fewer threads than asked (e.g. nested regions): shares are then
    dealt round-robin over the team, so every w runs exactly once."""
    errors = []

    def task(_data):
        try:
            tid, size = _GOMP.omp_get_thread_num(), _GOMP.omp_get_num_threads()
            if tid != 0:
                _keep_thread_state()
            for w in range(tid, n, size):
                work(w)
        except BaseException as e:  # noqa: BLE001 - re-raised below, outside the OpenMP region
            errors.append(e)

    _GOMP.GOMP_parallel(_CALLBACK(task), None, n, 0)
    if errors:
        raise errors[0]

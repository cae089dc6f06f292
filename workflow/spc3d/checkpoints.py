"""Checkpoints of a training (both stages): fingerprints, when to save, one trainer per checkpoint.

    fingerprint, digest_path, digest_arrays, differences    what determines a training
    Checkpoint, CheckpointPolicy                             checkpoints that belong to their settings
    CheckpointLock, SnakemakeWatch                           one trainer per checkpoint, none orphaned

:func:`spc3d.training.run` (the loop) resumes from, saves and locks a :class:`Checkpoint` per its
:class:`CheckpointPolicy`: every ``fraction`` of the run or every ``minutes`` of training, whichever
comes first (and at the end).

**A checkpoint belongs to its settings.** It stores the job's *fingerprint*: the resolved settings
and seed, a digest of every input file, a digest of this package's code and :data:`FORMAT`. It is
resumed only when the fingerprint is identical; otherwise it is deleted, with a log line naming
what changed (``settings.iterations: 40 -> 20``), and the training starts from scratch. A rerun
after a settings change can therefore never continue (or silently reuse) a model trained under
other settings, and the record describes the model actually in it. Checkpoints are read with
``torch.load(weights_only=True)``: no pickled code runs.

**One trainer per checkpoint, and none without its Snakemake.** While it trains, the loop
holds an exclusive lock on ``<checkpoint>.lock`` (:class:`CheckpointLock`): a second training of
the same checkpoint (a rerun while an earlier one still runs) stops at once with a message naming
the other process. A training started by Snakemake stops by itself, within about a second and
before writing anything more, once that Snakemake process is gone (:class:`SnakemakeWatch`:
after ``kill -9`` of Snakemake it would otherwise run on, reparented, writing its checkpoint).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spc3d import io
from spc3d.provenance import ROOT, files_digest

try:
    import fcntl  # POSIX only: where it is missing (Windows) a checkpoint is not locked
except ImportError:  # pragma: no cover
    fcntl = None

log = logging.getLogger(__name__)

FORMAT = 2  # bump when what a checkpoint holds changes meaning (2: fingerprinted checkpoints)


# --- fingerprints -------------------------------------------------------------------------------


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as f:
        for block in iter(functools.partial(f.read, 1 << 20), b""):
            h.update(block)


def digest_path(path: str | os.PathLike | None) -> str | None:
    """sha256 of a file, or of a folder's files (relative names and contents, sorted).

    Hidden entries (``.name``: the atomic writers' temporary folders) are skipped.
    """
    if path is None:
        return None
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"input {path} does not exist (cannot fingerprint a training on it)")
    h = hashlib.sha256()
    if path.is_file():
        _hash_file(h, path)
        return h.hexdigest()
    for root, dirs, files in os.walk(path):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(f for f in files if not f.startswith(".")):
            file = Path(root) / name
            h.update(str(file.relative_to(path)).encode() + b"\0")
            _hash_file(h, file)
    return h.hexdigest()


def digest_arrays(arrays: dict | None) -> str | None:
    """sha256 of a dict of arrays (e.g. loss-network weights handed over in memory)."""
    if arrays is None:
        return None
    h = hashlib.sha256()
    for key in sorted(arrays):
        a = np.ascontiguousarray(np.asarray(arrays[key]))
        h.update(f"{key}:{a.dtype}:{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """The code key of this package's Python sources (:func:`spc3d.provenance.files_digest`: blind
    to comments, docstrings and formatting): a change of code invalidates every checkpoint."""
    return files_digest(sorted(ROOT.rglob("*.py")))


def canonical(obj):
    """A JSON-stable copy: tuples -> lists, numpy scalars -> numbers, paths -> strings, keys sorted."""
    return json.loads(json.dumps(obj, sort_keys=True, default=io.json_default))


FINGERPRINT_KEYS = ("format", "code", "kind", "inputs")


def fingerprint(kind: str, job: dict, inputs: dict[str, str | None]) -> dict:
    """What determines a training: its kind, the job's resolved settings (seed included), input
    digests and the code. ``job``'s keys sit at the top level, so a change reads as
    ``settings.iterations: 40 -> 20`` or ``seed: 0 -> 1``; ``inputs`` maps a name to a digest
    (:func:`digest_path`, :func:`digest_arrays`) or None."""
    clash = sorted(set(job) & set(FINGERPRINT_KEYS))
    if clash:
        raise ValueError(f"fingerprint: job keys {clash} are reserved")
    return {"format": FORMAT, "code": code_digest(), "kind": kind, **canonical(job), "inputs": dict(inputs)}


def _flatten(obj, prefix: str = "") -> dict:
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: obj}


def differences(old: dict, new: dict, limit: int = 6) -> str:
    """What changed between two fingerprints, e.g. ``settings.iterations: 40 -> 20; inputs.scene changed``."""
    a, b = _flatten(old), _flatten(new)
    diffs = []
    for key in sorted(set(a) | set(b)):
        if a.get(key, "<unset>") == b.get(key, "<unset>"):
            continue
        if key.startswith("inputs.") or key == "code":
            diffs.append(f"{key} changed")
        else:
            diffs.append(f"{key}: {_short(a.get(key, '<unset>'))} -> {_short(b.get(key, '<unset>'))}")
    more = f"; and {len(diffs) - limit} more" if len(diffs) > limit else ""
    return "; ".join(diffs[:limit]) + more


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 40 else text[:37] + "..."


# --- checkpoints --------------------------------------------------------------------------------


@dataclass(frozen=True)
class CheckpointPolicy:
    """When a training writes its checkpoint (always at the end too)."""

    fraction: float = 0.1  # every this fraction of the run's iterations (0: never by count)
    minutes: float = 10.0  # and after this many minutes of training since the last one (0: never by time)

    def __post_init__(self):
        if not 0.0 <= self.fraction <= 1.0 or self.minutes < 0:
            raise ValueError(f"checkpoints: need 0 <= fraction <= 1 and minutes >= 0, got {self}")

    def every(self, iterations: int) -> int | None:
        """Iterations between count-based checkpoints (None: only by time and at the end)."""
        return max(1, math.ceil(self.fraction * iterations)) if self.fraction > 0 else None


class Checkpoint:
    """One training's checkpoint file and the fingerprint it must carry to be resumed.

    ``record`` collects what happened (resumed from, discarded and why, saves) for ``train.json``.
    """

    def __init__(self, path: str | os.PathLike, fingerprint: dict):
        self.path, self.fingerprint = Path(path), fingerprint
        self.record = {"path": str(self.path), "resumed_from": 0, "discarded": None, "saves": 0}

    def _read(self) -> dict | None:
        """The saved checkpoint if it belongs to this job, else None (discarded with a reason)."""
        if not self.path.is_file():
            return None
        try:
            saved = torch.load(self.path, weights_only=True, map_location="cpu")
            old = saved["fingerprint"]
        except Exception as e:  # noqa: BLE001 - any unreadable file is discarded the same way
            return self._discard(f"unreadable ({type(e).__name__}: {str(e).splitlines()[0][:120]})")
        if old != self.fingerprint:
            return self._discard(differences(old, self.fingerprint))
        return saved

    def _discard(self, why: str) -> None:
        log.warning("discarding checkpoint %s, it does not belong to this run: %s", self.path, why)
        self.path.unlink(missing_ok=True)
        self.record["discarded"] = why
        return None

    def resume(self, trainer) -> tuple[int, float]:
        """Load ``trainer`` from the checkpoint if it belongs to this job: (iterations done, seconds)."""
        saved = self._read()
        if saved is None:
            return 0, 0.0
        trainer.load(saved["state"])
        torch.set_rng_state(saved["torch_rng"])
        it = int(saved["iteration"])
        log.info("resuming from %s at iteration %d", self.path, it)
        self.record["resumed_from"] = it
        return it, float(saved["elapsed_s"])

    def save(self, it: int, trainer, elapsed: float) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with io.atomic_path(self.path) as tmp:
            torch.save(
                {
                    "fingerprint": self.fingerprint,
                    "iteration": it,
                    "state": trainer.state(),
                    "elapsed_s": elapsed,
                    "torch_rng": torch.get_rng_state(),
                },
                tmp,
            )
        self.record["saves"] += 1


# --- guards: one trainer per checkpoint, none without its Snakemake -------------------------------


class CheckpointInUse(RuntimeError):
    """Another live training holds the checkpoint (see :class:`CheckpointLock`)."""


class Orphaned(RuntimeError):
    """The Snakemake process that started this training is gone (see :class:`SnakemakeWatch`)."""


class CheckpointLock:
    """An exclusive ``flock`` on ``<checkpoint>.lock``, held while a training runs.

    A second trainer of the same checkpoint raises :class:`CheckpointInUse`, naming the holder
    (pid, host and start, which the holder writes into the file). The file is removed on release;
    as another process may have opened it just before, a new holder checks that the file it locked
    is still the one at the path. Without ``fcntl`` (Windows), or on a file system without locks
    (logged), nothing is locked.
    """

    def __init__(self, checkpoint: str | os.PathLike):
        self.checkpoint = Path(checkpoint)
        self.path = self.checkpoint.with_name(self.checkpoint.name + ".lock")
        self.fd: int | None = None

    def __enter__(self) -> CheckpointLock:
        if fcntl is None:
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while self.fd is None:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 256, 0).decode(errors="replace").split()
                os.close(fd)
                raise CheckpointInUse(self.busy(holder)) from None
            except OSError as e:  # e.g. ENOLCK: a file system without locks
                os.close(fd)
                log.warning("cannot lock %s (%s): a second trainer of this checkpoint would go unnoticed", self.path, e)
                return self
            if _same_file(fd, self.path):
                self.fd = fd
            else:  # its holder released and removed it meanwhile: lock the file now at the path
                os.close(fd)
        os.ftruncate(self.fd, 0)
        os.write(self.fd, f"{os.getpid()} {socket.gethostname()} {time.strftime('%Y-%m-%dT%H:%M:%S')}\n".encode())
        return self

    def busy(self, holder: list[str]) -> str:
        """The refusal: which checkpoint, held by whom (``holder``: pid, host, start), what to do."""
        pid, host, since = (holder + ["?", "?", "?"])[:3]
        return (
            f"checkpoint {self.checkpoint} is in use by another training (pid {pid} on {host}, started "
            f"{since}): two trainers would overwrite each other's checkpoint. Wait until it ends, or stop "
            f"it (`kill {pid}` on {host}) and rerun; a training whose Snakemake was killed stops by itself "
            f"within a few seconds."
        )

    def __exit__(self, *exc) -> None:
        if self.fd is not None:
            self.path.unlink(missing_ok=True)  # while still holding the lock (see __enter__)
            os.close(self.fd)
            self.fd = None


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    fst = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (fst.st_dev, fst.st_ino)


WATCH_EVERY_S = 1.0  # how often a training looks for its Snakemake (and always before a checkpoint)


class SnakemakeWatch:
    """Notices that the Snakemake process which started this training is gone.

    It records this process's ancestors up to the outermost Snakemake among them: a Snakemake 9
    ``script:`` job is its direct child, but a shell or a ``--mode subprocess`` Snakemake may sit in
    between, and in a SLURM job the outermost is the job's own Snakemake (under slurmstepd). When
    one of them dies its children are reparented, so the chain read again differs, and
    :meth:`check` raises :class:`Orphaned`. Linux only (``/proc``): elsewhere, and outside
    Snakemake, :meth:`start` returns None and nothing is watched.
    """

    def __init__(self, chain: list[int]):
        self.chain, self.next_check = chain, time.monotonic() + WATCH_EVERY_S

    @classmethod
    def start(cls) -> SnakemakeWatch | None:
        chain = _ancestors()
        found = [i for i, pid in enumerate(chain) if _is_snakemake(_cmdline(pid))]
        return cls(chain[: found[-1] + 1]) if found else None

    def check(self, now: bool = False) -> None:
        """Raise :class:`Orphaned` when the chain changed (read every WATCH_EVERY_S, or ``now``)."""
        if not now and time.monotonic() < self.next_check:
            return
        self.next_check = time.monotonic() + WATCH_EVERY_S
        if _ancestors(len(self.chain)) != self.chain:
            raise Orphaned(
                f"the Snakemake process that started this training (pid {self.chain[-1]}) is gone: "
                "stopping, so that no orphaned training runs on and writes; rerun the workflow "
                "(after `snakemake --unlock`) to resume from the last checkpoint"
            )


def _ancestors(limit: int = 64) -> list[int]:
    """This process's parent, grandparent, ... (read from /proc: empty where there is none)."""
    chain, pid = [], os.getppid()
    while pid > 0 and len(chain) < limit:
        try:
            with open(f"/proc/{pid}/stat", "rb") as f:
                stat = f.read()
        except OSError:  # no /proc, or the process just ended
            break
        chain.append(pid)
        pid = int(stat[stat.rindex(b")") + 2 :].split()[1])  # the field after the state; comm may hold ")"
    return chain


def _cmdline(pid: int) -> list[str]:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().decode(errors="replace").split("\0")
    except OSError:
        return []


def _is_snakemake(argv: list[str]) -> bool:
    """``snakemake ...``, ``python /venv/bin/snakemake ...`` or ``python -m snakemake ...``."""
    if any(os.path.basename(a) == "snakemake" for a in argv[:2]):
        return True
    return "-m" in argv[1:] and argv[argv.index("-m") + 1 : argv.index("-m") + 2] == ["snakemake"]

"""Training utilities shared by stage 1 (:mod:`spc3d.translate`) and stage 2 (:mod:`spc3d.reconstruct`).

    seed_everything, default_device, peak_rss_mb                  small helpers both stages use
    Plateau                                                        the stage-2 stopping rule
    run                                                            the one training loop

Checkpoints (fingerprints, when to save, the lock, the Snakemake watch) are :mod:`spc3d.checkpoints`.

A trainer (stage 1: :class:`spc3d.translate.train.TranslatorTrainer`; stage 2: one per model
family) offers

    step(it) -> dict[str, float]     one optimisation step (``it`` is 1-based); the values are shown
    state() -> dict / load(state)    everything needed to continue bit for bit (no pickled objects:
                                     tensors, numbers, strings, lists and dicts only)
    should_stop() -> bool            optional: True after a step ends the training early (e.g.
                                     validation stopped improving); a checkpoint is written then

:func:`run` drives it: a tqdm bar, a checkpoint every ``CheckpointPolicy.fraction`` of the run or
every ``minutes`` of training, whichever comes first (and at the end), and on restart a resume from
the last checkpoint. A checkpoint is resumed only when its fingerprint is the job's own, and while
it trains :func:`run` holds the checkpoint's lock and, under Snakemake, stops once that Snakemake
is gone (:mod:`spc3d.checkpoints`).
"""

from __future__ import annotations

import contextlib
import math
import random
import resource
import time

import numpy as np
import torch
from tqdm import tqdm

from spc3d.checkpoints import Checkpoint, CheckpointLock, CheckpointPolicy, SnakemakeWatch

# --- small helpers ------------------------------------------------------------------------------


def seed_everything(seed: int) -> None:
    """Python, numpy and torch's global generators (models draw from their own seeded streams too)."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def default_device() -> torch.device:
    """CUDA when present, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def set_lr(optimizer: torch.optim.Optimizer, lrs: dict[str, float]) -> None:
    """Set each named parameter group's learning rate from ``lrs`` (group name -> lr)."""
    for group in optimizer.param_groups:
        group["lr"] = lrs[group["name"]]


# --- the stopping rule ---------------------------------------------------------------------------


class Plateau:
    """Stops a training once its own objective has stopped improving (the stage-2 trainers' rule).

    Every ``window`` steps the training objective is averaged per training view and then over the
    views seen, so a window's value does not depend on which views the random draw happened to
    pick. A window counts as progress when that value is below the best window so far by at least
    ``min_gain`` of it and by at least ``tol`` (in the objective's units: a fit already that close
    to its floor has nothing left that matters, though its tiny values may still halve);
    ``patience`` windows in a row without progress stop the training, never before step ``start``
    (while a schedule still changes the model: coarse-to-fine grids). ``patience`` 0 never stops.
    A trainer that holds training views out of its fit (``plateau_views``) instead closes each
    window with its objective on those views (:meth:`close`): a fit that has begun to learn its
    targets' view-inconsistent noise stops there, while its training loss still falls.
    Only training views are read: the scored views play no part in when a training ends.
    """

    def __init__(self, window: int, patience: int, min_gain: float, start: int = 0, tol: float = 0.0):
        if window < 1 or patience < 0 or not 0.0 <= min_gain < 1.0 or not tol >= 0.0:
            raise ValueError(
                f"plateau rule: need window >= 1, patience >= 0, 0 <= min_gain < 1 and tol >= 0 "
                f"(got window = {window}, patience = {patience}, min_gain = {min_gain}, tol = {tol})"
            )
        self.window, self.patience, self.min_gain, self.start, self.tol = window, patience, min_gain, start, tol
        self.sums: dict[int, list[float]] = {}  # view -> [sum, count] in the current window
        self.curve: list[tuple[int, float]] = []  # (last step of a window, its value)
        self.best, self.since_best, self.stopped_at = math.inf, 0, None
        self.views: list[str] = []  # training views held out of the fit that judge it (none: the objective)

    @classmethod
    def of(cls, cfg, enabled: bool = True, start: int = 0) -> Plateau:
        """The rule of a model config's ``plateau_window / _patience / _gain / _tol`` fields;
        ``enabled`` False (an objective whose relative gains mean nothing) never stops."""
        patience = cfg.plateau_patience if enabled else 0
        return cls(cfg.plateau_window, patience, cfg.plateau_gain, start, cfg.plateau_tol)

    def update(self, it: int, value: float, view: int = 0) -> None:
        """Add step ``it``'s training objective on training view ``view``."""
        acc = self.sums.setdefault(view, [0.0, 0])
        acc[0], acc[1] = acc[0] + value, acc[1] + 1
        if it % self.window:
            return
        mean = float(np.mean([s / n for s, n in self.sums.values()]))
        self.sums = {}
        self.close(it, mean)

    def observe(self, it: int, value: float, view: int = 0, held_out=None) -> None:
        """A trainer's per-step call: its training objective ``value`` on ``view``, or, when it
        holds views out of its fit, ``held_out()`` (their objective) once per window."""
        if held_out is None:
            self.update(it, value, view)
        elif it % self.window == 0:
            self.close(it, held_out())

    def close(self, it: int, mean: float) -> None:
        """End the window at step ``it`` with value ``mean``: the training views' mean from
        :meth:`update`, or the objective on views held out of the fit (``views``)."""
        self.curve.append((it, mean))
        if self.best == math.inf or self.best - mean >= max(self.min_gain * self.best, self.tol):
            self.best, self.since_best = mean, 0
        else:
            self.best, self.since_best = min(self.best, mean), self.since_best + 1
        if self.patience and self.since_best >= self.patience and it >= self.start:
            self.stopped_at = it

    def should_stop(self) -> bool:
        return self.stopped_at is not None

    def record(self, iterations: int, steps: int) -> dict:
        """Where and why the training stopped, with the rule and its curve (for ``train.json``)."""
        reason = "plateau" if self.stopped_at is not None else "budget"
        rule = {"window": self.window, "patience": self.patience, "min_gain": self.min_gain, "tol": self.tol}
        rule["start"] = self.start
        judged = {"on": "held-out training views" if self.views else "training objective", "views": self.views}
        return {"step": steps, "of": iterations, "reason": reason, "rule": rule | judged, "curve": self.curve}

    def state(self) -> dict:
        return {
            "sums": [[v, s, n] for v, (s, n) in self.sums.items()],
            "curve": [list(c) for c in self.curve],
            "best": self.best,
            "since_best": self.since_best,
            "stopped_at": self.stopped_at,
        }

    def load(self, state: dict) -> None:
        self.sums = {int(v): [float(s), int(n)] for v, s, n in state["sums"]}
        self.curve = [(int(i), float(m)) for i, m in state["curve"]]
        self.best, self.since_best, self.stopped_at = state["best"], state["since_best"], state["stopped_at"]


# --- the loop -----------------------------------------------------------------------------------


def run(
    trainer,
    iterations: int,
    checkpoint: Checkpoint | None = None,
    policy: CheckpointPolicy = CheckpointPolicy(),
    desc: str = "train",
    log_every: int = 50,
    postfix=None,
) -> dict:
    """Train to ``iterations`` (resuming from ``checkpoint`` when it belongs to this job), or until
    the trainer's optional ``should_stop()`` says so after a step (early stopping).

    ``postfix(stats) -> dict`` adds values to the progress bar every ``log_every`` steps. The
    checkpoint is locked while it trains (:class:`CheckpointInUse` if another training holds it),
    and under Snakemake it stops with :class:`Orphaned` once that Snakemake is gone. A stop is
    checkpointed at once, and a trainer resumed from that checkpoint stops without a step. Returns
    iterations, steps done, whether it stopped early, resume point, training seconds, the last
    step's values and the checkpoint record.
    """
    if iterations < 1:
        raise ValueError(f"{desc}: iterations must be >= 1 (got {iterations}); an untrained model is not a result")
    watch = SnakemakeWatch.start()
    with CheckpointLock(checkpoint.path) if checkpoint else contextlib.nullcontext():
        start, elapsed = checkpoint.resume(trainer) if checkpoint else (0, 0.0)
        every, t0 = policy.every(iterations), time.perf_counter() - elapsed
        last_save, stats, done = time.perf_counter(), {}, start
        stopped = _wants_stop(trainer)  # resumed from the checkpoint of an early stop
        steps = range(start + 1, iterations + 1) if not stopped else range(0)
        bar = tqdm(steps, desc=desc, initial=start, total=iterations, mininterval=2.0)
        for it in bar:
            if watch:
                watch.check()
            stats, done = trainer.step(it), it
            stopped = _wants_stop(trainer)
            if it % log_every == 0:
                bar.set_postfix({k: f"{v:.4f}" for k, v in stats.items()} | (postfix(stats) if postfix else {}))
            due = (
                it == iterations
                or stopped
                or (every and it % every == 0)
                or (policy.minutes > 0 and time.perf_counter() - last_save >= 60.0 * policy.minutes)
            )
            if checkpoint and due:
                if watch:
                    watch.check(now=True)  # never write for a Snakemake that is gone
                checkpoint.save(it, trainer, time.perf_counter() - t0)
                last_save = time.perf_counter()
            if stopped:
                break
    return {
        "iterations": iterations,
        "steps": done,
        "stopped_early": stopped,
        "resumed_from": start,
        "train_s": time.perf_counter() - t0,
        "final": stats,
        "checkpoint": checkpoint.record if checkpoint else None,
    }


def _wants_stop(trainer) -> bool:
    """The trainer's own early-stopping verdict (trainers without ``should_stop`` never stop early)."""
    should_stop = getattr(trainer, "should_stop", None)
    return bool(should_stop()) if should_stop is not None else False


def __getattr__(name: str):
    """The settings builders' old home (a plugin's config function may import them from here), with
    a warning: they are :mod:`spc3d.specs.build`'s, torch-free."""
    if name in ("build_config", "require_positive", "check_range", "check_shape"):
        import warnings

        from spc3d.specs import build

        warnings.warn(f"spc3d.training.{name} is now spc3d.specs.build.{name}", DeprecationWarning, stacklevel=2)
        return getattr(build, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""The training loop shared by every reconstructor: progress, checkpoints, resume, timing.

A trainer (one per model family, e.g. :class:`spc3d.reconstruct.splatting.SplatTrainer`) offers

    step(it) -> {"loss": float, "psnr": float}   one optimisation step (it is 1-based)
    state() -> dict / load(state)                 everything needed to resume bit-for-bit
    render(cams, i) -> (H, W, 3) sRGB tensor      evaluation render of view i
    capacity() -> dict                            what the model holds now (Gaussians, voxels, ...)

:func:`run` drives it: tqdm with loss and PSNR, an atomic checkpoint every ``checkpoint_every``
iterations (and at the end), and on restart it resumes from the last checkpoint, so an interrupted
Snakemake job that is rerun continues where it stopped.
"""

from __future__ import annotations

import os
import random
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from .. import io
from ..cameras import Cameras


@dataclass
class Views:
    """Training views of one scene: targets (N, H, W, 3) float32 aligned with ``cameras``."""

    targets: Tensor
    cameras: Cameras
    names: list[str]


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def save_checkpoint(path: str | os.PathLike, it: int, trainer, elapsed: float) -> None:
    with io.atomic_path(path) as tmp:
        torch.save({"iteration": it, "state": trainer.state(), "elapsed_s": elapsed,
                    "torch_rng": torch.get_rng_state()}, tmp)


def load_checkpoint(path: str | os.PathLike, trainer) -> tuple[int, float]:
    """Resume ``trainer`` from ``path`` if it exists: (iterations done, training seconds so far)."""
    if not Path(path).is_file():
        return 0, 0.0
    ckpt = torch.load(path, weights_only=False, map_location="cpu")  # our own file (GPU-written too)
    trainer.load(ckpt["state"])
    torch.set_rng_state(ckpt["torch_rng"])
    return int(ckpt["iteration"]), float(ckpt["elapsed_s"])


def run(trainer, iterations: int, checkpoint: str | os.PathLike | None = None, checkpoint_every: int = 1000,
        desc: str = "train", log_every: int = 50) -> dict:
    """Train to ``iterations``; returns timing, final loss/PSNR, capacity and peak memory."""
    start, elapsed = load_checkpoint(checkpoint, trainer) if checkpoint else (0, 0.0)
    t0, stats = time.perf_counter() - elapsed, {}
    bar = tqdm(range(start + 1, iterations + 1), desc=desc, initial=start, total=iterations, mininterval=2.0)
    for it in bar:
        stats = trainer.step(it)
        if it % log_every == 0:
            bar.set_postfix(loss=f"{stats['loss']:.4f}", psnr=f"{stats['psnr']:.2f}", **_short(trainer.capacity()))
        if checkpoint and (it % checkpoint_every == 0 or it == iterations):
            save_checkpoint(checkpoint, it, trainer, time.perf_counter() - t0)
    return {"iterations": iterations, "resumed_from": start, "train_s": time.perf_counter() - t0,
            "final_loss": stats.get("loss"), "final_train_psnr": stats.get("psnr"),
            "capacity": {**trainer.capacity(), "peak_rss_mb": peak_rss_mb()}}


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _short(capacity: dict) -> dict:
    return {k: v for k, v in capacity.items() if isinstance(v, int)}

"""Training a stage-1 model: the loop, linear learning-rate decay, checkpoints, record and curve.

``train_translator`` is the entry point of the workflow's ``train_translator`` rule. It writes
(``results/models/{method}/``, atomically):

    model.pt      the trained networks (every module's state) + method name + resolved Config
    train.json    seed, resolved model and training settings, wall time, parameter counts,
                  peak memory, final losses, resume point
    curve.csv     the losses every ``log_every`` iterations
    curve.png     the training curve (a figure a person would rather look at than the csv)

The schedule follows pix2pix/pix2pixHD (constant lr for the first half, then linear decay to 0:
their "100 + 100 epochs"), expressed in iterations. The checkpoint (optimiser states and the
sampler's RNG included) lives outside the output folder so a killed job resumes when rerun.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import torch
from tqdm import tqdm

from .. import io
from ..reconstruct import build_config
from ..reconstruct.train import peak_rss_mb, seed_everything
from . import TRANSLATORS
from .data import PairSampler, load_pairs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainSettings:
    """How long and on what a stage-1 model trains (the config's ``stage1.train``)."""

    iterations: int = 400  # optimisation steps (paper: 100 + 100 epochs over ~15k pairs)
    batch_size: int = 4  # pairs per step (pix2pix/pix2pixHD: 1)
    crop: int = 64  # random square crop side in pixels (pix2pix: 256 from 286)
    decay_from: float = 0.5  # fraction of the iterations after which lr decays linearly to 0
    checkpoint_every: int = 200  # iterations between checkpoints
    log_every: int = 10  # iterations between curve points

    def __post_init__(self):
        if self.iterations < 0 or self.batch_size < 1 or self.crop < 8:
            raise ValueError(f"stage1.train: need iterations >= 0, batch_size >= 1, crop >= 8; got {self}")
        if not 0.0 <= self.decay_from <= 1.0:
            raise ValueError(f"stage1.train.decay_from={self.decay_from}: must be in [0, 1]")


def lr_scale(it: int, s: TrainSettings) -> float:
    """1 until ``decay_from`` of the run, then linearly down to 0 at the last iteration."""
    start = s.decay_from * s.iterations
    if it <= start or s.iterations == 0:
        return 1.0
    return max(0.0, 1.0 - (it - start) / max(s.iterations - start, 1.0))


def model_config(method: str, settings: dict):
    """The method's Config: ``preset: paper`` starts from the published sizes; other keys override."""
    if method not in TRANSLATORS:
        raise ValueError(f"unknown stage-1 method {method!r}; choose one of {sorted(TRANSLATORS)}")
    module = TRANSLATORS[method]
    settings = dict(settings)
    preset = settings.pop("preset", None)
    settings.pop("checkpoint", None)
    if preset not in (None, "paper"):
        raise ValueError(f"stage1.{method}.preset={preset!r}: use 'paper' or leave it out (CPU default)")
    base = module.Config(**{k: tuple(v) if isinstance(v, list) else v for k, v in module.PAPER.items()}) \
        if preset == "paper" else None
    return build_config(module.Config, settings, f"stage1.{method}", base)


def build_translator(method: str, cfg, device: torch.device, vgg_weights: dict | None = None):
    return TRANSLATORS[method].Translator(cfg, device, vgg_weights=vgg_weights)


def _device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _save_checkpoint(path, it, model, sampler, elapsed, curve) -> None:
    with io.atomic_path(path) as tmp:
        torch.save({"iteration": it, "state": model.state(), "sampler": sampler.state(), "elapsed_s": elapsed,
                    "curve": curve, "torch_rng": torch.get_rng_state()}, tmp)


def _resume(path, model, sampler) -> tuple[int, float, list]:
    if not path or not Path(path).is_file():
        return 0, 0.0, []
    ckpt = torch.load(path, weights_only=False, map_location="cpu")  # our own file
    model.load(ckpt["state"])
    sampler.load(ckpt["sampler"])
    torch.set_rng_state(ckpt["torch_rng"])
    log.info("resuming from %s at iteration %d", path, ckpt["iteration"])
    return int(ckpt["iteration"]), float(ckpt["elapsed_s"]), list(ckpt["curve"])


def fit(model, sampler: PairSampler, s: TrainSettings, checkpoint=None, desc: str = "stage1") -> dict:
    """Run the optimisation to ``s.iterations``; returns timing, curve and final losses."""
    start, elapsed, curve = _resume(checkpoint, model, sampler)
    t0, losses = time.perf_counter() - elapsed, {}
    model.train(True)
    bar = tqdm(range(start + 1, s.iterations + 1), desc=desc, initial=start, total=s.iterations, mininterval=2.0)
    for it in bar:
        model.set_lr_scale(lr_scale(it, s))
        binary, rgb = (x.to(model.device) for x in sampler())
        losses = model.train_step(binary, rgb)
        if it % s.log_every == 0 or it == s.iterations:
            curve.append({"iteration": it, **losses})
            bar.set_postfix({k: f"{v:.4f}" for k, v in losses.items()})
        if checkpoint and (it % s.checkpoint_every == 0 or it == s.iterations):
            _save_checkpoint(checkpoint, it, model, sampler, time.perf_counter() - t0, curve)
    return {"iterations": s.iterations, "resumed_from": start, "train_s": time.perf_counter() - t0,
            "final_losses": losses, "curve": curve}


def train_translator(method: str, augment_dirs: list[str], out_dir: str | os.PathLike, settings: dict,
                     train: dict, seed: int = 0, frames: int = 1, checkpoint: str | os.PathLike | None = None,
                     vgg_weights: dict | None = None, threads: int | None = None) -> dict:
    """Train ``method`` on the augmented pairs of ``augment_dirs``; write ``out_dir`` (see module doc)."""
    if threads:
        torch.set_num_threads(threads)
    seed_everything(seed)
    cfg, s = model_config(method, settings), build_config(TrainSettings, train, "stage1.train")
    model = build_translator(method, cfg, _device(), vgg_weights)
    pretrained = settings.get("checkpoint")
    if pretrained:
        model.load_pretrained(pretrained)
    binary, rgb = load_pairs(augment_dirs, frames)
    sampler = PairSampler(binary, rgb, s.batch_size, s.crop, seed, paired=model.paired)
    if checkpoint:
        Path(checkpoint).parent.mkdir(parents=True, exist_ok=True)
    result = fit(model, sampler, s, checkpoint, desc=method)
    record = {"method": method, "seed": seed, "frames": frames, "pairs": len(binary),
              "augment_dirs": [str(d) for d in augment_dirs], "pretrained": pretrained,
              "settings": dataclasses.asdict(cfg), "train": dataclasses.asdict(s),
              "parameters": model.parameter_count(), "device": str(model.device),
              "peak_rss_mb": peak_rss_mb(), **{k: v for k, v in result.items() if k != "curve"}}
    write_model_folder(out_dir, model, record, result["curve"])
    return record


def write_model_folder(out_dir, model, record: dict, curve: list[dict]) -> None:
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        tmp = Path(tmp)
        tmp.mkdir(parents=True, exist_ok=True)
        torch.save({"method": record["method"], "config": record["settings"],
                    "modules": {k: m.state_dict() for k, m in model.modules().items()}}, tmp / "model.pt")
        io.write_json(tmp / "train.json", record)
        frame = pd.DataFrame(curve)
        io.write_text(tmp / "curve.csv", frame.to_csv(index=False, float_format="%.6g"))
        plot_curve(frame, tmp / "curve.png", record["method"])


def plot_curve(frame: pd.DataFrame, path: Path, title: str) -> None:
    """Every loss against the iteration, one panel per loss (log scale where all positive)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [c for c in frame.columns if c != "iteration"]
    fig, axes = plt.subplots(1, max(len(keys), 1), figsize=(3.2 * max(len(keys), 1), 2.6), squeeze=False)
    for ax, key in zip(axes[0], keys):
        ax.plot(frame["iteration"], frame[key], lw=1.2)
        if (frame[key] > 0).all():
            ax.set_yscale("log")
        ax.set_title(key, fontsize=9)
        ax.set_xlabel("iteration", fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: training losses", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def load_translator(model_dir: str | os.PathLike, device: torch.device | None = None):
    """A trained model from ``model_dir/model.pt``, ready for ``translate`` (no loss networks)."""
    path = Path(model_dir) / "model.pt"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: train the method first (rule train_translator)")
    saved = torch.load(path, weights_only=False, map_location="cpu")  # our own file
    method = saved["method"]
    cfg = build_config(TRANSLATORS[method].Config, saved["config"], f"{path} config")
    if any(f.name == "vgg_loss" for f in dataclasses.fields(cfg)):
        cfg = dataclasses.replace(cfg, vgg_loss=False)  # the perceptual loss is a training-only network
    model = build_translator(method, cfg, device or _device())
    for k, m in model.modules().items():
        m.load_state_dict(saved["modules"][k])
    return method, model


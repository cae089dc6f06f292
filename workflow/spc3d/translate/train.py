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
sampler's RNG included) lives outside the output folder so a killed job resumes when rerun; it is
resumed only when its fingerprint (method, resolved settings, seed, frames, digests of the pairs,
of published weights and of the perceptual-loss network, code) is the job's own
(:mod:`spc3d.training`), otherwise discarded with the reason logged.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import torch

from .. import io
from ..training import (Checkpoint, CheckpointPolicy, build_config, default_device, digest_arrays, digest_path,
                        fingerprint, peak_rss_mb, run, seed_everything)
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
    log_every: int = 10  # iterations between curve points

    def __post_init__(self):
        if self.iterations < 0 or self.batch_size < 1 or self.crop < 8 or self.log_every < 1:
            raise ValueError(f"stage1.train: need iterations >= 0, batch_size >= 1, crop >= 8, log_every >= 1; "
                             f"got {self}")
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


def train_settings(train: dict, method: str, pretrained: str | None = None) -> TrainSettings:
    """``stage1.train`` (with the method's own ``train`` block) as TrainSettings; 0 iterations only
    when the method starts from published weights (an untrained network is not a result)."""
    s = build_config(TrainSettings, train, f"stage1.{method}.train")
    if s.iterations == 0 and not pretrained:
        raise ValueError(f"stage1.train.iterations = 0 for {method}: an untrained network is not a result; use "
                         f"iterations >= 1 (0 only with published weights, stage1.{method}.checkpoint)")
    return s


def check_pretrained(method: str, settings: dict) -> None:
    """Load the published weights of ``settings['checkpoint']`` into the method's network now (safely:
    no pickled code runs), so a corrupt or mismatched file stops the run before any job."""
    cfg = model_config(method, settings)
    build_translator(method, cfg, torch.device("cpu")).load_pretrained(settings["checkpoint"])


def build_translator(method: str, cfg, device: torch.device, vgg_weights: dict | None = None):
    return TRANSLATORS[method].Translator(cfg, device, vgg_weights=vgg_weights)


class TranslatorTrainer:
    """A translator and its pair sampler as a trainer for :func:`spc3d.training.run`.

    Each step sets the learning-rate scale, draws a batch and optimises; every ``log_every``
    steps (and at the last) the losses join ``curve``, which the checkpoint carries.
    """

    def __init__(self, model, sampler: PairSampler, s: TrainSettings):
        self.model, self.sampler, self.s, self.curve = model, sampler, s, []

    def step(self, it: int) -> dict[str, float]:
        self.model.train(True)
        self.model.set_lr_scale(lr_scale(it, self.s))
        binary, rgb = (x.to(self.model.device) for x in self.sampler())
        losses = self.model.train_step(binary, rgb)
        if it % self.s.log_every == 0 or it == self.s.iterations:
            self.curve.append({"iteration": it, **losses})
        return losses

    def state(self) -> dict:
        return {"model": self.model.state(), "sampler": self.sampler.state(), "curve": self.curve}

    def load(self, state: dict) -> None:
        self.model.load(state["model"])
        self.sampler.load(state["sampler"])
        self.curve = list(state["curve"])


def fit(model, sampler: PairSampler, s: TrainSettings, checkpoint: Checkpoint | None = None,
        policy: CheckpointPolicy = CheckpointPolicy(), desc: str = "stage1") -> dict:
    """Run the optimisation to ``s.iterations``; returns timing, curve and final losses."""
    trainer = TranslatorTrainer(model, sampler, s)
    if s.iterations == 0:  # published weights used as they are (setup_training allows nothing else)
        return {"iterations": 0, "resumed_from": 0, "train_s": 0.0, "checkpoint": None, "final_losses": {},
                "curve": []}
    result = run(trainer, s.iterations, checkpoint, policy, desc=desc, log_every=s.log_every)
    return {**{k: v for k, v in result.items() if k != "final"}, "final_losses": result["final"],
            "curve": trainer.curve}


@dataclass
class TrainingJob:
    """Everything a stage-1 training needs, built from the rule's arguments (see :func:`setup_training`)."""

    model: object  # the Translator
    sampler: PairSampler
    settings: TrainSettings
    checkpoint: Checkpoint | None
    meta: dict  # method, seed, frames, resolved model and training settings (the fingerprint's settings)
    pairs: int


def setup_training(method: str, augment_dirs: list[str], settings: dict, train: dict, seed: int = 0,
                   frames: int = 1, checkpoint: str | os.PathLike | None = None,
                   vgg_weights: dict | None = None, input_digests: dict | None = None) -> TrainingJob:
    """Seed, build the model and its pair sampler, and the checkpoint with this job's fingerprint
    (``input_digests``, when given, identifies the pairs instead of digests of their folders)."""
    seed_everything(seed)
    pretrained = settings.get("checkpoint")
    cfg, s = model_config(method, settings), train_settings(train, method, pretrained)
    model = build_translator(method, cfg, default_device(), vgg_weights)
    if pretrained:
        model.load_pretrained(pretrained)
    binary, rgb = load_pairs(augment_dirs, frames)
    sampler = PairSampler(binary, rgb, s.batch_size, s.crop, seed, paired=model.paired)
    meta = {"method": method, "seed": seed, "frames": frames, "settings": dataclasses.asdict(cfg),
            "train": dataclasses.asdict(s), "pretrained": pretrained}
    inputs = input_digests or {f"pairs[{i}]": digest_path(d) for i, d in enumerate(augment_dirs)}
    ckpt = Checkpoint(checkpoint, fingerprint("train_translator", meta, inputs | {
        "pretrained": digest_path(pretrained), "vgg": digest_arrays(vgg_weights)})) if checkpoint else None
    return TrainingJob(model, sampler, s, ckpt, meta, len(binary))


def train_translator(method: str, augment_dirs: list[str], out_dir: str | os.PathLike, settings: dict,
                     train: dict, seed: int = 0, frames: int = 1, checkpoint: str | os.PathLike | None = None,
                     vgg_weights: dict | None = None, threads: int | None = None,
                     policy: CheckpointPolicy = CheckpointPolicy(), input_digests: dict | None = None) -> dict:
    """Train ``method`` on the augmented pairs of ``augment_dirs``; write ``out_dir`` (see module doc).
    ``input_digests``: see :func:`spc3d.stage2.reconstruct` (a sweep point rebuilds its pairs)."""
    if threads:
        torch.set_num_threads(threads)
    job = setup_training(method, augment_dirs, settings, train, seed, frames, checkpoint, vgg_weights, input_digests)
    result = fit(job.model, job.sampler, job.settings, job.checkpoint, policy, desc=method)
    record = {**job.meta, "pairs": job.pairs, "augment_dirs": [str(d) for d in augment_dirs],
              "parameters": job.model.parameter_count(), "device": str(job.model.device),
              "peak_rss_mb": peak_rss_mb(), **{k: v for k, v in result.items() if k != "curve"}}
    write_model_folder(out_dir, job.model, record, result["curve"])
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
    saved = io.load_torch(path, "trained stage-1 model")
    method = saved["method"]
    cfg = build_config(TRANSLATORS[method].Config, saved["config"], f"{path} config")
    if any(f.name == "vgg_loss" for f in dataclasses.fields(cfg)):
        cfg = dataclasses.replace(cfg, vgg_loss=False)  # the perceptual loss is a training-only network
    model = build_translator(method, cfg, device or default_device())
    for k, m in model.modules().items():
        m.load_state_dict(saved["modules"][k])
    return method, model


"""Training a stage-1 model: the loop, linear learning-rate decay, validation, checkpoints and the record.

``train_translator`` is the entry point of the workflow's ``train_translator`` rule; the rule's
adapter describes the job once, as a :class:`TranslatorJob` (method, data, settings, seed, frames,
validation, checkpoint, output folder), and passes it here. It trains on ``stage1.data``:
``fixed`` cycles over the augmented pairs (:mod:`.data`), ``online`` draws every batch fresh from
the training scenes (:mod:`.online`); with ``stage1.validation`` it validates on the training
scenes' held-out views, keeps the best model and stops early (:mod:`.validate`). It writes
(``results/models/{method}/``, atomically, with :func:`.model_io.write_model_folder`):

    model.pt      the kept networks (every module's state: the best validated step, else the last)
                  + method name + resolved Config
    train.json    seed, resolved model, training and validation settings, the data (mode, samples
                  drawn, distinct samples), the validation curve, best step, stop step and reason
                  (``patience`` / ``budget``), wall time, parameter counts, peak memory, final
                  losses, resume point; ``selection``: what the model's ``fit_untrained`` returned
                  (``classical``: every candidate denoiser's score and time, and the one chosen)
    curve.csv     the losses every ``log_every`` iterations and the validation PSNR / L1
    curve.png     the training curve (a figure a person would rather look at than the csv; :mod:`.curves`)

The schedule follows pix2pix/pix2pixHD (constant lr for the first half, then linear decay to 0:
their "100 + 100 epochs"), expressed in iterations. The checkpoint (optimiser states, the
sampler's RNG and the validation state included) lives outside the output folder so a killed job
resumes when rerun; it is resumed only when its fingerprint (method, resolved settings, seed,
frames, data mode, digests of the pairs or scene and SPC folders, of published weights and of the
perceptual-loss network, code) is the job's own (:mod:`spc3d.checkpoints`), otherwise discarded with
the reason logged.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from spc3d.checkpoints import Checkpoint, CheckpointPolicy, digest_arrays, digest_path, fingerprint
from spc3d.specs.build import build_config
from spc3d.specs.translators import (
    AugmentSettings,
    TrainSettings,
    data_mode,
    model_config,
    train_settings,
    validation_settings,
)
from spc3d.training import default_device, peak_rss_mb, run, seed_everything
from spc3d.translate.data import PairSampler, load_pairs
from spc3d.translate.model_io import build_translator, write_model_folder
from spc3d.translate.online import OnlineSampler, load_sources
from spc3d.translate.validate import Validator, load_views

log = logging.getLogger(__name__)


def lr_scale(it: int, s: TrainSettings) -> float:
    """1 until ``decay_from`` of the run, then linearly down to 0 at the last iteration."""
    start = s.decay_from * s.iterations
    if it <= start or s.iterations == 0:
        return 1.0
    return max(0.0, 1.0 - (it - start) / max(s.iterations - start, 1.0))


class TranslatorTrainer:
    """A translator and its sampler (fixed pairs or online samples) as a trainer for
    :func:`spc3d.training.run`.

    Each step sets the learning-rate scale, draws a batch and optimises; every ``log_every``
    steps (and at the last) the losses join ``curve``, which the checkpoint carries. With a
    ``validator`` it validates when due (:mod:`.validate`) and asks the loop to stop once
    validation has not improved for the configured patience.
    """

    def __init__(self, model, sampler, s: TrainSettings, validator: Validator | None = None):
        self.model, self.sampler, self.s, self.validator, self.curve = model, sampler, s, validator, []

    def step(self, it: int) -> dict[str, float]:
        if self.validator and not self.validator.history:  # the untrained start: kept until a step beats it
            self.validator.update(0, self.model)
        self.model.train(True)
        self.model.set_lr_scale(lr_scale(it, self.s))
        binary, rgb = (x.to(self.model.device) for x in self.sampler())
        if self.model.prior is not None:
            rgb = self.model.prior.relevel(binary, rgb)  # the brightness is the prior's (translate/prior.py)
        losses = self.model.train_step(binary, rgb)
        if it % self.s.log_every == 0 or it == self.s.iterations:
            self.curve.append({"iteration": it, **losses})
        if self.validator and self.validator.due(it):
            scores = self.validator.update(it, self.model)
            if self.should_stop() and self.curve[-1]["iteration"] != it:
                self.curve.append({"iteration": it, **losses})  # the loss curve ends where training stopped
            return losses | scores
        return losses

    def should_stop(self) -> bool:
        """Validation has not improved for ``patience`` validations (never without a validator)."""
        return self.validator is not None and self.validator.should_stop()

    def state(self) -> dict:
        return {
            "model": self.model.state(),
            "sampler": self.sampler.state(),
            "curve": self.curve,
            "validation": self.validator.state() if self.validator else None,
        }

    def load(self, state: dict) -> None:
        self.model.load(state["model"])
        self.sampler.load(state["sampler"])
        self.curve = list(state["curve"])
        if self.validator:
            self.validator.load(state["validation"])


def fit(
    model,
    sampler,
    s: TrainSettings,
    checkpoint: Checkpoint | None = None,
    policy: CheckpointPolicy = CheckpointPolicy(),
    desc: str = "stage1",
    validator: Validator | None = None,
) -> dict:
    """Run the optimisation to ``s.iterations`` (or an early stop); returns timing, curve, final losses,
    the step it stopped at and why (``patience`` / ``budget``)."""
    trainer = TranslatorTrainer(model, sampler, s, validator)
    if s.iterations == 0:  # published weights used as they are, or a method without a network
        if validator:
            validator.update(0, model)  # their score on the held-out views, for the record
        return {
            "iterations": 0,
            "resumed_from": 0,
            "train_s": 0.0,
            "checkpoint": None,
            "final_losses": {},
            "curve": [],
            "stopped": {"step": 0, "of": 0, "reason": "budget"},
        }
    result = run(trainer, s.iterations, checkpoint, policy, desc=desc, log_every=s.log_every)
    reason = "patience" if result["stopped_early"] else "budget"  # validation stopped improving, or the maximum
    stopped = {"step": result["steps"], "of": s.iterations, "reason": reason}
    final = {k: v for k, v in trainer.curve[-1].items() if k != "iteration"}  # also when resumed at the end
    return {
        **{k: v for k, v in result.items() if k not in ("final", "steps", "stopped_early")},
        "final_losses": final,
        "curve": trainer.curve,
        "stopped": stopped,
    }


@dataclass(frozen=True)
class TrainingData:
    """Where a translator's training and validation data come from (the rule's inputs)."""

    mode: str = "fixed"  # stage1.data: fixed (augment_dirs) | online (fresh samples of scene_dirs + spc_dirs)
    augment_dirs: tuple = ()  # results/augment/{scene}{rep} of the training scenes (fixed)
    scene_dirs: tuple = ()  # results/scenes/{scene} of the training scenes (online; validation views)
    spc_dirs: tuple = ()  # their results/spc/{scene}{rep} (online: exposure and physics; validation input)
    augment: AugmentSettings = AugmentSettings()  # the online samples' augmentation ranges (the augment block)
    sensor: dict | None = None  # the sensor the inputs are recorded by ({"cfa", "white"}); None: the simulator's RGB

    def __post_init__(self):
        data_mode(self.mode)
        if self.mode == "fixed" and not self.augment_dirs:
            raise ValueError("stage1.data = 'fixed' needs the augmented pairs (results/augment/{scene} folders)")
        if len(self.scene_dirs) != len(self.spc_dirs):
            raise ValueError(f"{len(self.scene_dirs)} training scene folder(s) but {len(self.spc_dirs)} SPC folder(s)")
        if self.mode == "online" and not self.scene_dirs:
            raise ValueError("stage1.data = 'online' needs the training scenes' folders and their SPC folders")

    def digests(self) -> dict[str, str | None]:
        folders = {
            "pairs": self.augment_dirs if self.mode == "fixed" else (),
            "scenes": self.scene_dirs,
            "spc": self.spc_dirs,
        }
        return {f"{k}[{i}]": digest_path(d) for k, dirs in folders.items() for i, d in enumerate(dirs)}

    def hold_out(self, n: int) -> tuple[TrainingData, tuple, tuple]:
        """(this data without its last ``n`` scenes, their scene folders, their SPC folders): the
        scenes ``stage1.validation.hold_out`` keeps out of the training to validate on. The rule
        lists pairs, scenes and SPC folders in the same scene order."""
        if n == 0:
            return self, self.scene_dirs, self.spc_dirs
        scenes = [Path(d).name for d in self.scene_dirs]
        if n >= len(scenes):
            raise ValueError(
                f"stage1.validation.hold_out = {n} keeps every training scene out of the training "
                f"(the fold has {len(scenes)}: {', '.join(scenes) or 'none'}); it must be below that"
            )
        if self.mode == "fixed" and len(self.augment_dirs) != len(scenes):
            raise ValueError(
                f"stage1.validation.hold_out needs one pairs folder per training scene, got "
                f"{len(self.augment_dirs)} for {len(scenes)} scenes"
            )
        kept = dataclasses.replace(
            self,
            augment_dirs=self.augment_dirs[:-n] if self.mode == "fixed" else self.augment_dirs,
            scene_dirs=self.scene_dirs[:-n],
            spc_dirs=self.spc_dirs[:-n],
        )
        return kept, self.scene_dirs[-n:], self.spc_dirs[-n:]


def training_data(
    mode: str = "fixed",
    augment_dirs=(),
    scene_dirs=(),
    spc_dirs=(),
    augment: dict | None = None,
    sensor: dict | None = None,
) -> TrainingData:
    """TrainingData from the rule's values (``augment``: the config's augment block, ``count``
    ignored; ``sensor``: a capture's sensor, :func:`spc3d.captures.importing.capture_sensor`)."""
    ranges = {k: v for k, v in (augment or {}).items() if k != "count"}
    return TrainingData(
        mode,
        tuple(map(str, augment_dirs)),
        tuple(map(str, scene_dirs)),
        tuple(map(str, spc_dirs)),
        build_config(AugmentSettings, ranges, "augment"),
        sensor,
    )


def make_sampler(data: TrainingData, s: TrainSettings, frames: int, seed: int, paired: bool):
    """The fixed pairs' :class:`PairSampler` or an :class:`OnlineSampler` of the training scenes."""
    if data.mode == "online":
        sources = load_sources(list(data.scene_dirs), list(data.spc_dirs), frames)
        return OnlineSampler(sources, s.batch_size, s.crop, seed, data.augment, paired=paired, sensor=data.sensor)
    binary, rgb = load_pairs(list(data.augment_dirs), frames, data.sensor)
    return PairSampler(binary, rgb, s.batch_size, s.crop, seed, paired=paired)


def make_validator(data: TrainingData, validation: dict | None, frames: int, iterations: int) -> Validator | None:
    """The validator of ``stage1.validation`` (None when ``every`` is 0 or ``validation`` None):
    the held-out views of ``data``'s scenes, or every view of its ``hold_out`` scenes."""
    v = validation_settings(validation)
    if v.every == 0:
        return None
    if not data.scene_dirs:
        raise ValueError(
            f"stage1.validation.every = {v.every} needs the training scenes' folders and SPC folders "
            "(their held-out views); set stage1.validation.every: 0 to train without validation"
        )
    _, scene_dirs, spc_dirs = data.hold_out(v.hold_out)
    views = load_views(list(scene_dirs), list(spc_dirs), frames, data.sensor, every_view=v.hold_out > 0)
    return Validator(views, v, iterations)


@dataclass(frozen=True)
class TranslatorJob:
    """One stage-1 training as the ``train_translator`` rule describes it: what to train, on which
    data, how, and where its model and checkpoint go.

    Built once by the rule's adapter (``workflow/scripts/train_translator.py``) and read by
    :func:`setup_training` and :func:`train_translator`, so the two cannot disagree about a job.
    It holds the settings as the config gives them; :func:`setup_training` resolves them (model
    Config, TrainSettings, validation settings) into ``meta``, which is both train.json's
    description of the job and the checkpoint's fingerprint. The perceptual loss's VGG weights are
    not part of the description (big arrays, not settings): they travel beside the job and are
    fingerprinted by their digest.
    """

    method: str  # the stage-1 method (spc3d.translate.MODULES)
    data: TrainingData  # where training samples and validation views come from (training_data())
    out_dir: str | os.PathLike  # results/models/{method}: model.pt, train.json, curve.csv, curve.png
    settings: dict  # stage1.{method}: the model's settings (checkpoint: published weights to start from)
    train: dict  # stage1.train with the method's own train block
    seed: int = 0
    frames: int = 1  # SPC frames per binary input
    validation: dict | None = None  # stage1.validation (None: no validation)
    checkpoint: str | os.PathLike | None = None  # the resumable checkpoint's file (None: no checkpoint)
    policy: CheckpointPolicy = CheckpointPolicy()  # when the checkpoint is saved
    threads: int | None = None  # torch threads (None: leave torch's setting)

    def __post_init__(self):
        if not isinstance(self.data, TrainingData):
            raise TypeError(
                f"TranslatorJob.data must be a TrainingData (see training_data()), got {type(self.data).__name__}"
            )


@dataclass
class TrainingSetup:
    """A :class:`TranslatorJob` made ready to train (see :func:`setup_training`): its model,
    sampler, validator and checkpoint, and ``meta``, the job with its settings resolved."""

    model: object  # the Translator
    sampler: PairSampler | OnlineSampler
    settings: TrainSettings
    checkpoint: Checkpoint | None
    meta: dict  # method, seed, frames, data, resolved model, training and validation settings (fingerprinted)
    pairs: int | None  # fixed pairs (None online)
    validator: Validator | None = None
    selection: dict | None = None  # what the model's fit_untrained returned (classical: its selection table)
    trained_on: TrainingData | None = None  # the data without the scenes validation holds out


def setup_training(job: TranslatorJob, vgg_weights: dict | None = None) -> TrainingSetup:
    """Seed, build the model, its sampler and validator, and the checkpoint with this job's fingerprint.

    ``vgg_weights``: the perceptual-loss network's weights (methods that use one), fingerprinted by
    digest. The checkpoint's inputs are digests of the data's folders. Separate from
    :func:`train_translator` so a test can drive the training loop itself."""
    seed_everything(job.seed)
    data = job.data
    pretrained = job.settings.get("checkpoint")
    cfg, s = model_config(job.method, job.settings, job.frames), train_settings(job.train, job.method, pretrained)
    model = build_translator(job.method, cfg, default_device(), vgg_weights)
    if not model.trainable:
        s = dataclasses.replace(s, iterations=0)  # an untrained method: its fit_untrained is all there is
    if pretrained:
        model.load_pretrained(pretrained)
    validator = make_validator(data, job.validation, job.frames, s.iterations)
    trained_on = data.hold_out(validator.s.hold_out)[0] if validator else data
    sampler = make_sampler(trained_on, s, job.frames, job.seed, model.paired)
    validate = validator.score if validator else None
    # the prior's gain on the training data (restored as it is on resume); an untrained method's whole fit
    selection = model.fit_untrained(sampler.calibration_pairs, validate)
    meta = {
        "method": job.method,
        "seed": job.seed,
        "frames": job.frames,
        "settings": dataclasses.asdict(cfg),
        "train": dataclasses.asdict(s),
        "pretrained": pretrained,
        "data": data.mode,
        "augment": dataclasses.asdict(data.augment) if data.mode == "online" else None,
        "sensor": data.sensor,
        "validation": dataclasses.asdict(validator.s) if validator else None,
    }
    inputs = data.digests()
    ckpt = (
        Checkpoint(
            job.checkpoint,
            fingerprint(
                "train_translator",
                meta,
                inputs | {"pretrained": digest_path(pretrained), "vgg": digest_arrays(vgg_weights)},
            ),
        )
        if job.checkpoint
        else None
    )
    pairs = len(sampler.binary) if isinstance(sampler, PairSampler) else None
    return TrainingSetup(model, sampler, s, ckpt, meta, pairs, validator, selection, trained_on)


def prior_record(model, validator: Validator | None) -> dict | None:
    """For train.json: the physics prior's blur and fitted gain, and its own validation score (what
    the network's residual starts from and has to beat); None without a prior."""
    if model.prior is None:
        return None
    prior = model.prior
    scores = validator.score(lambda b: prior(b.to(prior.gain.device)).clamp(0.0, 1.0)) if validator else {}
    return {"sigma": prior.sigma, "gain": prior.gain.tolist(), **scores}


def train_translator(job: TranslatorJob, vgg_weights: dict | None = None) -> dict:
    """Train ``job.method`` on ``job.data``, validating per ``job.validation``; write ``job.out_dir``
    (see module doc) and return its train.json record. ``vgg_weights``: see :func:`setup_training`."""
    if job.threads:
        torch.set_num_threads(job.threads)
    setup = setup_training(job, vgg_weights)
    result = fit(
        setup.model,
        setup.sampler,
        setup.settings,
        setup.checkpoint,
        job.policy,
        desc=job.method,
        validator=setup.validator,
    )
    best = setup.validator.best_modules() if setup.validator else None
    record = {
        **setup.meta,
        "prior": prior_record(setup.model, setup.validator),
        "selection": setup.selection,
        "pairs": setup.pairs,
        "augment_dirs": list(setup.trained_on.augment_dirs),
        "training_scenes": [Path(d).name for d in setup.trained_on.scene_dirs] or None,
        "data": setup.sampler.describe(),
        "validation": setup.validator.record() if setup.validator else None,
        "model_step": setup.validator.best["step"] if best else result["stopped"]["step"],
        "parameters": setup.model.parameter_count(),
        "device": str(setup.model.device),
        "peak_rss_mb": peak_rss_mb(),
        **{k: v for k, v in result.items() if k != "curve"},
    }
    write_model_folder(job.out_dir, setup.model, record, result["curve"], best)
    return record

"""The settings of stage 1, torch-free: each built-in translator's settings dataclass and published
sizes in a file of its own (``spc3d.specs.translators.<method>``: ``Config``, the CPU-budget
defaults, and ``PAPER``, the sizes of the paper or of the method's reference implementation for
``preset: paper``), and here :func:`model_config` and the settings every translator shares
(``augment``, ``stage1.data``, ``stage1.train``, ``stage1.validation``).

The model modules of :mod:`spc3d.translate` import their ``Config`` and ``PAPER`` from their file;
the settings live apart from them so that the workflow builds and checks every job's settings when
it parses the configuration, without importing torch (``spc3d.config``), and one file a model so
that a change to one model's defaults reruns that model's training alone (a job's code key covers
the modules it imports, :mod:`spc3d.provenance`). The augmentation (:mod:`spc3d.inputs.augment`),
the training loop (:mod:`spc3d.translate.train`) and its validator (:mod:`spc3d.translate.validate`)
run with the shared settings.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from spc3d import specs
from spc3d.specs.build import build_config


def model_config(method: str, settings: dict, frames: int | None = None):
    """The method's Config: ``preset: paper`` starts from the published sizes; other keys override.
    A Config with a ``frames`` field (a method that must know K: ``classical``) takes ``frames``, the
    job's stage1.frames (a sweep point's K), never its own settings block's: one K per run."""
    if method not in specs.TRANSLATORS:
        raise ValueError(f"unknown stage-1 method {method!r}; choose one of {sorted(specs.TRANSLATORS)}")
    config, paper = specs.settings_classes(method)
    settings = dict(settings)
    preset = settings.pop("preset", None)
    settings.pop("checkpoint", None)
    if preset not in (None, "paper"):
        raise ValueError(f"stage1.{method}.preset={preset!r}: use 'paper' or leave it out (CPU default)")
    has_frames = any(f.name == "frames" for f in dataclasses.fields(config))
    if has_frames and "frames" in settings:
        raise ValueError(
            f"stage1.{method}.frames: the frames per input are stage1.frames for every method; set K there"
        )
    if has_frames and frames is not None:
        settings["frames"] = frames
    base = (
        config(**{k: tuple(v) if isinstance(v, list) else v for k, v in paper.items()}) if preset == "paper" else None
    )
    return build_config(config, settings, f"stage1.{method}", base)


# --- training data, training and validation (every translator) ------------------------------------


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
            raise ValueError(
                f"stage1.train: need iterations >= 0, batch_size >= 1, crop >= 8, log_every >= 1; got {self}"
            )
        if not 0.0 <= self.decay_from <= 1.0:
            raise ValueError(f"stage1.train.decay_from={self.decay_from}: must be in [0, 1]")


def train_settings(train: dict, method: str, pretrained: str | None = None) -> TrainSettings:
    """``stage1.train`` (with the method's own ``train`` block) as TrainSettings; 0 iterations only
    when the method starts from published weights (an untrained network is not a result)."""
    s = build_config(TrainSettings, train, f"stage1.{method}.train")
    if s.iterations == 0 and not pretrained:
        raise ValueError(
            f"stage1.train.iterations = 0 for {method}: an untrained network is not a result; use "
            f"iterations >= 1 (0 only with published weights, stage1.{method}.checkpoint)"
        )
    return s


DATA_MODES = ("fixed", "online")


def data_mode(mode: str) -> str:
    """``stage1.data``, checked."""
    if mode not in DATA_MODES:
        raise ValueError(
            f"stage1.data = {mode!r}: use one of {list(DATA_MODES)} (fixed: the augmented pairs of "
            f"results/augment; online: fresh augmentations and SPC photons every step)"
        )
    return mode


@dataclass(frozen=True)
class ValidationSettings:
    """When a translator is validated and when it stops (the config's ``stage1.validation``)."""

    # every and patience: config.yaml's stage1.validation (their home; tests/test_defaults.py checks they agree)
    every: int = 50  # steps between validations, plus one at the last step (0: none, the last model is kept)
    patience: int = 4  # validations without a better PSNR before training stops (0: never stop early)
    hold_out: int = 0  # the last N training scenes: not trained on, every view validated (0: held-out views)

    def __post_init__(self):
        if min(self.every, self.patience, self.hold_out) < 0:
            raise ValueError(
                f"need every, patience and hold_out >= 0, got every = {self.every}, patience = {self.patience}, "
                f"hold_out = {self.hold_out}"
            )


def validation_settings(values: dict | None, where: str = "stage1.validation") -> ValidationSettings:
    """``stage1.validation`` (with a method's own block) as ValidationSettings; None: no validation."""
    if values is None:
        return ValidationSettings(every=0)
    return build_config(ValidationSettings, dict(values), where)


@dataclass(frozen=True)
class AugmentSettings:
    """Ranges of the random affine maps."""

    zoom: tuple[float, float] = (0.8, 1.25)  # zoom factor range, sampled log-uniformly
    rotation_deg: float = 15.0  # max |rotation|
    shear_deg: float = 10.0  # max |shear|
    flip_prob: float = 0.5  # probability of a horizontal flip

    def __post_init__(self):
        lo, hi = self.zoom
        if not 0 < lo <= hi:
            raise ValueError(f"augment.zoom={list(self.zoom)}: need 0 < min <= max")
        if not 0 <= self.flip_prob <= 1:
            raise ValueError(f"augment.flip_prob={self.flip_prob}: must be in [0, 1]")
        if self.rotation_deg < 0 or self.shear_deg < 0:
            raise ValueError("augment.rotation_deg and augment.shear_deg must be >= 0")


def split_count(total: int, n_scenes: int, index: int) -> int:
    """Samples for scene ``index`` of ``n_scenes`` when ``total`` are split as evenly as possible."""
    return total // n_scenes + (1 if index < total % n_scenes else 0)

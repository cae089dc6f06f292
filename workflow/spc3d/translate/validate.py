"""Validation while a translator trains: a held-out slice of the training scenes, the best model,
early stopping (``stage1.validation``).

The slice is the held-out views (every 8th, :func:`spc3d.cameras.split_views`) of the *training*
scenes, never an evaluation scene. Neither the fixed pairs (:mod:`spc3d.inputs.augment` draws training
views only) nor the online samples (:mod:`.online`, likewise) ever show them. Those views share
their scenes' content with the training data, so they measure fitting; ``hold_out: N`` measures
generalisation instead: the last N training scenes (in configured order) are kept out of the
training altogether and every one of their views is validated (per scene too, ``val_psnr:{scene}``). Their input is the
first ``frames`` stored frames of the scene's SPC folder (a seeded sample, fixed for the run),
translated exactly as an evaluation scene is (:func:`.apply.translate_scene`).

Every ``every`` steps and at the last one the model translates the slice; the mean PSNR over
views (as stage-1 scores average) and the mean L1 error join the history. The model with the
best PSNR so far is kept (a copy of every module's weights); after ``patience`` validations
without a better PSNR the training stops (:func:`spc3d.training.run` asks ``should_stop``). All
of it (history, best weights, the count since the best) is checkpoint state, so a resumed run
stops at the same step with the same best model.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.evaluation.metrics import psnr
from spc3d.physics.record import camera_exposure, read_spc_record
from spc3d.specs.translators import ValidationSettings
from spc3d.translate.camera import from_camera
from spc3d.translate.data import binary_input, chw, sensor_draws, sensor_pattern


@dataclass
class ValidationView:
    name: str  # scene/view
    binary: Tensor  # (3, H, W) K-frame mean of its stored SPC frames
    rgb: Tensor  # (3, H, W) ground truth sRGB
    exposure: float  # photons per frame at linear 1 its camera reports: a translation's display (.camera)


def load_views(
    scene_dirs: list[str | os.PathLike],
    spc_dirs: list[str | os.PathLike],
    frames: int,
    sensor: dict | None = None,
    every_view: bool = False,
) -> list[ValidationView]:
    """The held-out views of the training scenes (``every_view``: all their views, for scenes kept
    out of the training) with their stored binary input (as ``sensor`` records it,
    :func:`.data.binary_input`: its W / mono pixels drawn from the view at the scene's exposure,
    seeded by the view)."""
    views, pattern = [], sensor_pattern(sensor)
    for scene_dir, spc_dir in zip(map(Path, scene_dirs), map(Path, spc_dirs)):
        names = llff.read_scene(scene_dir, with_images=False).names
        record = read_spc_record(spc_dir)
        exposure = camera_exposure(record, f"{spc_dir / 'spc.json'}")
        for i in range(len(names)) if every_view else split_views(len(names))[1]:
            name = names[i]
            rgb = io.read_rgb(scene_dir / "images" / f"{name}.png")
            drawn = {}
            if pattern is not None:
                stream, seed = f"{scene_dir.name}/sensor-validation", record.get("seed") or 0
                drawn = sensor_draws(rgb, record["flux_scale"], record["params"], seed, stream, int(i))
            binary = binary_input(spc_dir / "frames" / f"{name}.npz", frames, pattern, **drawn)
            views.append(ValidationView(f"{scene_dir.name}/{name}", chw(binary), chw(rgb), exposure))
    return views


def score(
    translate: Callable[[Tensor], Tensor], views: list[ValidationView], per_scene: bool = False
) -> dict[str, float]:
    """Mean PSNR (dB) and L1 error of ``translate`` ((B, 3, H, W) binary -> camera image in [0, 1],
    e.g. a model's ``translate``) on ``views`` (views of one size batched), each output displayed
    at its view's exposure (:func:`.camera.from_camera`) and compared with the ground truth, as an
    evaluation scene's translation is scored. ``per_scene``: also each scene's mean PSNR
    (``val_psnr:{scene}``), when the views span more than one scene."""
    psnrs, l1s = {}, {}
    for size in dict.fromkeys(tuple(v.binary.shape) for v in views):
        group = [v for v in views if tuple(v.binary.shape) == size]
        camera = translate(torch.stack([v.binary for v in group])).cpu()
        out = from_camera(camera, torch.tensor([v.exposure for v in group], dtype=torch.float64))
        for pred, v in zip(out, group):
            psnrs[v.name] = psnr(pred, v.rgb)
            l1s[v.name] = float((pred - v.rgb).abs().mean())
    scores = {"val_psnr": sum(psnrs.values()) / len(psnrs), "val_l1": sum(l1s.values()) / len(l1s)}
    by_scene: dict[str, list[float]] = {}
    for name, value in psnrs.items() if per_scene else ():
        by_scene.setdefault(name.split("/")[0], []).append(value)
    if len(by_scene) > 1:
        scores |= {f"val_psnr:{scene}": sum(v) / len(v) for scene, v in by_scene.items()}
    return scores


class Validator:
    """The validation history, the best model so far and the early-stopping count of one training."""

    def __init__(self, views: list[ValidationView], s: ValidationSettings, iterations: int):
        if s.every and not views:
            raise ValueError(
                "stage1.validation: no views to validate on (every 8th view of each training scene, or "
                "every view of the hold_out scenes); set stage1.validation.every: 0 to train without validation"
            )
        self.views, self.s, self.iterations = views, s, iterations
        self.history: list[dict] = []
        self.best: dict | None = None  # {"step", "val_psnr", "modules"}
        self.since_best = 0  # validations since the best one

    def due(self, it: int) -> bool:
        return self.s.every > 0 and (it % self.s.every == 0 or it == self.iterations)

    def score(self, translate: Callable[[Tensor], Tensor]) -> dict[str, float]:
        """:func:`score` on this validation's views (per scene when they are held-out scenes)."""
        return score(translate, self.views, per_scene=self.s.hold_out > 0)

    def update(self, it: int, model) -> dict[str, float]:
        """Validate the model at step ``it``; keep it if it is the best so far."""
        scores = self.score(model.translate)
        self.history.append({"iteration": it, **scores})
        if self.best is None or scores["val_psnr"] > self.best["val_psnr"]:
            modules = {
                k: {n: t.detach().cpu().clone() for n, t in m.state_dict().items()} for k, m in model.modules().items()
            }
            self.best, self.since_best = {"step": it, "val_psnr": scores["val_psnr"], "modules": modules}, 0
        else:
            self.since_best += 1
        return scores

    def should_stop(self) -> bool:
        return self.s.patience > 0 and self.since_best >= self.s.patience

    def best_modules(self) -> dict | None:
        """Every module's weights at the best validation (None before any)."""
        return self.best["modules"] if self.best else None

    def record(self) -> dict:
        """For train.json: settings, views, the best step and PSNR, and the validation curve."""
        best = self.best or {"step": None, "val_psnr": math.nan}
        return {
            "every": self.s.every,
            "patience": self.s.patience,
            "hold_out": self.s.hold_out,
            "views": [v.name for v in self.views],
            "best_step": best["step"],
            "best_psnr": best["val_psnr"],
            "evaluations": len(self.history),
            "curve": list(self.history),
        }

    def state(self) -> dict:
        return {"history": list(self.history), "best": self.best, "since_best": self.since_best}

    def load(self, state: dict) -> None:
        self.history, self.best, self.since_best = list(state["history"]), state["best"], int(state["since_best"])

"""Applying a trained stage-1 model to a scene.

``translate_scene`` (rule ``translate_scene``) turns every view's binary input of a scene (the mean
of its first K SPC frames, K = 1 by default) into a camera image with a trained model and shows it
at the exposure the scene's camera reports (:mod:`.camera`: a dark scene displays dark), then
writes ``results/translate/{scene}/{method}/`` (atomically):

    images/{view}.png   one image per view, named like the scene's views (stage 2's source)
    prior/{view}.png    with a physics prior (:mod:`.prior`): the prior alone, what the network's
                        residual was added to (scored beside the translation, never a stage-2 source)
    translate.json      method, model folder, frames, self-ensemble size, per-image inference time,
                        the prior's settings, the exposure it was displayed at

``ensemble`` (``stage1.ensemble``) averages the model's outputs over flips of the input, each
flipped back (:func:`self_ensemble`; the geometric self-ensemble of EDSR, Lim et al. 2017): 1 = one
pass, 2 = with the horizontal mirror, 4 = with both mirrors. It is the inference-time
estimate of the posterior mean: the error of a single pass is partly specific to the orientation
of the noise, and the diffusion stand-in's one sample is one draw of many. On the training scenes'
held-out views (never an evaluation scene) 4 beat 1 for four of the five
methods (docs/stage1.md). Validation while training scores single passes (:mod:`.validate`).
Its images are scored before 3D by :func:`spc3d.evaluation.stage1.score_images`.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from spc3d import io, llff
from spc3d.physics.record import camera_exposure, read_spc_record
from spc3d.translate.camera import from_camera
from spc3d.translate.data import binary_input
from spc3d.translate.model_io import load_translator

log = logging.getLogger(__name__)


ENSEMBLE_FLIPS: dict[int, tuple[tuple[int, ...], ...]] = {1: ((),), 2: ((), (-1,)), 4: ((), (-1,), (-2,), (-2, -1))}


def check_ensemble(size: int) -> None:
    if size not in ENSEMBLE_FLIPS:
        raise ValueError(f"stage1.ensemble must be one of {sorted(ENSEMBLE_FLIPS)} (flipped passes), got {size!r}")


def self_ensemble(translate: Callable[[Tensor], Tensor], binary: Tensor, size: int = 1) -> Tensor:
    """Mean of ``translate`` ((B, 3, H, W) -> (B, 3, H, W)) over the ``size`` flips of
    :data:`ENSEMBLE_FLIPS` applied to ``binary``, each output flipped back before averaging."""
    check_ensemble(size)
    total = None
    for dims in ENSEMBLE_FLIPS[size]:
        out = translate(binary.flip(dims)).flip(dims) if dims else translate(binary)
        total = out if total is None else total + out
    return total / size


def translate_scene(
    model_dir: str | os.PathLike,
    spc_dir: str | os.PathLike,
    scene_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    frames: int = 1,
    threads: int | None = None,
    ensemble: int = 1,
) -> dict:
    """Translate all views of a scene with the model in ``model_dir`` (averaged over ``ensemble``
    flips of each input, :func:`self_ensemble`); returns the record."""
    check_ensemble(ensemble)
    if threads:
        torch.set_num_threads(threads)
    method, model = load_translator(model_dir)
    pattern, valid = input_sensor(model_dir, spc_dir)
    exposure = camera_exposure(read_spc_record(spc_dir), f"{Path(spc_dir) / 'spc.json'}")
    names = llff.read_scene(scene_dir, with_images=False).names
    times = []
    residual = model.prior is not None and model.trainable  # the prior alone is the output of ``prior`` itself
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        (Path(tmp) / "images").mkdir(parents=True)
        if residual:
            (Path(tmp) / "prior").mkdir()
        for name in names:
            x = torch.from_numpy(binary_input(Path(spc_dir) / "frames" / f"{name}.npz", frames, pattern, valid))
            x = x.permute(2, 0, 1)[None].to(model.device)
            t0 = time.perf_counter()
            y = from_camera(self_ensemble(model.translate, x, ensemble)[0], exposure)
            times.append(time.perf_counter() - t0)
            io.write_image(Path(tmp) / "images" / f"{name}.png", y.permute(1, 2, 0).cpu().numpy())
            if residual:
                with torch.no_grad():
                    base = from_camera(model.prior(x)[0], exposure)
                io.write_image(Path(tmp) / "prior" / f"{name}.png", base.permute(1, 2, 0).cpu().numpy())
        prior = None if model.prior is None else {"sigma": model.prior.sigma, "gain": model.prior.gain.tolist()}
        record = {
            "method": method,
            "model_dir": str(model_dir),
            "scene": Path(scene_dir).name,
            "frames": frames,
            "ensemble": ensemble,
            "views": len(names),
            "seconds_per_image": float(np.mean(times)),
            "device": str(model.device),
            "prior": prior,
            "exposure": exposure,
            "display": "camera image shown at the scene's reported exposure (spc3d.translate.camera)",
            "sensor": None if pattern is None else pattern.name,
        }
        io.write_json(Path(tmp) / "translate.json", record)
    log.info("%s: %d views of %s in %.2f s each", method, len(names), Path(scene_dir).name, record["seconds_per_image"])
    return record


def input_sensor(model_dir: str | os.PathLike, spc_dir: str | os.PathLike):
    """(pattern, valid) of a scene's SPC folder (None, None: the simulator's RGB frames), checked
    against the sensor the model in ``model_dir`` was trained for (its train.json)."""
    from spc3d.captures.importing import sensor_tag
    from spc3d.physics.record import spc_sensor
    from spc3d.translate.data import sensor_pattern

    train_json = Path(model_dir) / "train.json"
    trained = sensor_pattern(io.read_json(train_json).get("sensor")) if train_json.is_file() else None
    found = spc_sensor(spc_dir)
    have = None if found is None else sensor_tag(found[0])
    want = None if trained is None else sensor_tag(trained)
    if have != want:
        raise ValueError(
            f"{model_dir} was trained on inputs of the {want or 'simulated RGB'} sensor but {spc_dir} holds "
            f"{have or 'simulated RGB'} frames; the workflow trains one model per sensor (results/models-<sensor>)"
        )
    return (None, None) if found is None else found

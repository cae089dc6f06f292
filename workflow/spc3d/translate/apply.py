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

``translate_frame`` (``python -m spc3d.translate MODEL_DIR FRAME.png OUT.png``) turns one real
capture frame, a binary frame or a K-frame mean as a monochrome PNG, into an image with a trained
model: the frame copied to the model's three channels, the luminance of its output kept
(:func:`translate_mean` says why).
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
from spc3d.inputs.exposure import PREVIEW_LEVEL, display_srgb, metered_gain
from spc3d.physics import sensors, spc
from spc3d.physics.record import camera_exposure, read_spc_record
from spc3d.translate.camera import CAMERA_WHITE, from_camera
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


# --------------------------------------------------------------------------------------------
# one real frame (a monochrome PNG) through a trained model


def mono_input_kind(model_dir: str | os.PathLike) -> str:
    """How a monochrome frame enters the model in ``model_dir``: ``"replicated"`` for a model of the
    simulator's RGB sensor (the frame mean copied to its three channels), ``"mono"`` for one trained
    for a colourless sensor (whose input is that same copy: :func:`spc3d.physics.sensors.demosaic_bilinear`).
    A model trained for a colour-filter mosaic is refused: a mono frame is not that sensor's data."""
    from spc3d.translate.data import sensor_pattern

    train_json = Path(model_dir) / "train.json"
    trained = sensor_pattern(io.read_json(train_json).get("sensor")) if train_json.is_file() else None
    if trained is None:
        return "replicated"
    if not trained.colour:
        return "mono"
    raise ValueError(
        f"{model_dir} was trained for the {trained.name} colour-filter sensor; a monochrome frame needs a model "
        "of the simulator's RGB sensor (results/models/{method}) or of a colourless sensor (results/models-mono/)"
    )


def translate_mean(model, mean: np.ndarray, ensemble: int = 1) -> np.ndarray:
    """(H, W) frame mean (fraction of K frames that fired) -> (H, W) float64 detections per frame
    λT the model's output implies, from the Rec. 709 luminance of its camera image.

    The translators see three channels, each the mean of its own channel's bits; a monochrome
    pixel has one bit of all the light, so the mean is copied to all three (what the RGB sensor
    records of a grey scene, its channels firing alike). The output's colour is then the model's
    guess, not a measurement, so only its luminance is kept: in the camera domain
    (:mod:`.camera`) linear light x Λ is photons per frame, so λT = Λ Y(lin(c)).
    """
    x = torch.from_numpy(np.repeat(np.asarray(mean, np.float32)[None, None], 3, axis=1)).to(model.device)
    with torch.no_grad():
        camera = self_ensemble(model.translate, x, ensemble)[0].permute(1, 2, 0).cpu().numpy().astype(np.float64)
    return CAMERA_WHITE * (spc.srgb_to_linear(camera) @ np.asarray(sensors.LUMINANCE))


def translate_frame(
    model_dir: str | os.PathLike,
    frame: str | os.PathLike,
    out: str | os.PathLike,
    frames: int | None = None,
    ensemble: int = 1,
    level: float = PREVIEW_LEVEL,
    threads: int | None = None,
) -> dict:
    """Translate one capture frame (a binary frame or a K-frame mean as a monochrome PNG,
    :func:`spc3d.captures.photon_cubes.read_frame_mean`; ``frames`` = K or its sidecar) with the model
    in ``model_dir`` and write ``out`` (a grey 8-bit PNG, atomically): the output's λT
    (:func:`translate_mean`) shown with average metering (mean at linear ``level``, the
    exposure being unknown, as ``capture.py inspect`` shows its previews). Returns the record."""
    from spc3d.captures.photon_cubes import read_frame_mean

    check_ensemble(ensemble)
    if not str(out).lower().endswith(".png"):
        raise ValueError(f"output {out}: write the translation as a .png file")
    frame_mean = read_frame_mean(frame, frames)  # the file's faults are named before the model loads
    kind = mono_input_kind(model_dir)
    if threads:
        torch.set_num_threads(threads)
    method, model = load_translator(model_dir)
    train_json = Path(model_dir) / "train.json"
    trained_frames = io.read_json(train_json).get("frames") if train_json.is_file() else None
    if trained_frames is not None and trained_frames != frame_mean.frames:
        log.warning(
            "%s was trained on means of %s frames (stage1.frames) and is given a mean of %d: its input is "
            "outside what it learnt",
            model_dir,
            trained_frames,
            frame_mean.frames,
        )
    t0 = time.perf_counter()
    lam = translate_mean(model, frame_mean.mean, ensemble)
    seconds = time.perf_counter() - t0
    gain = metered_gain(lam, level)
    io.write_image(out, display_srgb(lam, gain)[..., None])
    record = {
        "method": method,
        "model_dir": str(model_dir),
        "frame": str(frame),
        "frames": frame_mean.frames,
        "frames_from": frame_mean.frames_from,
        "model_frames": trained_frames,
        "size": list(frame_mean.counts.shape),
        "input": kind,
        "output": "Rec. 709 luminance of the model's camera image, as detections per frame",
        "display": {"rule": "average metering", "level": level, "gain": gain},
        "ensemble": ensemble,
        "seconds": seconds,
    }
    log.info("%s: %s (K = %d) -> %s in %.2f s", method, frame, frame_mean.frames, out, seconds)
    return record

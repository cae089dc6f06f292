"""Stage-1 training data of ``stage1.data: fixed``: the augmented (binary, RGB) pairs of the
training scenes, in memory (``online``: fresh samples instead, :mod:`.online`).

A pair is ``results/augment/{scene}/frames/{i}.npz`` (K packed binary frames) and
``rgb/{i}.png`` (the 8-bit sRGB image the frames were simulated from, so the two are
pixel-aligned). The network input is the mean of the first ``frames`` binary frames (K = 1: the
bits of frame 0, the paper's setting). Batches are random crops drawn with a seeded
``torch.Generator``, so a run is reproducible and a resumed run continues the same sequence.
For unpaired methods (CycleGAN) the RGB crops come from independently drawn samples.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from spc3d import io
from spc3d.physics import sensors, spc
from spc3d.physics.record import camera_exposure
from spc3d.physics.sensors import CFAPattern
from spc3d.translate.camera import to_camera


def binary_input(
    frames_npz: str | os.PathLike,
    frames: int,
    pattern: CFAPattern | None = None,
    valid: np.ndarray | None = None,
    phi: np.ndarray | None = None,
    params: spc.SPCParams | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """(H, W, 3) float32 input of the first ``frames`` binary frames stored in ``frames_npz``.

    The simulator's RGB frames (K, H, W, 3) give their mean; with a sensor ``pattern`` they are
    first recorded as that sensor would (:func:`spc3d.physics.sensors.sensor_frames`: ``phi``, ``params``
    and ``rng`` draw its W / mono pixels). A capture's frames (K, H, W) give their demosaiced mean
    (:func:`spc3d.physics.sensors.sensor_input`, ``valid`` False at hot pixels).
    """
    bits = spc.unpack_frames(*io.load_frames(frames_npz))
    if not 1 <= frames <= bits.shape[0]:
        raise ValueError(
            f"stage1.frames={frames} but {frames_npz} stores K={bits.shape[0]} frames "
            f"(use 1..{bits.shape[0]}, or simulate more with spc.frames)"
        )
    bits = bits[:frames]
    if bits.ndim == 3:
        if pattern is None:
            raise ValueError(f"{frames_npz}: one bit per pixel (a capture's mosaic) but no sensor pattern was given")
        return sensors.sensor_input(bits, pattern, valid)
    if pattern is None:
        return bits.mean(0, dtype=np.float32)
    return sensors.sensor_input(sensors.sensor_frames(bits, pattern, phi, params, rng), pattern)


def sensor_draws(srgb: np.ndarray, flux_scale: float, params: dict, seed: int, stream: str, index: int) -> dict:
    """The ``phi``, ``params`` and ``rng`` with which :func:`binary_input` draws a sensor's W / mono
    pixels from a training view (``srgb`` at the scene's exposure; seeded per stream and view)."""
    return {
        "phi": spc.flux_from_srgb(srgb, flux_scale),
        "params": spc.SPCParams(**params),
        "rng": spc.view_rng(seed, stream, index),
    }


def sensor_pattern(sensor: dict | None) -> CFAPattern | None:
    """The pattern of a translator's ``sensor`` setting ({"cfa": ..., "white": ...}; None: the simulator's RGB)."""
    return None if sensor is None else sensors.cfa_pattern(sensor["cfa"], sensor.get("white", "sum"))


def load_pairs(
    augment_dirs: list[str | os.PathLike], frames: int, sensor: dict | None = None
) -> tuple[list[Tensor], list[Tensor]]:
    """All pairs of the given augment folders: binary and rgb lists of (3, H, W) float32 tensors,
    the rgb as the camera's exposure shows it (the translators' domain, :mod:`.camera`).

    Scenes may differ in size (LLFF captures keep their aspect ratio): training crops a fixed
    square from every pair, so only the crop must fit. ``sensor``: the inputs as that sensor
    records them (:func:`binary_input`); its W / mono pixels are drawn from the pair's RGB at the
    scene's exposure (augment.json), seeded by the pair.
    """
    binary, rgb = [], []
    pattern = sensor_pattern(sensor)
    for folder in map(Path, augment_dirs):
        names = sorted(p.stem for p in (folder / "frames").glob("*.npz"))
        if not names:
            raise FileNotFoundError(f"{folder}/frames holds no .npz pairs: run the augment_scene rule first")
        record = io.read_json(folder / "augment.json")
        exposure = camera_exposure(record, f"{folder / 'augment.json'}")
        for i, name in enumerate(names):
            r = io.read_rgb(folder / "rgb" / f"{name}.png")
            drawn = {}
            if pattern is not None:
                stream = f"{record['scene']}/sensor"
                drawn = sensor_draws(r, record["flux_scale"], record["spc_params"], record["seed"], stream, i)
            b = binary_input(folder / "frames" / f"{name}.npz", frames, pattern, **drawn)
            if b.shape != r.shape:
                raise ValueError(
                    f"{folder}: pair {name} has binary {b.shape} but rgb {r.shape}; rerun the augment_scene rule"
                )
            binary.append(chw(b))
            rgb.append(to_camera(chw(r), exposure))
    return binary, rgb


def chw(image: np.ndarray) -> Tensor:
    """(H, W, 3) array -> (3, H, W) tensor."""
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).contiguous()


class PairSampler:
    """Random crops of (binary, rgb) pairs; ``paired=False`` decouples the RGB draws."""

    def __init__(self, binary, rgb, batch_size: int, crop: int, seed: int, paired: bool = True):
        """``binary``, ``rgb``: sequences of (3, H_i, W_i) tensors (or (N, 3, H, W) tensors)."""
        self.binary, self.rgb = list(binary), list(rgb)
        smallest = min(min(x.shape[-2:]) for x in self.binary + self.rgb)
        if crop > smallest:
            raise ValueError(
                f"stage1.train.crop={crop} exceeds the smallest training image side ({smallest} px); use <= {smallest}"
            )
        self.batch, self.crop, self.paired = batch_size, crop, paired
        # (6, H, W): one crop
        self.pairs = [torch.cat(p, dim=0) for p in zip(self.binary, self.rgb)] if paired else None
        self.gen = torch.Generator().manual_seed(seed)
        self.seen = torch.zeros(len(self.binary), dtype=torch.bool)  # pairs drawn at least once
        self.drawn = 0  # samples drawn so far

    def _crops(self, images: list[Tensor], idx: Tensor) -> Tensor:
        """(B, C, crop, crop): a uniformly placed window of each chosen image."""
        out = []
        for i in idx.tolist():
            h, w = images[i].shape[-2:]
            y = int(torch.randint(0, h - self.crop + 1, (1,), generator=self.gen))
            x = int(torch.randint(0, w - self.crop + 1, (1,), generator=self.gen))
            out.append(images[i][:, y : y + self.crop, x : x + self.crop])
        return torch.stack(out)

    def _draw(self) -> tuple[Tensor, Tensor]:
        """Crops of the same pixels (paired) or of independent samples (unpaired)."""
        idx = torch.randint(0, len(self.binary), (self.batch,), generator=self.gen)
        self.seen[idx] = True
        if not self.paired:
            other = torch.randint(0, len(self.rgb), (self.batch,), generator=self.gen)
            return self._crops(self.binary, idx), self._crops(self.rgb, other)
        crops = self._crops(self.pairs, idx)
        return crops[:, :3], crops[:, 3:]

    def __call__(self) -> tuple[Tensor, Tensor]:
        self.drawn += self.batch
        return self._draw()

    def calibration_pairs(self):
        """Every (binary, rgb) pair, whole: the data the physics prior's gain is fitted on."""
        return zip(self.binary, self.rgb)

    def describe(self) -> dict:
        """For train.json: the mode, the samples drawn and how many distinct pairs they came from."""
        return {
            "mode": "fixed",
            "pairs": len(self.binary),
            "samples": self.drawn,
            "distinct_samples": int(self.seen.sum()),
        }

    def state(self) -> dict:
        return {"gen": self.gen.get_state(), "seen": self.seen.clone(), "drawn": self.drawn}

    def load(self, state: dict) -> None:
        self.gen.set_state(state["gen"])
        self.seen, self.drawn = state["seen"].clone(), int(state["drawn"])

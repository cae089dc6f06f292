"""Online stage-1 data: every batch drawn fresh from the training scenes (``stage1.data: online``).

Each sample takes a random training view (not a held-out one: those validate, :mod:`.validate`)
of a random training scene, a fresh random affine map from the augmentation's distribution
(:func:`spc3d.inputs.augment.sample_params`, zoom / rotation / shear / flip), a random ``crop`` window of
the warped view (only that window is warped: :func:`spc3d.inputs.augment.warp_linear`), and a fresh
Bernoulli sample of ``frames`` 1-bit frames of exactly that window at the scene's exposure (its
``flux_scale`` and physics from ``spc.json``), averaged as the fixed pairs' input is. The target
is the warped window as the camera's reported exposure shows it (:mod:`.camera`), so input and
target are pixel-aligned as in a fixed pair, but no sample is ever seen twice.

One numpy PCG64 stream, seeded by the run's seed, draws everything in a fixed order; its state
is in :meth:`OnlineSampler.state`, so a resumed run continues the same sequence bit for bit.
For unpaired methods (CycleGAN) the RGB crops come from independently drawn samples.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from spc3d import llff
from spc3d.cameras import split_views
from spc3d.inputs.augment import sample_params, warp_linear
from spc3d.physics import sensors, spc
from spc3d.physics.record import camera_exposure, params_from_record, read_spc_record
from spc3d.specs.translators import AugmentSettings
from spc3d.translate.camera import to_camera
from spc3d.translate.data import chw, sensor_pattern


@dataclass
class SceneSource:
    """What online sampling needs of one training scene."""

    name: str
    views: list[np.ndarray]  # its training views, linear light, (H, W, 3) float64
    flux_scale: float  # photons/s at linear 1.0 (the scene's exposure, from spc.json)
    params: spc.SPCParams  # its physics, with frames = the K frames averaged into the input
    exposure: float  # photons per frame at linear 1 the camera reports (the targets' domain, .camera)


def load_sources(
    scene_dirs: list[str | os.PathLike], spc_dirs: list[str | os.PathLike], frames: int
) -> list[SceneSource]:
    """The training views, exposure and physics of every training scene (paired folders in order)."""
    if len(scene_dirs) != len(spc_dirs) or not scene_dirs:
        raise ValueError(
            f"online stage-1 data needs one SPC folder per training scene folder, got "
            f"{len(scene_dirs)} scene(s) and {len(spc_dirs)} SPC folder(s)"
        )
    sources = []
    for scene_dir, spc_dir in zip(map(Path, scene_dirs), map(Path, spc_dirs)):
        record = read_spc_record(spc_dir)
        if record.get("scene") not in (None, scene_dir.name):
            raise ValueError(f"{spc_dir}/spc.json belongs to scene {record['scene']!r}, not {scene_dir.name!r}")
        scene = llff.read_scene(scene_dir)
        train, _ = split_views(len(scene.names))
        views = [spc.srgb_to_linear(scene.images[i]).astype(np.float64) for i in train]
        physics = dataclasses.replace(params_from_record(record), frames=frames)
        exposure = camera_exposure(record, f"{spc_dir / 'spc.json'}")
        sources.append(SceneSource(scene_dir.name, views, float(record["flux_scale"]), physics, exposure))
    return sources


class OnlineSampler:
    """Fresh (binary, rgb) crops of the training scenes, as :class:`.data.PairSampler` gives fixed ones."""

    def __init__(
        self,
        sources: list[SceneSource],
        batch_size: int,
        crop: int,
        seed: int,
        augment: AugmentSettings = AugmentSettings(),
        paired: bool = True,
        sensor: dict | None = None,
    ):
        """``sensor``: the inputs as that sensor records them ({"cfa", "white"}; None: the simulator's RGB)."""
        smallest = min(min(v.shape[:2]) for s in sources for v in s.views)
        if crop > smallest:
            raise ValueError(
                f"stage1.train.crop={crop} exceeds the smallest training image side ({smallest} px); use <= {smallest}"
            )
        self.sources, self.batch, self.crop, self.augment, self.paired = sources, batch_size, crop, augment, paired
        self.rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, zlib.crc32(b"stage1-online")])))
        self.drawn = 0  # samples drawn so far (each one distinct)
        self.seed = seed
        self.pattern = sensor_pattern(sensor)

    def window(self) -> tuple[SceneSource, np.ndarray]:
        """A random scene, training view, affine map and crop: (scene, linear crop (crop, crop, 3))."""
        source = self.sources[self.rng.integers(len(self.sources))]
        view = source.views[self.rng.integers(len(source.views))]
        p = sample_params(self.rng, self.augment)
        h, w = view.shape[:2]
        y, x = (int(self.rng.integers(0, n - self.crop + 1)) for n in (h, w))
        return source, np.clip(warp_linear(view, p, (y, x, self.crop, self.crop)), 0.0, 1.0)

    def sample(self) -> tuple[SceneSource, Tensor, Tensor]:
        """One fresh pair: its scene, the K-frame mean of a Bernoulli sample of the crop and the crop
        as the camera shows it (:mod:`.camera`), both (3, crop, crop)."""
        source, linear = self.window()
        srgb = spc.linear_to_srgb(linear).astype(np.float32)
        self.drawn += 1
        return source, chw(self.input(srgb, source, self.rng)), to_camera(chw(srgb), source.exposure)

    def input(self, srgb: np.ndarray, source: SceneSource, rng: np.random.Generator) -> np.ndarray:
        """(H, W, 3) input of a fresh Bernoulli sample of ``srgb``: the K-frame mean, or as the
        sensor records it (demosaiced; its W / mono pixels drawn from the same flux)."""
        bits = spc.simulate_frames(srgb, source.flux_scale, source.params, rng)
        if self.pattern is None:
            return bits.mean(0, dtype=np.float32)
        phi = spc.flux_from_srgb(srgb, source.flux_scale)
        return sensors.sensor_input(sensors.sensor_frames(bits, self.pattern, phi, source.params, rng), self.pattern)

    def __call__(self) -> tuple[Tensor, Tensor]:
        """(B, 3, crop, crop) binary input and RGB target (from other samples when unpaired)."""
        pairs = [self.sample() for _ in range(self.batch)]
        binary = torch.stack([b for _, b, _ in pairs])
        if self.paired:
            return binary, torch.stack([r for _, _, r in pairs])
        rgb = []
        for _ in range(self.batch):
            source, linear = self.window()
            rgb.append(to_camera(chw(spc.linear_to_srgb(linear).astype(np.float32)), source.exposure))
        return binary, torch.stack(rgb)

    def calibration_pairs(self):
        """Every training view, whole, with a Bernoulli sample at its scene's exposure (a generator of
        its own, so the training draws do not change): the data the physics prior's gain is fitted on."""
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([self.seed, zlib.crc32(b"stage1-prior")])))
        for source in self.sources:
            for linear in source.views:
                srgb = spc.linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32)
                yield chw(self.input(srgb, source, rng)), to_camera(chw(srgb), source.exposure)

    def describe(self) -> dict:
        """For train.json: the mode, the samples drawn (all distinct), the scenes and their views."""
        return {
            "mode": "online",
            "samples": self.drawn,
            "distinct_samples": self.drawn,
            "scenes": [s.name for s in self.sources],
            "training_views": sum(len(s.views) for s in self.sources),
            "augment": dataclasses.asdict(self.augment),
        }

    def state(self) -> dict:
        """The generator's state (as JSON text: its 128-bit integers) and the count drawn."""
        return {"rng": json.dumps(self.rng.bit_generator.state), "drawn": self.drawn}

    def load(self, state: dict) -> None:
        self.rng.bit_generator.state = json.loads(state["rng"])
        self.drawn = int(state["drawn"])

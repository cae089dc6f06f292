"""Stage-1 training data: the augmented (binary, RGB) pairs of the training scenes, in memory.

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

from .. import io, spc


def binary_input(frames_npz: str | os.PathLike, frames: int) -> np.ndarray:
    """(H, W, 3) float32 mean of the first ``frames`` binary frames stored in ``frames_npz``."""
    bits = spc.unpack_frames(*io.load_frames(frames_npz))
    if not 1 <= frames <= bits.shape[0]:
        raise ValueError(f"stage1.frames={frames} but {frames_npz} stores K={bits.shape[0]} frames "
                         f"(use 1..{bits.shape[0]}, or simulate more with spc.frames)")
    return bits[:frames].mean(0, dtype=np.float32)


def load_pairs(augment_dirs: list[str | os.PathLike], frames: int) -> tuple[Tensor, Tensor]:
    """All pairs of the given augment folders: binary (N, 3, H, W), rgb (N, 3, H, W), float32."""
    binary, rgb = [], []
    for folder in map(Path, augment_dirs):
        names = sorted(p.stem for p in (folder / "frames").glob("*.npz"))
        if not names:
            raise FileNotFoundError(f"{folder}/frames holds no .npz pairs: run the augment rule first")
        for name in names:
            binary.append(binary_input(folder / "frames" / f"{name}.npz", frames))
            rgb.append(io.read_rgb(folder / "rgb" / f"{name}.png"))
    shapes = {b.shape for b in binary} | {r.shape for r in rgb}
    if len(shapes) != 1:
        raise ValueError(f"augmented pairs in {list(map(str, augment_dirs))} differ in size {sorted(shapes)}; "
                         "every training scene must share resolution.width/height")
    return _nchw(binary), _nchw(rgb)


def _nchw(images: list[np.ndarray]) -> Tensor:
    """(H, W, 3) arrays -> one (N, 3, H, W) tensor."""
    return torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous()


class PairSampler:
    """Random crops of (binary, rgb) pairs; ``paired=False`` decouples the RGB draws."""

    def __init__(self, binary: Tensor, rgb: Tensor, batch_size: int, crop: int, seed: int, paired: bool = True):
        h, w = binary.shape[-2:]
        if crop > min(h, w):
            raise ValueError(f"stage1.train.crop={crop} exceeds the training images ({w}x{h}); use <= {min(h, w)}")
        self.binary, self.rgb, self.batch, self.crop, self.paired = binary, rgb, batch_size, crop, paired
        self.pairs = torch.cat([binary, rgb], dim=1) if paired else None  # (N, 6, H, W): one crop for both
        self.gen = torch.Generator().manual_seed(seed)

    def _crops(self, images: Tensor, idx: Tensor) -> Tensor:
        h, w = images.shape[-2:]
        ys = torch.randint(0, h - self.crop + 1, (len(idx),), generator=self.gen)
        xs = torch.randint(0, w - self.crop + 1, (len(idx),), generator=self.gen)
        return torch.stack([images[i, :, y:y + self.crop, x:x + self.crop] for i, y, x in zip(idx, ys, xs)])

    def _draw(self) -> tuple[Tensor, Tensor]:
        """Crops of the same pixels (paired) or of independent samples (unpaired)."""
        idx = torch.randint(0, len(self.binary), (self.batch,), generator=self.gen)
        if not self.paired:
            other = torch.randint(0, len(self.rgb), (self.batch,), generator=self.gen)
            return self._crops(self.binary, idx), self._crops(self.rgb, other)
        crops = self._crops(self.pairs, idx)
        return crops[:, :3], crops[:, 3:]

    def __call__(self) -> tuple[Tensor, Tensor]:
        return self._draw()

    def state(self) -> Tensor:
        return self.gen.get_state()

    def load(self, state: Tensor) -> None:
        self.gen.set_state(state)

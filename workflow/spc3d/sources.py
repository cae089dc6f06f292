"""Stage-2 image sources: what a reconstructor of a scene is trained on.

    gt         ground-truth RGB views (the oracle upper bound)
    none       the raw binary SPC frame 0 as a 0/1 image (the paper's single-stage baselines)
    mle        the K-frame maximum-likelihood flux, tone-mapped to sRGB (physics baseline)
    bernoulli  the binary frames themselves, fitted through the SPAD likelihood (beyond the paper)
    <method>   a stage-1 translator's output folder (issue 4), images named like the scene's views

Every source yields targets aligned with the scene's cameras; only training views are returned
(every 8th view is held out for evaluation, see :func:`spc3d.cameras.split_views`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import io, llff, spc
from .cameras import split_views
from .reconstruct.objectives import BernoulliObjective
from .reconstruct.train import Views
from .simulate import read_spc_record

IMAGE_SOURCES = {"gt": ("scene", "images"), "none": ("spc", "binary"), "mle": ("spc", "mle_srgb")}
FRAME_SOURCES = ("bernoulli",)


@dataclass
class Source:
    """Training targets of one scene from one source, and how they are compared (``objective``)."""

    views: Views
    objective: object | None  # a BernoulliObjective for frame sources; None = the model's RGB loss
    name: str


def load_source(name: str, scene_dir: str | os.PathLike, spc_dir: str | os.PathLike | None = None,
                image_dir: str | os.PathLike | None = None, frames: int = 1) -> Source:
    """Training views of ``scene_dir`` from source ``name``.

    ``image_dir`` overrides where an image source is read (stage-1 outputs); ``frames`` is the
    number of binary frames the bernoulli source uses (1 = the paper's setting).
    """
    scene = llff.read_scene(scene_dir)
    train, _ = split_views(len(scene.names))
    names = [scene.names[i] for i in train]
    cams = scene.cameras.subset(train)
    if name in FRAME_SOURCES:
        targets, objective = bit_fractions(Path(spc_dir), names, frames), bernoulli_objective(Path(spc_dir))
    else:
        folder = Path(image_dir) if image_dir else _image_folder(name, Path(scene_dir), spc_dir)
        targets, objective = np.stack([_read_view(folder, n, cams) for n in names]), None
    return Source(Views(torch.as_tensor(targets, dtype=torch.float32), cams, names), objective, name)


def _image_folder(name: str, scene_dir: Path, spc_dir) -> Path:
    if name not in IMAGE_SOURCES:
        raise ValueError(f"unknown image source {name!r}: use one of {sorted(IMAGE_SOURCES) + list(FRAME_SOURCES)} "
                         "or give the folder of a stage-1 method's images")
    base, sub = IMAGE_SOURCES[name]
    if base == "spc" and spc_dir is None:
        raise ValueError(f"source {name!r} needs the scene's SPC folder (results/spc/{{scene}})")
    return (scene_dir if base == "scene" else Path(spc_dir)) / sub


def _read_view(folder: Path, name: str, cams) -> np.ndarray:
    img = io.read_rgb(folder / f"{name}.png")
    if img.shape[:2] != (cams.height, cams.width):
        raise ValueError(f"{folder / name}.png is {img.shape[1]}x{img.shape[0]}, "
                         f"expected {cams.width}x{cams.height} like the scene's views")
    return img


def bit_fractions(spc_dir: Path, names: list[str], frames: int) -> np.ndarray:
    """(N, H, W, 3) fraction of ones over the first ``frames`` binary frames of each view."""
    out = []
    for n in names:
        bits = spc.unpack_frames(*io.load_frames(spc_dir / "frames" / f"{n}.npz"))
        if frames > bits.shape[0]:
            raise ValueError(f"stage2.frames={frames} but {spc_dir} stores only K={bits.shape[0]} frames per view")
        out.append(bits[:frames].mean(0, dtype=np.float32))
    return np.stack(out)


def bernoulli_objective(spc_dir: Path) -> BernoulliObjective:
    """The SPAD likelihood with the physics the frames were simulated with (spc.json)."""
    rec = read_spc_record(spc_dir)
    p = rec["params"]
    return BernoulliObjective(flux_scale=rec["flux_scale"], q=p["q"], exposure_s=p["exposure_s"],
                              dark_count_rate=p["dark_count_rate"])

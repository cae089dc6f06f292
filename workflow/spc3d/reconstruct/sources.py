"""Stage-2 image sources: what a reconstructor of a scene is trained on.

    gt           ground-truth RGB views (the oracle upper bound)
    none         the paper's single-stage input: one binary frame taken at spc.capture_factor x the
                 working resolution and area-averaged to it, as the reference NeRF / 3DGS loaders
                 downscale a capture-resolution image (``spc/{scene}/capture``)
    none-x1      the raw binary frame 0 at the working resolution, a 0/1 image
    mle[-kK]     the MLE flux of K frames per view at the metered display gain (physics baseline);
                 at K = 1 of the capture-resolution frame, ``mle-x1`` of frame 0
    bernoulli[-kK]  K binary frames per view themselves, fitted through the SPAD likelihood
    joint-<method>  the frames through the SPAD likelihood and a stage-1 method's output as a prior
                 term, in one fit (:class:`spc3d.reconstruct.objectives.JointObjective`)
    <method>     a stage-1 method's output folder (``<method>-pub``: its published network; ``prior``:
                 the physics prior alone), images named like the scene's views

The suffix ``-mse`` (none, mle) fits the images with MSE instead of the model's own loss: 3DGS's
0.8 L1 + 0.2 D-SSIM fits the per-pixel *median* of 0/1 targets across views (a binary render),
MSE their mean (:mod:`spc3d.names`, ``SUFFIXES``).

Every source yields targets aligned with the scene's cameras; only training views are returned
(every 8th view is held out for evaluation, see :func:`spc3d.cameras.split_views`). Only ``gt``
reads the scene's images: the others see the frames, q, T, dcr, the exposure the camera reports
and what was learnt on the training scenes (the display gain of mle / bernoulli comes from
:mod:`spc3d.inputs.exposure`: that exposure times a level fitted on the training scenes).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.inputs.exposure import capture_factor as spc_capture_factor
from spc3d.inputs.exposure import read_gain
from spc3d.names import SOURCE_IMAGES, parse_source, reads_capture_frame, source_images
from spc3d.physics import spc
from spc3d.physics.record import read_spc_record
from spc3d.reconstruct.objectives import BernoulliObjective, JointObjective, RGBObjective
from spc3d.reconstruct.views import Views
from spc3d.specs.reconstructors import config_joint

FRAME_SOURCES = ("bernoulli",)


@dataclass
class Source:
    """Training targets of one scene from one source, and how they are compared (``objective``)."""

    views: Views
    objective: object | None  # a BernoulliObjective for frame sources, MSE for "-mse"; None = the model's RGB loss
    name: str
    capture_factor: int = 1  # sensor pixels per working pixel and axis behind each image (the capture frame's S)


def load_source(
    name: str,
    scene_dir: str | os.PathLike,
    spc_dir: str | os.PathLike | None = None,
    image_dir: str | os.PathLike | None = None,
    frames: int = 1,
    display_dir: str | os.PathLike | None = None,
    joint: dict | None = None,
) -> Source:
    """Training views of ``scene_dir`` from source ``name``.

    ``image_dir`` overrides where an image source is read (stage-1 outputs); ``frames`` is the
    number of binary frames per view the bernoulli source uses (1 = the paper's setting);
    ``display_dir``: the metered MLE folder of that budget (``results/mle/{scene}/k{K}``), whose
    images the mle source trains on and whose gain the bernoulli source's likelihood uses;
    ``joint``: stage2.joint's settings (the prior term's schedule of a joint source).
    """
    parsed = parse_source(name)
    base = parsed.base
    scene = llff.read_scene(scene_dir, with_images=base == "gt")
    train, _ = split_views(len(scene.names))
    names = [scene.names[i] for i in train]
    cams = scene.cameras.subset(train)
    if parsed.joint:
        targets, likelihood = frame_targets(name, spc_dir, names, frames, display_dir)
        if image_dir is None:
            raise ValueError(f"source {name!r} needs the folder of {parsed.method!r}'s images (its prior term)")
        images = np.stack([_read_view(Path(image_dir), n, cams) for n in names])
        targets = np.concatenate([targets.reshape(*images.shape[:3], -1), images], axis=-1)
        objective = JointObjective(likelihood, config_joint(joint or {}))
    elif base in FRAME_SOURCES:
        targets, objective = frame_targets(name, spc_dir, names, frames, display_dir)
    else:
        folder = Path(image_dir) if image_dir else _image_folder(name, Path(scene_dir), spc_dir, display_dir, frames)
        targets = np.stack([_read_view(folder, n, cams) for n in names])
        objective = RGBObjective("mse") if parse_source(name).mse else None
    views = Views(torch.as_tensor(targets, dtype=torch.float32), cams, names)
    return Source(views, objective, name, capture_factor(name, spc_dir, frames))


def frame_targets(name: str, spc_dir, names: list[str], frames: int, display_dir):
    """(targets, SPAD likelihood) of the views ``names``: the fraction of ones over their first
    ``frames`` frames, at the gain of the metered display (a capture's mosaic: :func:`sensor_targets`)."""
    if display_dir is None:
        raise ValueError(
            f"source {name!r} needs the metered display folder (results/mle/{{scene}}/k{frames}): "
            f"its gain turns rendered intensity into flux without the ground truth"
        )
    targets = bit_fractions(Path(spc_dir), names, frames)
    objective = bernoulli_objective(Path(spc_dir), read_gain(display_dir, likelihood=True))
    return sensor_targets(Path(spc_dir), targets, objective)


def capture_factor(name: str, spc_dir, frames: int) -> int:
    """S of the images a source trains on: the SPC folder's ``capture_factor`` for a row reading
    the capture-resolution frame (:func:`spc3d.names.reads_capture_frame`), else 1."""
    if not reads_capture_frame(name, frames) or spc_dir is None:
        return 1
    return spc_capture_factor(spc_dir)


def with_estimated_poses(src: Source, poses_dir: str | os.PathLike) -> Source:
    """``src`` on the training views COLMAP posed (:mod:`spc3d.poses.estimate`), at their estimated cameras;
    raises :class:`spc3d.poses.estimate.NoPoses` when too few were posed."""
    from spc3d.poses.estimate import estimated_views

    keep, cameras = estimated_views(src.views.names, poses_dir)
    views = Views(src.views.targets[keep], cameras, [src.views.names[i] for i in keep])
    return Source(views, src.objective, src.name, src.capture_factor)


def _image_folder(name: str, scene_dir: Path, spc_dir, display_dir, frames: int) -> Path:
    """The folder of source ``name``'s images (spc3d.names.source_images), from the folders given."""
    base = parse_source(name).base
    if SOURCE_IMAGES.get(base, ("translated",))[0] == "translated":  # a stage-1 method's images come as image_dir
        known = sorted(k for k, (where, _) in SOURCE_IMAGES.items() if where != "translated")
        raise ValueError(
            f"unknown image source {name!r}: use one of {known + list(FRAME_SOURCES)} "
            "or give the folder of a stage-1 method's images"
        )
    kind, sub = source_images(name, frames)
    folders = {"scene": scene_dir, "spc": spc_dir, "display": display_dir}
    if folders[kind] is None:
        what = {
            "spc": "the scene's SPC folder (results/spc/{scene})",
            "display": "the metered display folder (results/mle/{scene}/<budget>)",
        }[kind]
        raise ValueError(f"source {name!r} needs {what}")
    return Path(folders[kind]) / sub


def _read_view(folder: Path, name: str, cams) -> np.ndarray:
    img = io.read_rgb(folder / f"{name}.png")
    if img.shape[:2] != (cams.height, cams.width):
        raise ValueError(
            f"{folder / name}.png is {img.shape[1]}x{img.shape[0]}, "
            f"expected {cams.width}x{cams.height} like the scene's views"
        )
    return img


def sensor_targets(spc_dir: Path, fractions: np.ndarray, objective: BernoulliObjective):
    """A capture's (N, H, W) fractions as (N, H, W, 5) targets of the mosaic likelihood (each pixel's
    fraction, the channel weights it sees, 0 at hot pixels: :func:`spc3d.physics.sensors.pack_mosaic_target`);
    the simulator's RGB fractions pass through."""
    from spc3d.physics.record import spc_sensor
    from spc3d.physics.sensors import MosaicBernoulliObjective, cfa_mask, pack_mosaic_target

    sensor = spc_sensor(spc_dir)
    if sensor is None:
        return fractions, objective
    pattern, valid = sensor
    weights = torch.from_numpy(cfa_mask(pattern, *fractions.shape[1:3]))
    packed = pack_mosaic_target(torch.from_numpy(fractions), weights, torch.from_numpy(valid))
    return packed.numpy(), MosaicBernoulliObjective(objective)


def bit_fractions(spc_dir: Path, names: list[str], frames: int) -> np.ndarray:
    """(N, H, W, 3) fraction of ones over the first ``frames`` binary frames of each view ((N, H, W)
    for a capture's one bit per pixel)."""
    out = []
    for n in names:
        bits = spc.unpack_frames(*io.load_frames(spc_dir / "frames" / f"{n}.npz"))
        if frames > bits.shape[0]:
            raise ValueError(f"stage2.frames={frames} but {spc_dir} stores only K={bits.shape[0]} frames per view")
        out.append(bits[:frames].mean(0, dtype=np.float32))
    return np.stack(out)


def bernoulli_objective(spc_dir: Path, gain: float) -> BernoulliObjective:
    """The SPAD likelihood with the camera's q, T and dcr (spc.json) and the display gain of the
    camera's reported exposure: rendered linear intensity l means flux gain * l."""
    p = read_spc_record(spc_dir)["params"]
    return BernoulliObjective(
        flux_scale=gain, q=p["q"], exposure_s=p["exposure_s"], dark_count_rate=p["dark_count_rate"]
    )

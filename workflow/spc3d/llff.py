"""LLFF folders: read real captures, write the canonical scene layout every later rule reads.

An LLFF folder holds ``images/`` (full size) and optionally ``images_4/``, ``images_8/`` (downscaled
by that factor) plus ``poses_bounds.npy`` (N x 17; see :mod:`spc3d.cameras`). ``hwf`` in the file
refers to the full-size images, so the focal length is rescaled to the folder actually loaded.

The canonical scene folder written by :func:`write_scene` (``results/scenes/{scene}/``) is an LLFF
folder at the working resolution, whose ``hwf`` already matches its ``images/``:

    images/{name}.png     sRGB, 8 bit
    depth/{name}.exr      ground-truth depth along the camera z axis (built-in scenes only)
    poses_bounds.npy      N x 17, LLFF convention
    scene.json            provenance: source, resolution, seed, settings, wall time
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import io
from .cameras import Cameras, cameras_to_llff, llff_to_cameras


@dataclass
class SceneData:
    """Views of one scene. images: (N, H, W, 3) float32 sRGB in [0, 1]; names: file stems."""

    images: np.ndarray
    cameras: Cameras
    names: list[str]
    depths: np.ndarray | None = None  # (N, H, W) float32, when known
    meta: dict = field(default_factory=dict)


def image_folder(root: str | os.PathLike, factor: int) -> Path:
    """``images/`` for factor 1, else ``images_{factor}/``; a clear error lists what exists."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"scene folder {root} does not exist (expected an LLFF folder)")
    folder = root / ("images" if factor == 1 else f"images_{factor}")
    if not folder.is_dir():
        found = sorted(p.name for p in root.glob("images*") if p.is_dir())
        raise FileNotFoundError(
            f"{folder} does not exist; choose an LLFF factor whose folder is present (found: {found or 'none'})"
        )
    return folder


def load_llff(root: str | os.PathLike, factor: int = 8, width: int | None = None) -> SceneData:
    """Load an LLFF folder at ``factor``, then area-downscale to ``width`` (aspect kept) if given."""
    root = Path(root)
    folder = image_folder(root, factor)
    pb_path = root / "poses_bounds.npy"
    if not pb_path.is_file():
        raise FileNotFoundError(f"{pb_path} is missing (an LLFF folder needs poses_bounds.npy, N x 17)")
    poses_bounds = np.load(pb_path)
    files = io.list_images(folder)
    if len(files) != len(poses_bounds):
        raise ValueError(
            f"{folder} holds {len(files)} images but {pb_path} has {len(poses_bounds)} poses; they must match"
        )
    images = np.stack([io.read_rgb(f) for f in files])
    if len({im.shape for im in images}) > 1:
        raise ValueError(f"images in {folder} differ in size")
    cams = llff_to_cameras(poses_bounds, images.shape[1], images.shape[2])
    scene = SceneData(images, cams, [f.stem for f in files], meta={"source": str(root), "factor": factor})
    return resize_scene(scene, width) if width else scene


def resize_scene(scene: SceneData, width: int, height: int | None = None) -> SceneData:
    """Area-resample every view to ``width`` (height keeps the aspect unless given)."""
    n, h0, w0, _ = scene.images.shape
    height = height or max(1, int(round(width * h0 / w0)))
    if (height, width) == (h0, w0):
        return scene
    Ay, Ax = area_matrix(h0, height), area_matrix(w0, width)
    images = np.einsum("yh,nhwc,xw->nyxc", Ay, scene.images, Ax, optimize=True).astype(np.float32)
    depths = None if scene.depths is None else nearest_resize_depth(scene.depths, height, width)
    return SceneData(images, scene.cameras.rescaled(height, width), scene.names, depths, dict(scene.meta))


def nearest_resize_depth(depths: np.ndarray, height: int, width: int) -> np.ndarray:
    """Depth (N, H, W) sampled at each output pixel's centre: averaging across an occlusion edge
    would invent depths that belong to no surface, so depth is resampled, never filtered."""
    _, h0, w0 = depths.shape
    rows = np.minimum(((np.arange(height) + 0.5) * h0 / height).astype(int), h0 - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w0 / width).astype(int), w0 - 1)
    return depths[:, rows][:, :, cols].astype(np.float32)


def area_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) weights averaging the exact overlap of each output pixel with input pixels.

    The area filter of image resizing (OpenCV's INTER_AREA for shrinking), valid for any ratio.
    """
    edges = np.linspace(0.0, n_in, n_out + 1)
    lo, hi = edges[:-1, None], edges[1:, None]
    px = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(hi, px + 1) - np.maximum(lo, px), 0.0, None)
    return overlap / overlap.sum(1, keepdims=True)


def write_scene(out_dir: str | os.PathLike, scene: SceneData, record: dict) -> None:
    """Write the canonical scene folder atomically (built as a temporary folder, then renamed)."""
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i, name in enumerate(scene.names):
            io.write_image(tmp / "images" / f"{name}.png", scene.images[i])
            if scene.depths is not None:
                io.write_image(tmp / "depth" / f"{name}.exr", scene.depths[i][:, :, None])
        io.save_npy(tmp / "poses_bounds.npy", cameras_to_llff(scene.cameras))
        io.write_json(tmp / "scene.json", {**scene.meta, **record, "views": len(scene.names),
                                            "height": scene.cameras.height, "width": scene.cameras.width})


def read_scene(scene_dir: str | os.PathLike, with_depth: bool = False) -> SceneData:
    """Read a canonical scene folder written by :func:`write_scene`."""
    scene_dir = Path(scene_dir)
    data = load_llff(scene_dir, factor=1)
    meta_path = scene_dir / "scene.json"
    data.meta = io.read_json(meta_path) if meta_path.exists() else {}
    if with_depth and (scene_dir / "depth").is_dir():
        data.depths = np.stack([io.read_image(scene_dir / "depth" / f"{n}.exr")[:, :, 0] for n in data.names])
    return data

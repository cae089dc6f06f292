"""COLMAP-format scenes: ``images/`` + ``sparse/0/``, as 3DGS, nerfstudio and SPAD datasets ship them.

A COLMAP-format scene folder holds

    images/{name}            the views, named as in the model's image list
    images_{factor}/{name}   optionally the same views downscaled by ``factor`` (3DGS, nerfstudio)
    sparse/0/                the model: cameras, images, points3D as .bin or .txt (``sparse/``
                             itself is read too: that is where ``colmap image_undistorter`` writes)

and reads into the same :class:`spc3d.llff.SceneData` as an LLFF folder (:func:`load_colmap`):

- views: the registered images of the model, ordered as the canonical scene folder orders them
  (by file name, ``{stem}.png``); images of the folder without a pose in the model are left out
  and named in ``meta["colmap"]["images_not_read"]``;
- poses: COLMAP's ``cam_from_world`` *is* the internal w2c (OpenCV axes; the world is kept);
- intrinsics: fx, fy, cx, cy per view exactly as in the model (COLMAP and this project both put
  the centre of the top-left pixel at (0.5, 0.5)), rescaled to the images loaded;
- bounds: per view the 0.1 / 99.9 percentiles of the camera-z depths of the 3-D points that view
  observes: the rule of LLFF's ``imgs2poses``, computed by :func:`spc3d.poses.colmap.view_bounds`.

Camera models: PINHOLE and SIMPLE_PINHOLE are read directly, and so are SIMPLE_RADIAL, RADIAL,
OPENCV and FULL_OPENCV whose distortion parameters are all zero. Any other camera is refused with
its model and parameters named, unless ``undistort=True``: then pycolmap's image undistorter (on
the CPU, as ``colmap image_undistorter``) first resamples the views to PINHOLE cameras.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pycolmap

from spc3d import io, llff
from spc3d.cameras import Cameras
from spc3d.llff import SceneData
from spc3d.poses import colmap

log = logging.getLogger(__name__)

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
PINHOLE_WITHOUT_DISTORTION = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")  # pinhole when k = p = 0
MODEL_FILES = ("cameras", "images", "points3D")
BOUNDS_RULE = "0.1 / 99.9 percentile of the camera-z depths of the 3-D points each view observes (LLFF imgs2poses)"


def model_format(folder: str | os.PathLike) -> str | None:
    """``"bin"`` or ``"txt"`` when ``folder`` holds a complete COLMAP model in that format, else None."""
    for ext in ("bin", "txt"):
        if all((Path(folder) / f"{name}.{ext}").is_file() for name in MODEL_FILES):
            return ext
    return None


def find_model(root: str | os.PathLike) -> Path | None:
    """The model folder of a COLMAP-format scene: ``sparse/0``, else ``sparse``; None without one."""
    for folder in (Path(root) / "sparse" / "0", Path(root) / "sparse"):
        if model_format(folder):
            return folder
    return None


def listing(folder: Path, n: int = 12) -> str:
    """The entries of ``folder`` for an error message (folders end in '/')."""
    if not folder.is_dir():
        return f"{folder} does not exist"
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir())
    return ", ".join(names[:n]) + (f" (and {len(names) - n} more)" if len(names) > n else "") if names else "nothing"


def model_dir(root: str | os.PathLike) -> Path:
    """:func:`find_model`, or a FileNotFoundError saying what the folder holds instead."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"scene folder {root} does not exist (expected images/ + sparse/0/)")
    folder = find_model(root)
    if folder is None:
        where = root / "sparse" / "0" if (root / "sparse" / "0").is_dir() else root / "sparse"
        raise FileNotFoundError(
            f"{root}: no COLMAP model in sparse/0/ or sparse/ (need cameras, images and "
            f"points3D, all .bin or all .txt); {where} holds: {listing(where)}"
        )
    return folder


def read_model(folder: Path) -> pycolmap.Reconstruction:
    """The COLMAP model of ``folder`` (binary or text, see :func:`model_format`)."""
    fmt = model_format(folder)
    rec = pycolmap.Reconstruction()
    try:
        (rec.read_binary if fmt == "bin" else rec.read_text)(str(folder))
    except (RuntimeError, ValueError, IndexError, OSError) as e:  # pycolmap: failed checks, bad indices
        raise ValueError(f"cannot read the COLMAP model {folder}/*.{fmt}: {e}") from None
    return rec


def distortion(camera: pycolmap.Camera) -> dict[str, float]:
    """The extra (distortion) parameters of ``camera`` by name, e.g. {"k1": 0.02, "k2": 0.0}."""
    names = [s.strip() for s in camera.params_info.split(",")]
    return {names[i]: float(camera.params[i]) for i in camera.extra_params_idxs()}


def needs_undistortion(camera: pycolmap.Camera) -> bool:
    """False for a pinhole camera (PINHOLE, SIMPLE_PINHOLE, or a radial/OpenCV one without distortion)."""
    model = camera.model.name
    if model in PINHOLE_MODELS:
        return False
    return model not in PINHOLE_WITHOUT_DISTORTION or any(v != 0.0 for v in distortion(camera).values())


def describe(camera: pycolmap.Camera) -> str:
    """``camera 1: OPENCV 640x480 fx=500, fy=500, cx=320, cy=240, k1=0.05, ...``"""
    names = [s.strip() for s in camera.params_info.split(",")]
    params = ", ".join(f"{k}={v:g}" for k, v in zip(names, camera.params))
    return f"camera {camera.camera_id}: {camera.model.name} {camera.width}x{camera.height} {params}"


def model_counts(cameras: list[pycolmap.Camera]) -> dict[str, int]:
    """How many of ``cameras`` (one entry per view or per camera) use each camera model."""
    names = [c.model.name for c in cameras]
    return {name: names.count(name) for name in sorted(set(names))}


def describe_some(cameras: list[pycolmap.Camera], n: int = 3) -> str:
    """The first ``n`` cameras described, and how many more there are."""
    more = f" (and {len(cameras) - n} more)" if len(cameras) > n else ""
    return "; ".join(describe(c) for c in cameras[:n]) + more


def refuse_distortion(cameras: list[pycolmap.Camera], folder: Path, root: Path) -> None:
    """Raise a ValueError naming every distorted camera and how to undistort the scene."""
    fmt = model_format(folder)
    raise ValueError(
        f"{folder}/cameras.{fmt}: {describe_some(cameras)}. spc3d reads pinhole cameras only "
        f"({', '.join(PINHOLE_MODELS)}, or {', '.join(PINHOLE_WITHOUT_DISTORTION)} with all distortion parameters "
        f"0). Undistort the scene first: read it with undistort=True (scene key 'undistort: true'), or run "
        f"`colmap image_undistorter --image_path {root / 'images'} --input_path {folder} --output_path OUT "
        f"--output_type COLMAP` and read OUT (its images/ + sparse/ are a COLMAP-format scene)"
    )


def registered_views(rec: pycolmap.Reconstruction, folder: Path) -> list[pycolmap.Image]:
    """The posed images of the model, in canonical order (by ``{stem}.png``); stems must be unique."""
    views = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: f"{Path(im.name).stem}.png")
    if not views:
        raise ValueError(f"{folder}: the COLMAP model has no registered image ({rec.num_images()} images listed)")
    twins = sorted(s for s, k in Counter(Path(im.name).stem for im in views).items() if k > 1)
    if twins:
        raise ValueError(
            f"{folder}: several images share the file stem(s) {twins[:5]}; the views of a scene are "
            f"named by stem, so rename them apart"
        )
    return views


def check_cameras(views: list[pycolmap.Image], folder: Path) -> tuple[int, int]:
    """(height, width) shared by the cameras of ``views``; a ValueError names cameras of other sizes."""
    cams = list({im.camera_id: im.camera for im in views}.values())
    sizes = {(c.height, c.width) for c in cams}
    if len(sizes) > 1:
        raise ValueError(
            f"{folder}: the views' cameras differ in image size ({describe_some(cams, 6)}); the views "
            f"of a scene must share one size"
        )
    return sizes.pop()


def view_files(image_dir: Path, views: list[pycolmap.Image]) -> list[Path]:
    """The image file of every view; a FileNotFoundError names the missing ones."""
    files = [image_dir / im.name for im in views]
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(
            f"{image_dir}: {len(missing)} image(s) of the COLMAP model missing, e.g. {missing[:5]} "
            f"(the folder holds: {listing(image_dir)})"
        )
    return files


def loaded_size(files: list[Path], height: int, width: int, factor: int, folder: Path) -> tuple[int, int]:
    """(h, w) of the views at ``factor``: the cameras' size at factor 1, within a pixel of size / factor else."""
    llff.check_image_headers(files)
    h, w, _ = io.image_shape(files[0])
    exact = (h, w) == (height, width)
    near = abs(h * factor - height) < factor and abs(w * factor - width) < factor
    if not (exact if factor == 1 else near):
        want = f"{width}x{height}" if factor == 1 else f"{width / factor:g}x{height / factor:g} (+-1)"
        raise ValueError(
            f"{files[0]} is {w}x{h} pixels but the cameras of {folder} are {width}x{height}, so "
            f"images at factor {factor} must be {want}; choose the factor of that image folder"
        )
    return h, w


def check_observations(rec: pycolmap.Reconstruction, views: list[pycolmap.Image], folder: Path) -> None:
    """Every 3-D point a view observes exists in the model (else points3D is truncated or mismatched)."""
    for im in views:
        lost = [p.point3D_id for p in im.get_observation_points2D() if not rec.exists_point3D(p.point3D_id)]
        if lost:
            raise ValueError(
                f"{folder}: image {im.name!r} observes 3-D point(s) {lost[:5]} that the model's points3D "
                f"lacks ({len(lost)} in all): a truncated or mismatched points3D file"
            )


def model_cameras(rec: pycolmap.Reconstruction, names: list[str], height: int, width: int, folder: Path) -> Cameras:
    """Cameras of views ``names`` (all registered) with bounds from their observed points, checked."""
    like = Cameras(np.zeros((0, 3, 4)), np.zeros((0, 4)), height, width, np.zeros((0, 2)))
    cams, _ = colmap.reconstruction_cameras(rec, names, like)
    near, far = cams.bounds.T
    bad = np.flatnonzero(~(np.isfinite(near) & (near > 0) & (far > near)))
    if bad.size:
        i = bad[0]
        raise ValueError(
            f"{folder}: view {names[i]!r} (and {bad.size - 1} more) gets bounds near={near[i]:g}, "
            f"far={far[i]:g} from the 3-D points it observes; need observed points in front of the "
            f"camera (0 < near < far): a model without points3D or observations has no bounds"
        )
    return cams


def read_resized(files: list[Path], height: int, width: int) -> np.ndarray:
    """(N, height, width, 3) float32 sRGB views, each area-resampled as it is read (one full-size
    image in memory at a time)."""
    out = np.empty((len(files), height, width, 3), np.float32)
    for i, f in enumerate(files):
        img = llff.read_views([f])[0]
        if img.shape[:2] != (height, width):
            Ay, Ax = llff.area_matrix(img.shape[0], height), llff.area_matrix(img.shape[1], width)
            img = np.einsum("yh,hwc,xw->yxc", Ay, img, Ax, optimize=True)
        out[i] = img
    return out


def load_colmap(
    root: str | os.PathLike, factor: int = 1, width: int | None = None, undistort: bool = False
) -> SceneData:
    """Read a COLMAP-format scene at ``factor`` (``images/`` or ``images_{factor}/``), area-downscaled
    to ``width`` (aspect kept) if given. ``undistort``: resample distorted cameras to PINHOLE first
    (factor 1 only); without it they are refused. See the module docstring for what is read."""
    root = Path(root)
    folder = model_dir(root)
    rec = read_model(folder)
    views = registered_views(rec, folder)
    distorted = [c for c in {im.camera_id: im.camera for im in views}.values() if needs_undistortion(c)]
    if distorted and not undistort:
        refuse_distortion(distorted, folder, root)
    if distorted:
        return load_undistorted(root, folder, distorted, factor, width)
    cam_h, cam_w = check_cameras(views, folder)
    check_observations(rec, views, folder)
    files = view_files(llff.image_folder(root, factor), views)
    h, w = loaded_size(files, cam_h, cam_w, factor, folder)
    names = [f.stem for f in files]
    cams = model_cameras(rec, names, cam_h, cam_w, folder)
    out_h, out_w = (max(1, int(round(width * h / w))), width) if width else (h, w)
    meta = {"source": str(root), "factor": factor, "colmap": model_record(rec, folder, views, files)}
    if meta["colmap"]["images_not_read"]:
        log.warning(
            "%s: %d image(s) without a pose in the COLMAP model are left out, e.g. %s",
            files[0].parent,
            len(meta["colmap"]["images_not_read"]),
            meta["colmap"]["images_not_read"][:3],
        )
    return SceneData(read_resized(files, out_h, out_w), cams.rescaled(out_h, out_w), names, meta=meta)


def model_record(rec: pycolmap.Reconstruction, folder: Path, views: list[pycolmap.Image], files: list[Path]) -> dict:
    """What was read, for ``scene.json``: model folder and format, cameras, points, left-out images."""
    listed = {f.name for f in files}
    others = sorted(p.name for p in io.list_images(files[0].parent) if p.name not in listed)
    return {
        "model": str(folder),
        "format": model_format(folder),
        "points3D": int(rec.num_points3D()),
        "camera_models": model_counts([im.camera for im in views]),
        "bounds": BOUNDS_RULE,
        "unregistered": sorted(im.name for im in rec.images.values() if not im.has_pose),
        "images_not_read": others,
    }


def undistort_scene(root: Path, folder: Path, out: Path, num_threads: int = 1) -> Path:
    """Undistort the views of ``root/images`` with the model ``folder`` into ``out`` (images/ + sparse/,
    PINHOLE cameras), by pycolmap's image undistorter on the CPU; its log goes to ``out/undistort.log``."""
    out.mkdir(parents=True, exist_ok=True)
    with colmap.native_log_to(out / "undistort.log"):
        pycolmap.undistort_images(out, folder, llff.image_folder(root, 1), num_threads=num_threads)
    return out


def load_undistorted(
    root: Path, folder: Path, distorted: list[pycolmap.Camera], factor: int, width: int | None
) -> SceneData:
    """:func:`load_colmap` of the undistorted copy of ``root`` (made in a temporary folder)."""
    if factor != 1:
        raise ValueError(
            f"{root}: undistortion resamples the full-size images/ with the model's cameras; "
            f"read it at factor 1 (with a working width) instead of factor {factor}"
        )
    with tempfile.TemporaryDirectory(prefix="spc3d-undistort-") as tmp:
        scene = load_colmap(undistort_scene(root, folder, Path(tmp)), 1, width)
    record = {
        **scene.meta["colmap"],
        "model": str(folder),
        "format": model_format(folder),
        "undistorted_from": {"camera_models": model_counts(distorted), "first": describe(distorted[0])},
    }
    scene.meta = {**scene.meta, "source": str(root), "colmap": record}
    return scene

"""A captured SPAD scene (:mod:`spc3d.captures.folders`) into the workflow: the scene folder and the SPC
folder every combination reads, as a simulated scene has them.

``import_capture_scene`` (rule ``prepare_scene``, spec kind ``capture``) writes
``results/scenes/{scene}`` in the canonical LLFF layout (:mod:`spc3d.llff`):

- **cameras** from the capture's ``poses_bounds.npy`` (and ``intrinsics.npy``) when it has them;
  otherwise from COLMAP on every view's MLE image of all its frames (the photons are all a SPAD
  user has), with the intrinsics of ``sensor.json`` ``"intrinsics": [fx, fy, cx, cy]`` (pixels,
  held fixed) or, without them, a focal length of 1.2 x the larger side refined by bundle adjustment.
  Views COLMAP cannot pose are left out of the scene (``scene.json`` lists them), as LLFF's own
  ``imgs2poses`` does; such a scene's "ground-truth" poses are these estimates, and its rows say so.
- **reference views** from ``images/`` when the capture has them; without them the scene has no
  ``images/`` and says ``"reference": false``: its rows get renders and no-reference statistics.

``import_capture_frames`` (rule ``simulate_scene``, for a capture) writes ``results/spc/{scene}``:

    frames/{view}.npz    the capture's K frames, bool (K, H, W): one bit per pixel (the mosaic)
    binary/{view}.png    frame 0 demosaiced (the sensor's one-frame image: source ``none``)
    capture/{view}.png   the same, 16-bit: a capture has no higher resolution (``capture_factor`` 1)
    average/{view}.png   the demosaiced K-frame mean (hot pixels filled from their neighbours)
    mle/{view}.exr       the demosaiced MLE flux of the K frames (spc3d.physics.sensors.mle_rgb)
    hot_pixels.png       hot pixels detected from the training views' counts, with sensor.json's map
    spc.json             the sensor (q, T, dcr, CFA), hot-pixel report, detection rates, the
                         scored views (``held_out_views``: they set no hot pixel);
                         ``flux_scale`` null, and an ``exposure`` block metered from the
                         training views (the capture reports none: :func:`metered_exposure`)

Stage 1 and stage 2 read the sensor back with :func:`spc_sensor`: a folder without it holds the
simulator's RGB frames (K, H, W, 3), one bit per channel and pixel.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from spc3d import io, llff
from spc3d.cameras import Cameras, split_views
from spc3d.captures.folders import (
    capture_hot_pixels,
    capture_views,
    check_capture_folder,
    read_capture,
    read_sensor,
    reference_images,
)
from spc3d.captures.plausibility import capture_warnings
from spc3d.inputs.exposure import PREVIEW_LEVEL, display_srgb, metered_gain
from spc3d.physics import sensors, spc
from spc3d.physics.flux_scale import dark_floor
from spc3d.physics.hot_pixels import write_hot_pixel_map
from spc3d.physics.record import HOT_FILE, exposure_record, frame_warnings

log = logging.getLogger(__name__)

FOCAL_GUESS = 1.2  # COLMAP's own prior without EXIF: focal = 1.2 x the larger image side
MIN_POSED = 3  # fewer posed views give no scene worth training on (and no train/test split)
# --------------------------------------------------------------------------------------------
# the scene folder


def import_capture_scene(
    folder: str | os.PathLike,
    out_dir: str | os.PathLike,
    max_features: int = 4096,
    seed: int = 0,
    num_threads: int = 1,
    overrides: dict | None = None,
) -> dict:
    """Write the canonical scene folder of capture ``folder`` into ``out_dir``; return scene.json's
    record. ``overrides``: the config's sensor settings (:func:`spc3d.captures.folders.read_sensor`)."""
    t0 = time.perf_counter()
    folder = Path(folder)
    sensor = read_sensor(folder, overrides)
    names = capture_views(folder, sensor.format)
    refs = reference_images(folder, names)
    if refs is not None and refs.shape[1:3] != (sensor.height, sensor.width):
        raise ValueError(
            f"{folder}/images: reference views are {refs.shape[2]}x{refs.shape[1]} but the sensor is "
            f"{sensor.width}x{sensor.height} (sensor.json); give them at the sensor's size"
        )
    if (folder / "poses_bounds.npy").is_file():
        cams, poses = given_cameras(folder, len(names), sensor.height, sensor.width), {"source": "poses_bounds.npy"}
    else:  # the frames are read only here: given poses need just the view names
        names, cubes, sensor = read_capture(folder, overrides=overrides)
        cams, keep, poses = photon_cameras(names, cubes, sensor, folder, max_features, seed, num_threads)
        names, refs = [names[i] for i in keep], None if refs is None else refs[keep]
    record = {
        "source": "capture",
        "path": str(folder),
        "sensor": sensor.cfa.name,
        "colour": sensor.cfa.colour,  # False (mono, all-W): rows are scored by luminance (spc3d.evaluation.evaluate)
        "poses": poses,
        "settings": {"max_features": max_features},
        "seed": seed,
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    llff.write_scene(out_dir, llff.SceneData(refs, cams, names), record)
    log.info(
        "capture %s: %d views at %dx%d, poses from %s, %s reference views",
        folder,
        len(names),
        sensor.width,
        sensor.height,
        poses["source"],
        "with" if refs is not None else "no",
    )
    return record


def given_cameras(folder: Path, views: int, height: int, width: int) -> Cameras:
    """The capture's own poses_bounds.npy (one row per view in name order), checked."""
    path = folder / "poses_bounds.npy"
    pb = io.load_npy(path)
    llff.check_poses_bounds(pb, path)
    if len(pb) != views:
        raise ValueError(f"{path} has {len(pb)} rows but {folder}/frames holds {views} views; one row per view")
    return llff.llff_cameras(folder, pb, height, width)


def first_intrinsics(sensor, where: Path) -> tuple[np.ndarray, bool]:
    """(fx, fy, cx, cy) and whether they are a guess to refine: sensor.json's, or 1.2 x the larger side."""
    given = sensor.record.get("intrinsics")
    if given is None:
        f = FOCAL_GUESS * max(sensor.width, sensor.height)
        return np.array([f, f, sensor.width / 2, sensor.height / 2]), True
    try:
        values = np.asarray(given, dtype=np.float64)
    except (TypeError, ValueError):
        values = np.full(1, np.nan)  # not numbers: refused below with the file and key
    if values.shape != (4,) or not np.isfinite(values).all() or (values[:2] <= 0).any():
        raise ValueError(f"{where}: intrinsics={given!r} must be [fx, fy, cx, cy] in pixels with fx, fy > 0")
    return values, False


def photon_cameras(
    names: list[str], cubes: list[np.ndarray], sensor, folder: Path, max_features: int, seed: int, num_threads: int
) -> tuple[Cameras, np.ndarray, dict]:
    """COLMAP on every view's MLE image of all its frames: (cameras of the posed views, their
    indices into ``names``, the record). Raises when fewer than :data:`MIN_POSED` are posed."""
    from spc3d.poses.colmap import reconstruction_cameras, run_colmap  # pycolmap: only captures without poses need it
    from spc3d.poses.estimate import filled_bounds

    intrinsics, guess = first_intrinsics(sensor, folder / "sensor.json")
    h, w, k = sensor.height, sensor.width, sensor.params.frames
    like = Cameras(np.zeros((1, 3, 4)), intrinsics[None], h, w, np.ones((1, 2)))
    flux = mle_previews(cubes, sensor)
    gain = metered_gain(flux, PREVIEW_LEVEL)
    with tempfile.TemporaryDirectory(prefix="spc3d-capture-poses-") as tmp:
        images = Path(tmp) / "images"
        for name, phi in zip(names, flux):
            io.write_image(images / f"{name}.png", display_srgb(phi, gain))
        rec = run_colmap(images, Path(tmp) / "work", like, max_features, seed, num_threads, refine_focal=guess)
    cams, idx = reconstruction_cameras(rec, names, like) if rec is not None else (None, np.zeros(0, int))
    if len(idx) < MIN_POSED:
        raise RuntimeError(
            f"capture {folder}: COLMAP posed {len(idx)} of {len(names)} views from their {k}-frame MLE images "
            f"(needs {MIN_POSED}); give poses_bounds.npy, sensor.json intrinsics, or more frames per view"
        )
    cams, posed = Cameras(cams.w2c, cams.intrinsics, h, w, filled_bounds(cams.bounds)), set(idx.tolist())
    record = {
        "source": f"COLMAP on every view's MLE image of its {k} frames (no poses_bounds.npy)",
        "frames": k,
        "registered": int(len(idx)),
        "total": len(names),
        "left_out": [n for i, n in enumerate(names) if i not in posed],
        "intrinsics": "refined from a focal guess of 1.2 x the larger side" if guess else "sensor.json, fixed",
        "focal_px": float(cams.intrinsics[0, 0]),
    }
    return cams, idx, record


def mle_previews(cubes: list[np.ndarray], sensor) -> np.ndarray:
    """(N, H, W, 3) demosaiced MLE flux of every view's frames, hot pixels (detected, and sensor.json's) filled."""
    counts = [c.sum(0, dtype=np.int64) for c in cubes]
    hot, _ = capture_hot_pixels(counts, sensor)
    return np.stack([sensors.mle_rgb(c, sensor.params.frames, sensor.params, sensor.cfa, hot) for c in counts])


# --------------------------------------------------------------------------------------------
# the SPC folder


def import_capture_frames(
    folder: str | os.PathLike, scene_dir: str | os.PathLike, out_dir: str | os.PathLike, overrides: dict | None = None
) -> dict:
    """Write the SPC folder of capture ``folder`` for the views of ``scene_dir``; return spc.json's
    record. ``overrides``: the config's sensor settings (:func:`spc3d.captures.folders.read_sensor`)."""
    t0 = time.perf_counter()
    folder = Path(folder)
    views = llff.read_scene(scene_dir, with_images=False).names
    names, cubes, sensor = read_capture(folder, overrides=overrides)
    index = {n: i for i, n in enumerate(names)}
    cubes = [cubes[index[v]] for v in views]
    params, pattern, k = sensor.params, sensor.cfa, sensor.params.frames
    counts = [c.sum(0, dtype=np.int64) for c in cubes]
    total = sum(counts)
    train, test = split_views(len(views))
    hot, hot_record = capture_hot_pixels([counts[i] for i in train], sensor)  # the scored views stay unseen
    flux = [sensors.mle_rgb(s, k, params, pattern, hot).astype(np.float32) for s in counts]
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for view, cube, phi in zip(views, cubes, flux):
            io.save_frames(tmp / "frames" / f"{view}.npz", *spc.pack_frames(cube))
            binary = sensors.sensor_input(cube[:1], pattern, ~hot)
            io.write_image(tmp / "binary" / f"{view}.png", binary)
            io.write_image(tmp / "capture" / f"{view}.png", binary, bits=16)
            average = sensors.demosaic_average(cube, pattern, ~hot)
            io.write_image(tmp / "average" / f"{view}.png", np.clip(average, 0.0, 1.0).astype(np.float32), bits=16)
            io.write_image(tmp / "mle" / f"{view}.exr", phi)
        write_hot_pixel_map(tmp / HOT_FILE, hot)
        record = {
            "scene": Path(out_dir).name,
            "capture": str(folder),
            "params": asdict(params),
            "sensor": {"cfa": pattern.to_json(), "white": pattern.white, "name": pattern.name},
            "sensor_from_config": {k: sensor.record[k] for k in (overrides or {})},
            "sensor_json_values": sensor.record.get("overridden"),
            "exposure": metered_exposure([flux[i] for i in train], params),
            "flux_scale": None,
            "flux_scale_calibrated": False,
            "target_detection": None,
            "seed": None,
            "views": len(views),
            "held_out_views": [views[i] for i in test],
            "capture_factor": 1,
            "mean_detection_rate": float((total / (k * len(cubes)))[~hot].mean()),
            "mean_saturated_fraction": float(np.mean([(c == k)[~hot].mean() for c in counts])),
            "hot_pixels": {
                **{k_: v for k_, v in hot_record.items() if k_ not in ("rates", "neighbour_rates", "z")},
                "count": int(hot.sum()),
                "from_sensor_json": sensor.hot_pixels is not None,
            },
            "wall_s": round(time.perf_counter() - t0, 3),
        }
        saturated = record["mean_saturated_fraction"]
        record["warnings"] = capture_warnings(sensor) + frame_warnings(
            record["mean_detection_rate"], dark_floor(params), saturated
        )
        for warning in record["warnings"]:
            log.warning("capture %s: %s", folder, warning)
        io.write_json(tmp / "spc.json", record)
    log.info("capture %s: %d views, K = %d, %d hot pixels", folder, len(views), k, int(hot.sum()))
    return record


def metered_exposure(flux: list[np.ndarray], params: spc.SPCParams) -> dict:
    """The exposure block of a capture, which reports none: the training views' mean MLE flux
    shown at 18 % linear grey (:data:`spc3d.inputs.exposure.PREVIEW_LEVEL`), as a camera's display
    meters; the scored views do not take part."""
    mean = float(np.mean([f.mean(dtype=np.float64) for f in flux]))
    if not mean > 0:
        raise ValueError(
            "the capture's training views hold no detection above the dark counts (mean MLE flux 0): "
            "nothing to expose for; check the capture (lens cap on?)"
        )
    photons = params.q * params.exposure_s * mean / PREVIEW_LEVEL
    return exposure_record(photons, "metered", level=PREVIEW_LEVEL, metered_views=len(flux))


# --------------------------------------------------------------------------------------------
# reading it back


def capture_sensor(folder: str | os.PathLike, overrides: dict | None = None) -> tuple[str, dict]:
    """(tag, spec) of a capture folder's sensor, read at parse time: the tag names its translators'
    folder (``rggb``, ``mono``, ``rgbwmean``, ``custom<hash>``: one training per sensor, whatever
    the captures), the spec ``{"cfa": ..., "white": ...}`` rebuilds the pattern (sensors.cfa_pattern).
    The folder is checked against sensor.json from headers and listings (:func:`check_capture_folder`)."""
    sensor = read_sensor(folder, overrides)
    check_capture_folder(folder, sensor)
    pattern = sensor.cfa
    return sensor_tag(pattern), {"cfa": pattern.to_json(), "white": pattern.white}


def sensor_tag(pattern: sensors.CFAPattern) -> str:
    white = "" if pattern.white == "sum" else pattern.white
    if pattern.name != "custom":
        return pattern.name.lower() + white
    import hashlib

    return "custom" + hashlib.sha1(np.ascontiguousarray(pattern.tile).tobytes()).hexdigest()[:8] + white

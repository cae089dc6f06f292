"""Captured SPAD scenes: the folder a SPAD user brings, read back; simulated scenes exported to it.

Folder layout (``{capture}/``; view names are the file stems, views in name order, as LLFF's
``images/``: the rows of ``poses_bounds.npy`` follow it)::

    sensor.json               required: the sensor (below)
    frames/{view}.npy         one photon cube per view, all views in one format
                              (spc3d.captures.photon_cubes): bit-packed uint8 (K, H, ceil(W/8)) .npy,
    frames/{view}.npy.gz      the same gzip-compressed,
    frames/{view}/NNNN.png    a folder of 0/255 single-channel PNG frames, or
    frames/{view}.npz         the project's packed .npz (spc3d.io.save_frames) of shape (K, H, W)
    images/{view}.png         optional: reference RGB views (metrics need them; without them a
                              scene gets outputs and no-reference statistics only)
    poses_bounds.npy          optional: LLFF poses, one row per view in view order
    sparse/0/                 optional: a COLMAP model of the views (not read here)
    hot_pixels.png            optional: known hot-pixel map (H, W), nonzero = hot (or a .npy;
                              named by sensor.json "hot_pixels")
    cfa.png                   optional: the CFA tile image when sensor.json "cfa" names a file

``sensor.json``::

    {
      "format": "npy.gz",          # npy | npy.gz | png | npz (the frames/ entries must match)
      "width": 127, "height": 96,  # the true sensor size (the .npy rows carry ceil(width/8) bytes)
      "frames": 64,                # K per view (every view must hold at least this many)
      "bitorder": "big",           # bit order of .npy/.npy.gz rows (big: the SwissSPAD2 .npy layout)
      "cfa": "RGGB",               # mono | RGGB | BGGR | GRBG | GBRG | RGBW | a tile file in the
                                   # folder ("cfa.png") | nested 0/255 RGB pixels [[[255,0,0],...],...]
      "white": "sum",              # how W pixels weigh the channels (spc3d.physics.sensors): sum | mean
      "q": 0.45, "exposure_s": 1e-4, "dark_count_rate": 100.0,   # required physics
      "tau_d": 1.5e-7,             # optional dead time (default 0: it does not change a 1-bit frame)
      "hot_pixels": "hot_pixels.png",   # optional
      "source": {...}              # optional, free-form provenance (an export records its simulation)
    }

A simulated scene (``results/spc/{scene}/``, simulator RGB frames (K, H, W, 3)) is exported with
:func:`export_simulated`; :func:`read_capture` reads either kind back, so the import path is tested
end to end on data whose truth is known.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.captures import photon_cubes
from spc3d.inputs.exposure import PREVIEW_LEVEL, display_srgb, metered_gain
from spc3d.physics import sensors, spc
from spc3d.physics.hot_pixels import detect_hot_pixels, read_hot_pixel_map, write_hot_pixel_map

SENSOR_FILE = "sensor.json"
REQUIRED_KEYS = ("format", "width", "height", "frames", "cfa", "q", "exposure_s", "dark_count_rate")


@dataclass(frozen=True, eq=False)
class CaptureSensor:
    """What ``sensor.json`` says, checked and resolved."""

    params: spc.SPCParams  # q, tau_d, exposure_s, dark_count_rate; frames = K per view
    cfa: sensors.CFAPattern
    width: int
    height: int
    format: str
    bitorder: str = "big"
    hot_pixels: np.ndarray | None = None  # (H, W) bool, the known map (None: none given)
    record: dict = dataclasses.field(default_factory=dict)  # sensor.json as read


# --------------------------------------------------------------------------------------------
# sensor.json


def sensor_record(
    params: spc.SPCParams,
    cfa: sensors.CFAPattern,
    width: int,
    height: int,
    fmt: str,
    bitorder: str = "big",
    hot_pixels: str | None = None,
    source: dict | None = None,
) -> dict:
    """The ``sensor.json`` contents for these settings."""
    rec = {
        "format": fmt,
        "width": int(width),
        "height": int(height),
        "frames": params.frames,
        "bitorder": bitorder,
        "cfa": cfa.to_json(),
        "white": cfa.white,
        "q": params.q,
        "exposure_s": params.exposure_s,
        "dark_count_rate": params.dark_count_rate,
        "tau_d": params.tau_d,
    }
    if hot_pixels is not None:
        rec["hot_pixels"] = hot_pixels
    if source is not None:
        rec["source"] = source
    return rec


OVERRIDABLE = ("q", "exposure_s", "dark_count_rate", "tau_d", "hot_pixels")  # sensor settings the config may set


def read_sensor(folder: str | os.PathLike, overrides: dict | None = None) -> CaptureSensor:
    """Read and check ``{folder}/sensor.json``; errors name the file and the key. ``overrides``
    (the config's per-capture sensor settings, :data:`OVERRIDABLE`) replace its values and are
    recorded (``record["overridden"]``); a relative ``hot_pixels`` is taken from the folder."""
    folder = Path(folder)
    path = folder / SENSOR_FILE
    rec = io.read_json(path)
    if overrides:
        unknown = sorted(set(overrides) - set(OVERRIDABLE))
        if unknown:
            raise ValueError(f"sensor settings {unknown} for {folder}: the config may set {list(OVERRIDABLE)}")
        rec = {**rec, **overrides, "overridden": {k: rec.get(k) for k in overrides}}
    missing = [k for k in REQUIRED_KEYS if k not in rec]
    if missing:
        raise ValueError(f"{path}: missing keys {missing}; a capture's sensor.json needs {list(REQUIRED_KEYS)}")
    fmt = photon_cubes.check_choice(f"{path}: format", rec["format"], photon_cubes.FORMATS)
    bitorder = photon_cubes.check_choice(f"{path}: bitorder", rec.get("bitorder", "big"), photon_cubes.BITORDERS)
    width, height, frames = (_positive_int(path, k, rec[k]) for k in ("width", "height", "frames"))
    try:
        params = spc.SPCParams(
            q=rec["q"],
            exposure_s=rec["exposure_s"],
            dark_count_rate=rec["dark_count_rate"],
            tau_d=rec.get("tau_d", 0.0),
            frames=frames,
        )
        cfa = sensors.cfa_pattern(_cfa_spec(folder, rec["cfa"]), rec.get("white", "sum"))
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e
    hot = None
    if rec.get("hot_pixels"):
        hot = read_hot_pixel_map(folder / rec["hot_pixels"], (height, width))
    return CaptureSensor(params, cfa, width, height, fmt, bitorder, hot, rec)


def _positive_int(path: Path, key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{path}: {key}={value!r} must be a positive integer")
    return value


def _cfa_spec(folder: Path, spec):
    """A "cfa" entry that names a file is resolved against the capture folder."""
    if isinstance(spec, str) and Path(spec).suffix:
        if not (folder / spec).is_file():
            raise FileNotFoundError(f"{folder / SENSOR_FILE}: cfa names {spec}, which is not in {folder}")
        return folder / spec
    return spec


# --------------------------------------------------------------------------------------------
# reading


def capture_views(folder: str | os.PathLike, fmt: str) -> list[str]:
    """View names of ``{folder}/frames`` in format ``fmt``, in name order (LLFF's view order)."""
    frames_dir = Path(folder) / "frames"
    if not frames_dir.is_dir():
        raise FileNotFoundError(f"capture {folder}: no frames/ folder (one photon cube per view)")
    ending = {"npy": ".npy", "npy.gz": ".npy.gz", "npz": ".npz"}.get(fmt)
    if ending is None:
        views = [p.name for p in frames_dir.iterdir() if p.is_dir() and not p.name.startswith(".")]
    else:
        views = [
            p.name[: -len(ending)]
            for p in frames_dir.iterdir()
            if p.name.lower().endswith(ending) and not p.name.startswith(".")
        ]
    if not views:
        others = sorted(p.name for p in frames_dir.iterdir())[:5]
        raise FileNotFoundError(f"{frames_dir}: no views in format {fmt!r} (sensor.json); found {others}")
    return sorted(views)


def check_capture_folder(folder: str | os.PathLike, sensor: CaptureSensor) -> list[str]:
    """A capture folder against its sensor.json, from headers and listings (no frame is read): every
    view's cube of the sensor's size with at least ``frames`` frames, a reference image for every
    view when ``images/`` exists, one ``poses_bounds.npy`` row per view. Returns the view names;
    raises ValueError / FileNotFoundError naming the file, what it holds and what was expected."""
    folder = Path(folder)
    names = capture_views(folder, sensor.format)
    packed = sensor.format in ("npy", "npy.gz")
    want_w = -(-sensor.width // 8) if packed else sensor.width
    for view in names:
        path = photon_cubes.cube_path(folder / "frames", view, sensor.format)
        k, h, w = photon_cubes.cube_header(path)
        if (h, w) != (sensor.height, want_w):
            swapped = (h, w) == (sensor.width, -(-sensor.height // 8) if packed else sensor.height)
            unit = f" ({want_w} bytes of bit-packed rows for {sensor.width} pixels)" if packed else ""
            raise ValueError(
                f"{path}: frames of {h} rows x {w} {'bytes' if packed else 'columns'}; sensor.json says "
                f"height {sensor.height}, width {sensor.width}{unit}"
                + ("; width and height look swapped" if swapped else "")
            )
        if k < sensor.params.frames:
            raise ValueError(
                f"{path}: {k} frames; sensor.json says every view holds at least frames = {sensor.params.frames} "
                "(lower frames there to what every view holds)"
            )
    images = folder / "images"
    if images.is_dir():
        have = {p.stem for p in images.iterdir() if not p.name.startswith(".")}
        missing = [n for n in names if n not in have]
        if missing:
            raise FileNotFoundError(
                f"{images}: no reference image for view(s) {missing[:5]}; every view of frames/ needs one "
                "(or remove images/ to score without references)"
            )
    poses = folder / "poses_bounds.npy"
    if poses.is_file():
        rows = io.load_npy(poses, mmap=True).shape[0]
        if rows != len(names):
            raise ValueError(f"{poses}: {rows} rows of poses for {len(names)} views in frames/; one row per view")
    return names


def read_capture(
    folder: str | os.PathLike, max_frames: int | None = None, overrides: dict | None = None
) -> tuple[list[str], list[np.ndarray], CaptureSensor]:
    """(view names, photon cubes bool (K, H, W) per view, sensor) of a capture folder.

    Every cube must be ``height`` x ``width`` and hold at least ``frames`` (sensor.json) frames;
    the first ``frames`` (or ``max_frames``, if fewer) are returned. ``overrides``: see :func:`read_sensor`.
    """
    folder = Path(folder)
    sensor = read_sensor(folder, overrides)
    k = sensor.params.frames if max_frames is None else min(max_frames, sensor.params.frames)
    names = capture_views(folder, sensor.format)
    cubes = []
    for view in names:
        path = photon_cubes.cube_path(folder / "frames", view, sensor.format)
        cube = photon_cubes.read_cube(path, sensor.width, sensor.bitorder, k)
        if cube.shape[1:] != (sensor.height, sensor.width) or cube.shape[0] < k:
            raise ValueError(
                f"{path}: {cube.shape[0]} frames of {cube.shape[2]}x{cube.shape[1]} (WxH); "
                f"sensor.json says {k} frames of {sensor.width}x{sensor.height}"
            )
        cubes.append(cube)
    if k != sensor.params.frames:
        sensor = dataclasses.replace(sensor, params=dataclasses.replace(sensor.params, frames=k))
    return names, cubes, sensor


def reference_images(folder: str | os.PathLike, names: list[str]) -> np.ndarray | None:
    """(N, H, W, 3) reference RGB of every view from ``images/``, or None when the folder has none."""
    images = Path(folder) / "images"
    if not images.is_dir():
        return None
    files = {p.stem: p for p in io.list_images(images)}
    missing = [n for n in names if n not in files]
    if missing:
        raise FileNotFoundError(f"{images}: no reference image for views {missing[:5]}; give one per view or none")
    return np.stack([io.read_rgb(files[n]) for n in names])


def capture_hot_pixels(
    counts: list[np.ndarray], sensor: CaptureSensor, threshold: float = 6.0
) -> tuple[np.ndarray, dict]:
    """(hot (H, W) bool, detection record): detected from the ones ``counts`` of every view
    (:func:`spc3d.physics.hot_pixels.detect_hot_pixels`), united with the sensor's own map."""
    hot, record = detect_hot_pixels(sum(counts), sensor.params.frames * len(counts), sensor.cfa, threshold)
    return (hot if sensor.hot_pixels is None else hot | sensor.hot_pixels), record


# --------------------------------------------------------------------------------------------
# a first look at a capture: hot pixels, detection rates, MLE previews


def inspect_capture(
    folder: str | os.PathLike,
    out_dir: str | os.PathLike,
    max_frames: int | None = None,
    level: float = PREVIEW_LEVEL,
    threshold: float = 6.0,
) -> dict:
    """Check a capture folder and write what a SPAD user looks at first into ``out_dir``.

    ``hot_pixels.png``  hot pixels detected from the counts of every view (robust z-score above
                        ``threshold`` against same-colour neighbours), united with sensor.json's map
    ``preview/*.png``   each view's demosaiced MLE flux (hot pixels excluded), shown at one gain
                        metered from all views (mean flux at linear ``level``): no reference needed
    ``capture.json``    the sensor, views, frames used, detection rate per CFA colour, hot pixels
                        (the strongest listed), the display gain; returned too

    Nothing here reads the reference images: a capture without them is inspected the same way.
    """
    if not (isinstance(level, (int, float)) and 0 < level <= 1):
        raise ValueError(f"level={level!r}: the linear grey level the mean flux is shown at must be in (0, 1]")
    if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1):
        raise ValueError(f"max_frames={max_frames!r}: use a positive number of frames per view (or None: all)")
    names, cubes, sensor = read_capture(folder, max_frames)
    params, pattern, k = sensor.params, sensor.cfa, sensor.params.frames
    counts = [cube.sum(0, dtype=np.int64) for cube in cubes]
    total, total_frames = sum(counts), k * len(cubes)
    hot, hot_record = capture_hot_pixels(counts, sensor, threshold)
    flux = [sensors.mle_rgb(c, k, params, pattern, hot) for c in counts]
    gain = metered_gain(np.stack(flux), level)
    labels, classes = sensors.class_map(pattern, sensor.height, sensor.width)
    rate = total / total_frames
    record = {
        "folder": str(folder),
        "views": names,
        "frames": k,
        "width": sensor.width,
        "height": sensor.height,
        "cfa": pattern.name,
        "format": sensor.format,
        "detection_rate": {c: float(rate[(labels == i) & ~hot].mean()) for i, c in enumerate(classes)},
        "hot_pixels": {**hot_record, "count": int(hot.sum()), "from_sensor_json": sensor.hot_pixels is not None},
        "display": {"rule": "average metering over all views", "level": level, "gain": gain},
    }
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        write_hot_pixel_map(tmp / "hot_pixels.png", hot)
        for name, phi in zip(names, flux):
            io.write_image(tmp / "preview" / f"{name}.png", display_srgb(phi, gain))
        io.write_json(tmp / "capture.json", record)
    return record


# --------------------------------------------------------------------------------------------
# export of a simulated scene


def export_simulated(
    spc_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    cfa: str | sensors.CFAPattern = "RGGB",
    fmt: str = "npy.gz",
    bitorder: str = "big",
    scene_dir: str | os.PathLike | None = None,
    white: str = "sum",
    seed: int = 0,
    poses: bool = True,
) -> dict:
    """Write a simulated scene's SPC folder (``results/spc/{scene}``) as a captured scene.

    Pixels that see one channel keep that channel's simulated bits (the simulated route's exact
    measurement). Pixels that see several (W, mono) are drawn afresh from the scene's flux
    (``scene_dir`` images x the simulation's flux scale; seeded by ``seed``, scene and view). With
    ``scene_dir``, its images and (unless ``poses`` is False) poses_bounds.npy are copied as the
    reference views and poses.
    Returns the sensor.json record.
    """
    spc_dir, out_dir = Path(spc_dir), Path(out_dir)
    rec = io.read_json(spc_dir / "spc.json")
    params = spc.SPCParams(**rec["params"])
    pattern = sensors.cfa_pattern(cfa, white)
    names = sorted(p.name[:-4] for p in (spc_dir / "frames").glob("*.npz"))
    if not names:
        raise FileNotFoundError(f"{spc_dir}/frames: no simulated frames (*.npz); run the simulate_scene rule first")
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i, view in enumerate(names):
            cube = _export_view(spc_dir, view, i, pattern, params, rec, scene_dir, seed)
            photon_cubes.write_cube(photon_cubes.cube_path(tmp / "frames", view, fmt), cube, fmt, bitorder)
        h, w = cube.shape[1:]
        source = {
            "simulated": rec.get("scene", spc_dir.name),
            "spc_dir": str(spc_dir),
            "seed": rec.get("seed"),
            "export_seed": seed,
            "mode": params.mode,
            "flux_scale": rec["flux_scale"],
            "note": "flux_scale is the simulation's truth: a real capture has none, and no non-oracle row may read it",
        }
        record = sensor_record(params, pattern, w, h, fmt, bitorder, source=source)
        io.write_json(tmp / SENSOR_FILE, record)
        if scene_dir is not None:
            _copy_reference(Path(scene_dir), tmp, names, poses)
    return record


def _export_view(
    spc_dir: Path,
    view: str,
    index: int,
    pattern: sensors.CFAPattern,
    params: spc.SPCParams,
    rec: dict,
    scene_dir,
    seed: int,
) -> np.ndarray:
    """bool (K, H, W) of one view: channel bits where a pixel sees one channel, fresh draws elsewhere."""
    frames = spc.unpack_frames(*io.load_frames(spc_dir / "frames" / f"{view}.npz"))  # (K, H, W, 3)
    if sensors.channel_bits(frames[:1], pattern)[1].all():
        return sensors.sensor_frames(frames, pattern)
    if scene_dir is None:
        raise ValueError(
            f"export of {spc_dir} with cfa {pattern.name}: its pixels that see several channels "
            f"(W, mono) are drawn from the scene's flux; give scene_dir (the scene's images)"
        )
    srgb = io.read_rgb(Path(scene_dir) / "images" / f"{view}.png")
    phi = spc.flux_from_srgb(srgb, rec["flux_scale"])  # (H, W, 3) photons/s
    rng = spc.view_rng(seed, f"{rec.get('scene', spc_dir.name)}/export", index)
    return sensors.sensor_frames(frames, pattern, phi, params, rng)


def _copy_reference(scene_dir: Path, out: Path, names: list[str], poses: bool = True) -> None:
    files = {p.stem: p for p in io.list_images(scene_dir / "images")}
    for view in names:
        if view not in files:
            raise FileNotFoundError(f"{scene_dir}/images: no image for simulated view {view}")
        (out / "images").mkdir(exist_ok=True)
        shutil.copyfile(files[view], out / "images" / files[view].name)
    if poses and (scene_dir / "poses_bounds.npy").is_file():
        shutil.copyfile(scene_dir / "poses_bounds.npy", out / "poses_bounds.npy")

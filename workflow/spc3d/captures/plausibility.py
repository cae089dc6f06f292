"""A capture folder that reads fine but cannot be right, from what is cheap to read at parse time.

:func:`check_capture` (called by :func:`spc3d.jobs.capture_spec` when the workflow parses a
configured capture) refuses what is surely wrong and returns warnings for what is only unlikely:

    poses_bounds.npy       finite poses whose 3x3 parts are rotations (spc3d.llff.check_poses_bounds)
    hot-pixel map          marking (nearly) the whole sensor: an inverted map (nonzero = hot)
    exposure               dark counts alone would fire (almost) every bit at sensor.json's exposure,
                           or more bits than the first view's frames hold: an exposure in µs written
                           as seconds (or a dark count rate per µs)
    PNG frames             holding 0/1 instead of 0/255 (a bit written as its value, not as white)

The warnings are printed at parse time and recorded by the import job in spc.json's ``warnings``
(:func:`capture_warnings`), which the tables' captions name (spc3d.evaluation.tables.photon_note).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from spc3d import io

HOT_REFUSED = 0.5  # a map marking at least this share of the sensor leaves (almost) nothing to image
HOT_WARNED = 0.05  # ... this share is possible (a damaged sensor) but far above a SPAD's usual < 1 %
PROBE_FRAMES = 16  # frames of the first view read to compare the detection with the dark-count floor


def hot_fraction(sensor) -> float | None:
    """The share of the sensor the known hot-pixel map marks (None: no map)."""
    return None if sensor.hot_pixels is None else float(np.mean(sensor.hot_pixels))


def capture_warnings(sensor) -> list[str]:
    """What is possible but unlikely about a capture's sensor (the import job records these in
    spc.json's ``warnings``): a hot-pixel map marking more than :data:`HOT_WARNED` of the sensor."""
    fraction = hot_fraction(sensor)
    if fraction is not None and fraction > HOT_WARNED:
        name = sensor.record.get("hot_pixels")
        return [f"the hot-pixel map {name} marks {fraction:.1%} of the sensor (SPADs: usually below 1 %)"]
    return []


def check_capture(folder: str | os.PathLike, sensor, names: list[str]) -> list[str]:
    """Refuse (ValueError naming the file) what cannot be right about a capture (module docstring);
    return the warnings of :func:`capture_warnings`. ``names``: its views (``check_capture_folder``)."""
    from spc3d.llff import check_poses_bounds
    from spc3d.physics.flux_scale import dark_floor
    from spc3d.physics.record import SATURATED

    folder = Path(folder)
    poses = folder / "poses_bounds.npy"
    if poses.is_file():
        check_poses_bounds(io.load_npy(poses), poses)
    fraction = hot_fraction(sensor)
    if fraction is not None and fraction >= HOT_REFUSED:
        raise ValueError(
            f"{folder / str(sensor.record.get('hot_pixels'))}: the hot-pixel map marks {fraction:.0%} of the "
            "sensor (nonzero = hot), leaving nothing to image; is it inverted (0 = hot)?"
        )
    params, where = sensor.params, folder / "sensor.json"
    floor = dark_floor(params)
    hint = (
        f"is exposure_s in seconds? {params.exposure_s:g} µs is {params.exposure_s * 1e-6:g} s"
        if params.exposure_s >= 1e-3
        else "check exposure_s (seconds) and dark_count_rate (counts per second)"
    )
    if floor >= SATURATED:
        raise ValueError(
            f"{where}: exposure_s = {params.exposure_s:g} s with dark_count_rate = {params.dark_count_rate:g}/s: "
            f"dark counts alone would fire {floor:.4f} of the bits, so the frames could hold no image; {hint}"
        )
    if sensor.format == "png":
        check_png_levels(folder / "frames" / names[0])
    detection = first_detection(folder, sensor, names[0])
    if detection is not None:
        n = detection[1]
        if floor - detection[0] > 5 * math.sqrt(max(floor * (1 - floor), 1e-12) / n) + 0.01:
            raise ValueError(
                f"{where}: its frames fire {detection[0]:.4f} of the bits (view {names[0]}, first {PROBE_FRAMES} "
                f"frames) but dark counts alone would fire {floor:.4f} at exposure_s = {params.exposure_s:g} s and "
                f"dark_count_rate = {params.dark_count_rate:g}/s: the exposure cannot be right; {hint}"
            )
    return capture_warnings(sensor)


def check_png_levels(view_folder: Path) -> None:
    """PNG frames hold 0 and full scale (255, or 65535 at 16 bit): a frame of only 0 and 1 stored
    each bit as its value, which reads as (almost) black."""
    from spc3d.captures.photon_cubes import png_frames

    first = png_frames(view_folder)[0]
    img = io.read_image(first)
    levels = np.unique(img)
    if levels.size and levels.max() < 0.5 and np.allclose(levels * 255, np.round(levels * 255)) and levels.max() > 0:
        raise ValueError(
            f"{first}: a binary frame of 0 and {int(round(float(levels.max()) * 255))} (of 255): the bits were "
            "written as their values 0/1; write them as 0/255 (multiply by 255)"
        )


def first_detection(folder: Path, sensor, view: str) -> tuple[float, int] | None:
    """(mean of the bits, how many) of the first :data:`PROBE_FRAMES` frames of ``view``, hot
    pixels left out; None when they cannot be read here (the import job names why)."""
    from spc3d.captures import photon_cubes

    path = photon_cubes.cube_path(folder / "frames", view, sensor.format)
    try:
        cube = photon_cubes.read_cube(path, sensor.width, sensor.bitorder, min(PROBE_FRAMES, sensor.params.frames))
    except (OSError, ValueError):
        return None
    bits = cube if sensor.hot_pixels is None else cube[:, ~sensor.hot_pixels]
    return (float(bits.mean()), int(bits.size)) if bits.size else None

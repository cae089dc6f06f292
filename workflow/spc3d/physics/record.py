"""An SPC folder's record (``spc.json``) read back: its physics, its capture frame's factor S and,
for an imported capture, its sensor (colour filters and hot pixels).

Below every room that reads SPC folders (scene inputs, display exposure, captures, both stages),
so each reads the record one way.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.physics import sensors, spc
from spc3d.physics.hot_pixels import read_hot_pixel_map

MAX_CAPTURE_FACTOR = 255  # k/S² survives 16 bits exactly while S² < 65535: |error| <= S²/(2*65535) < 1/2


def check_capture_factor(capture_factor: object) -> int:
    """``capture_factor`` as an int in [1, :data:`MAX_CAPTURE_FACTOR`], or a ValueError saying why."""
    if isinstance(capture_factor, bool) or not isinstance(capture_factor, (int, np.integer)):
        raise ValueError(f"spc.capture_factor={capture_factor!r}: must be an integer (sub-pixels per axis, 1 = none)")
    if not 1 <= capture_factor <= MAX_CAPTURE_FACTOR:
        raise ValueError(
            f"spc.capture_factor={capture_factor!r}: must lie in [1, {MAX_CAPTURE_FACTOR}]; the capture frame "
            f"stores k/S² in 16 bits, exact (k = round(v S²)) only while S² < 65535"
        )
    return int(capture_factor)


def read_spc_record(spc_dir: str | os.PathLike) -> dict:
    return io.read_json(Path(spc_dir) / "spc.json")


def params_from_record(record: dict) -> spc.SPCParams:
    return spc.SPCParams(**record["params"])


SATURATED = 0.99  # a scene whose bits are this often 1 (or this much closer to the dark floor than to 1) shows nothing


def frame_warnings(mean_detection: float, dark_floor: float, saturated_pixels: float | None = None) -> list[str]:
    """spc.json's ``warnings``: frames that carry (almost) no image. ``mean_detection``: the mean
    P(bit = 1) over the scene's frames; ``dark_floor``: what dark counts alone fire; ``saturated_pixels``:
    the share of pixels that fired in every frame (captures). Rows of such a scene measure the
    exposure, not the method: the tables name the scene (:func:`spc3d.evaluation.tables.photon_note`)."""
    out = []
    if mean_detection >= SATURATED:
        out.append(f"frames almost all 1 (mean detection {mean_detection:.4f}): overexposed")
    elif mean_detection - dark_floor <= 1 - SATURATED:
        out.append(
            f"frames almost all dark (mean detection {mean_detection:.4g} against {dark_floor:.4g} from dark "
            "counts alone): underexposed"
        )
    if saturated_pixels is not None and saturated_pixels >= 0.5:
        out.append(f"{saturated_pixels:.0%} of the pixels fired in every frame (saturated)")
    return out


EXPOSURE_KINDS = ("auto", "fixed", "metered")  # how the camera set the exposure it reports


def exposure_record(photons_per_frame: float, how: str, **details) -> dict:
    """spc.json's ``exposure`` block: what the camera reports about the exposure of its frames.

    ``photons_per_frame`` is the expected number of signal photons a pixel detects per frame at
    scene linear intensity 1 (q T times the flux at 1): the camera's exposure (time, aperture, ND)
    times its radiometric calibration, in the units of the scene's images. ``how``: ``auto``
    (the camera chose it by metering its training views), ``fixed`` (set by the user) or
    ``metered`` (a capture that reports none: its mean flux shown at 18 % grey, as a camera's
    display meters). A non-oracle row may read this block (a SPAD user knows the exposure each
    capture was taken with), never the scene's images."""
    if how not in EXPOSURE_KINDS:
        raise ValueError(f"exposure how={how!r}: use one of {EXPOSURE_KINDS}")
    if not (math.isfinite(photons_per_frame) and photons_per_frame > 0):
        raise ValueError(f"exposure photons_per_frame={photons_per_frame!r}: must be finite and > 0")
    return {"photons_per_frame": float(photons_per_frame), "how": how, **details}


def camera_exposure(record: dict, where: str = "spc.json") -> float:
    """The exposure the camera reports (:func:`exposure_record`): photons per pixel and frame at
    scene linear intensity 1. A simulated folder written before the block existed gives q T times
    its flux scale (the same number)."""
    block = record.get("exposure")
    if block:
        return float(block["photons_per_frame"])
    if record.get("flux_scale"):
        p = record.get("params") or record["spc_params"]  # spc.json's or augment.json's name
        return float(p["q"] * p["exposure_s"] * record["flux_scale"])
    raise ValueError(
        f"{where} reports no camera exposure (no 'exposure' block, no flux scale): written by an older "
        "spc3d; delete that SPC folder so simulate_scene / the capture import writes it anew"
    )


HOT_FILE = "hot_pixels.png"


def spc_sensor(spc_dir: str | os.PathLike) -> tuple[sensors.CFAPattern, np.ndarray] | None:
    """(pattern, valid (H, W) bool: not hot) of an imported capture's SPC folder; None for the
    simulator's RGB frames (every pixel sees R, G and B, one bit each)."""
    spc_dir = Path(spc_dir)
    rec = io.read_json(spc_dir / "spc.json")
    if "sensor" not in rec:
        return None
    pattern = sensors.cfa_pattern(rec["sensor"]["cfa"], rec["sensor"]["white"])
    return pattern, ~read_hot_pixel_map(spc_dir / HOT_FILE)

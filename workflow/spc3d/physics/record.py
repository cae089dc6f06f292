"""An SPC folder's record (``spc.json``) read back: its physics, its capture frame's factor S and,
for an imported capture, its sensor (colour filters and hot pixels).

Below every room that reads SPC folders (scene inputs, display exposure, captures, both stages),
so each reads the record one way.
"""

from __future__ import annotations

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

"""Hot pixels: SPAD pixels whose dark counts make them fire far above their neighbours.

Detection (:func:`detect_hot_pixels`) works on the count of ones ``S`` of every pixel over ``K``
frames — best over all frames of all views of a capture (:func:`count_ones`): a hot pixel sits at
the same sensor position in every view while the scene moves, so summing views averages texture
out and keeps hot pixels.

1. Variance-stabilise the counts: ``a = 2 sqrt(K) asin(sqrt((S + 3/8) / (K + 3/4)))`` (Anscombe's
   binomial transform: variance ~1 at every rate, also at a fraction of a count per pixel, where a
   z-score of the log rate has no usable null spread).
2. Compare each pixel with the median of the same-colour pixels in a ``window`` x ``window``
   neighbourhood (centre excluded; for a CFA only pixels of the same colour class count, so an R
   pixel is never compared with its dimmer B neighbours).
3. Scale the residual by the local robust spread: ``1.4826 *`` the median absolute residual of the
   same same-colour neighbours, never below 1 (the photon noise alone). Near edges and in busy
   texture the spread is large, so texture is not taken for hot pixels; on flat ground it is ~1.
4. Hot = residual / spread > ``threshold`` (one-sided: far *above* the neighbours).

At the default threshold 6 a clean flat field of one million pixels has an expected ~1e-3 false
detections (Gaussian tail beyond 6 sd). On one view with many frames (K ~ 1000) single-pixel
texture can still pass (measured on the built-in courtyard at 128x96, K = 1000: 6 mono / 12 RGGB
false detections from one view, 1 / 0 from the sum of four views): count the frames of all views.
Hot pixels are left out of the likelihood and filled in the MLE (:mod:`spc3d.physics.sensors`); the record
lists them for the report.

Files: a hot-pixel map is an (H, W) image (nonzero = hot; PNG 0/255) or a bool/integer ``.npy``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.physics.sensors import CFAPattern, class_map

MAD_TO_SD = 1.4826  # sd of a normal distribution / its median absolute deviation
_ROWS_PER_CHUNK = 64  # rows of windows unrolled at a time (memory: rows * W * window^2 floats)


def count_ones(cubes: Iterable[np.ndarray]) -> tuple[np.ndarray, int]:
    """Sum bool (K_i, H, W) photon cubes -> (ones per pixel (H, W) int64, total frames sum K_i)."""
    counts, frames, shape = None, 0, None
    for i, cube in enumerate(cubes):
        cube = np.asarray(cube)
        if cube.dtype != np.bool_ or cube.ndim != 3:
            raise ValueError(f"count_ones: cube {i} is {cube.dtype} {cube.shape}; expected bool (K, H, W)")
        if shape is not None and cube.shape[1:] != shape:
            raise ValueError(f"count_ones: cube {i} is {cube.shape[1:]} pixels, the first {shape}")
        shape = cube.shape[1:]
        s = cube.sum(0, dtype=np.int64)
        counts = s if counts is None else counts + s
        frames += cube.shape[0]
    if counts is None:
        raise ValueError("count_ones: no photon cubes given")
    return counts, frames


def stabilised(counts: np.ndarray, frames: int) -> np.ndarray:
    """Anscombe's binomial variance-stabilising transform of ones among ``frames`` (variance ~1)."""
    return 2.0 * np.sqrt(frames) * np.arcsin(np.sqrt((counts + 0.375) / (frames + 0.75)))


def _unstabilised(a: np.ndarray, frames: int) -> np.ndarray:
    """The firing rate S/K whose transform is ``a`` (for reporting the neighbours' rate)."""
    s = (frames + 0.75) * np.sin(a / (2.0 * np.sqrt(frames))) ** 2 - 0.375
    return np.clip(s / frames, 0.0, 1.0)


def neighbour_median(values: np.ndarray, labels: np.ndarray, window: int) -> np.ndarray:
    """(H, W) median of the same-label pixels in the window around each pixel, itself excluded
    (NaN where the window holds none)."""
    h, w = values.shape
    r = window // 2
    padded = np.pad(values.astype(np.float64), r, constant_values=np.nan)
    lab = np.pad(labels, r, constant_values=-1)
    out = np.empty((h, w))
    centre = r * window + r
    for y0 in range(0, h, _ROWS_PER_CHUNK):
        y1 = min(h, y0 + _ROWS_PER_CHUNK)
        win = np.lib.stride_tricks.sliding_window_view(padded[y0 : y1 + 2 * r], (window, window))
        wl = np.lib.stride_tricks.sliding_window_view(lab[y0 : y1 + 2 * r], (window, window))
        win = win.reshape(y1 - y0, w, -1).copy()
        same = wl.reshape(y1 - y0, w, -1) == labels[y0:y1, :, None]
        same[:, :, centre] = False
        win[~same] = np.nan
        with warnings.catch_warnings():  # an all-NaN window (no same-colour neighbour) gives NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            out[y0:y1] = np.nanmedian(win, axis=-1)
    return out


def detect_hot_pixels(
    counts: np.ndarray,
    frames: int,
    pattern: CFAPattern | None = None,
    threshold: float = 6.0,
    window: int | None = None,
) -> tuple[np.ndarray, dict]:
    """Hot pixels of a sensor from its counts of ones.

    counts: (H, W) ones per pixel over ``frames`` frames (:func:`count_ones`). pattern: the CFA (None:
    monochrome, one class). window: odd side of the neighbourhood in pixels (default 5 for a 1x1 tile,
    9 otherwise: ~5x5 same-colour neighbours on a 2x2 CFA). Returns (hot (H, W) bool, record).
    """
    counts = np.asarray(counts)
    _check_inputs(counts, frames, threshold)
    period = (1, 1) if pattern is None else pattern.period
    window = (5 if period == (1, 1) else 9) if window is None else window
    if isinstance(window, bool) or not isinstance(window, int) or window < 3 or window % 2 == 0:
        raise ValueError(f"window={window!r}: must be an odd integer >= 3 (pixels)")
    labels = np.zeros(counts.shape, int) if pattern is None else class_map(pattern, *counts.shape)[0]
    a = stabilised(counts, frames)
    med = neighbour_median(a, labels, window)
    resid = a - med  # NaN where a pixel has no same-colour neighbour: never hot
    spread = MAD_TO_SD * neighbour_median(np.abs(resid), labels, window)
    z = resid / np.fmax(spread, 1.0)  # fmax: a NaN spread (no neighbour residual) falls back to 1
    hot = np.nan_to_num(z, nan=-np.inf) > threshold
    return hot, hot_pixel_record(hot, counts, frames, _unstabilised(med, frames), z, threshold, window)


def _check_inputs(counts: np.ndarray, frames: int, threshold: float) -> None:
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise ValueError(f"frames={frames!r}: the number of frames counted must be a positive integer")
    if counts.ndim != 2 or not np.issubdtype(counts.dtype, np.integer):
        raise ValueError(
            f"counts: {counts.dtype} array of shape {counts.shape}; expected integer (H, W) ones per pixel (count_ones)"
        )
    if counts.size and (counts.min() < 0 or counts.max() > frames):
        raise ValueError(
            f"counts span [{counts.min()}, {counts.max()}]; ones among {frames} frames lie in [0, {frames}]"
        )
    if not (isinstance(threshold, (int, float)) and np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold={threshold!r}: must be a positive number (robust z-score)")


def hot_pixel_record(
    hot: np.ndarray,
    counts: np.ndarray,
    frames: int,
    neighbour_rate: np.ndarray,
    z: np.ndarray,
    threshold: float,
    window: int,
    max_listed: int = 10000,
) -> dict:
    """Report of a detection: count, share, and per hot pixel (row, column), rate S/K, neighbours'
    median rate and z-score (the first ``max_listed``, strongest first)."""
    pos = np.argwhere(hot)
    order = np.argsort(-z[hot], kind="stable")[:max_listed]
    pos = pos[order]
    rate = counts / frames
    return {
        "count": int(hot.sum()),
        "pixels": int(hot.size),
        "fraction": float(hot.mean()),
        "threshold": float(threshold),
        "window": int(window),
        "frames": int(frames),
        "median_rate": float(np.median(rate)),
        "listed": int(len(pos)),
        "positions": pos.tolist(),
        "rates": [float(rate[y, x]) for y, x in pos],
        "neighbour_rates": [float(neighbour_rate[y, x]) for y, x in pos],
        "z": [float(z[y, x]) for y, x in pos],
    }


# --------------------------------------------------------------------------------------------
# files


def read_hot_pixel_map(path: str | os.PathLike, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool map from a ``.npy`` (bool or integer, nonzero = hot) or an image (nonzero = hot)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        try:
            data = io.load_npy(path)
        except (OSError, ValueError) as e:
            raise ValueError(f"hot-pixel map {path}: {e} (expected an (H, W) bool .npy)") from e
    else:
        data = io.read_image(path)
        if data.shape[2] != 1:
            raise ValueError(f"hot-pixel map {path}: {data.shape[2]} channels; expected one (nonzero = hot)")
        data = data[:, :, 0]
    if data.ndim != 2 or not (data.dtype == np.bool_ or np.issubdtype(data.dtype, np.number)):
        raise ValueError(f"hot-pixel map {path}: {data.dtype} {data.shape}; expected (H, W), nonzero = hot")
    if shape is not None and data.shape != tuple(shape):
        raise ValueError(
            f"hot-pixel map {path}: {data.shape[1]}x{data.shape[0]} (WxH) but the sensor is {shape[1]}x{shape[0]}"
        )
    return data != 0


def write_hot_pixel_map(path: str | os.PathLike, hot: np.ndarray) -> None:
    """Write an (H, W) bool map as a 0/255 PNG or a bool ``.npy`` (by suffix), atomically."""
    hot = np.asarray(hot, bool)
    if Path(path).suffix.lower() == ".npy":
        io.save_npy(path, hot)
    else:
        io.write_image(path, hot[:, :, None].astype(np.float32))

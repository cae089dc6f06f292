"""Photon cubes: one view's 1-bit frames of a real (or exported) SPAD sensor, read and written.

A photon cube is bool ``(K, H, W)``: K binary frames of the raw sensor plane, one value per pixel
(a colour-filter sensor's mosaic, not RGB; see :mod:`spc3d.physics.sensors`). Four on-disk formats:

``npy``     uint8 ``(K, H, ceil(W/8))``: each frame row bit-packed along the last (width) axis,
            pixel ``x`` in byte ``x // 8``. Bit order ``big`` (the default) puts pixel ``8j`` in the
            most significant bit of byte ``j``: ``np.packbits(cube, axis=-1)`` /
            ``np.unpackbits(..., axis=-1)`` with numpy's default bit order. That is the layout of
            the SwissSPAD2 ``.npy`` photon cubes of the WISION lab's ``photoncube`` tools
            (WISION-Lab/photoncube2video: ``unpack_single`` in ``src/transforms.rs`` maps bit
            ``7 - s`` of byte ``j`` to pixel ``8j + s``; its ``.bin``-to-``.npy`` conversion in
            ``src/cube.rs`` reverses the bits of the sensor's raw ``.bin`` bytes to get there, so the
            raw ``.bin`` bytes are ``little``). ``bitorder="little"`` reads and writes that other
            order. A width that is not a multiple of 8 leaves padding bits at the end of every row:
            they are written as 0 and dropped on read; the true width is an argument (a capture
            keeps it in ``sensor.json``), and without it the width is ``8 * ceil(W/8)``.
``npy.gz``  the same ``.npy`` file, gzip-compressed (read as a stream: nothing is unpacked to disk).
``png``     a folder of single-channel 0/255 PNG frames (8 or 16 bit), one per frame, in natural
            name order (``2.png`` before ``10.png``; zero-padded ``NNNN.png`` when written).
``npz``     the project's own :func:`spc3d.io.save_frames` file (``packed``, ``shape``; little bit
            order over the whole flattened array, :func:`spc3d.physics.spc.pack_frames`), shape ``(K, H, W)``.

A single binary frame or the mean of K frames may also come as one 8- or 16-bit PNG (the form in
which SPAD datasets often publish a capture: ``average1.png``, ``average16.png``, ...):
:func:`read_frame_mean` reads it back to counts of ones per pixel, K stated by the caller or read
from a sidecar ``{name}.json`` (``{"frames": K}``) beside it, and :func:`read_cube` reads a binary
one as a one-frame cube.

:func:`read_cube` picks the format from the name (a folder is PNG frames) and checks what it
reads: every error names the file and what was expected. Writers go through
:func:`spc3d.io.atomic_path`; every format round-trips exactly.
"""

from __future__ import annotations

import gzip
import math
import os
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.physics import spc

FORMATS = ("npy", "npy.gz", "png", "npz")
BITORDERS = ("big", "little")
_EXPECTED = (
    "a photon cube: .npy or .npy.gz (uint8 (K, H, ceil(W/8)), bit-packed along the width), "
    ".npz (spc3d.io.save_frames) or a folder of 0/255 PNG frames"
)


# --------------------------------------------------------------------------------------------
# names and checks


def cube_format(path: str | os.PathLike) -> str:
    """The format of an existing cube path: a folder is ``png``, else the file name's ending."""
    path = Path(path)
    if path.is_dir():
        return "png"
    if not path.exists():
        raise FileNotFoundError(f"photon cube {path} does not exist (expected {_EXPECTED})")
    return _format_from_name(path)


def _format_from_name(path: Path) -> str:
    name = path.name.lower()
    for fmt in ("npy.gz", "npy", "npz"):
        if name.endswith("." + fmt):
            return fmt
    raise ValueError(f"{path}: unknown photon-cube format; expected {_EXPECTED}")


def cube_path(folder: str | os.PathLike, view: str, fmt: str) -> Path:
    """Where view ``view`` of a frames folder lives in format ``fmt`` (``png``: a folder)."""
    check_choice("fmt", fmt, FORMATS)
    return Path(folder) / (view if fmt == "png" else f"{view}.{fmt}")


def check_choice(name: str, value: object, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"{name}={value!r}: use one of {choices}")
    return value


def _check_cube(cube: np.ndarray, path: Path) -> np.ndarray:
    cube = np.asarray(cube)
    if cube.dtype != np.bool_ or cube.ndim != 3 or 0 in cube.shape:
        raise ValueError(
            f"writing {path}: got {cube.dtype} array of shape {cube.shape}; a photon cube "
            f"is a non-empty bool (K, H, W) array"
        )
    return cube


def _check_width(width: int | None, packed_width: int, path: Path) -> int:
    """The true width: ``width`` if it fits ``packed_width`` bytes per row, else an error."""
    if width is None:
        return 8 * packed_width
    if (
        isinstance(width, bool)
        or not isinstance(width, (int, np.integer))
        or not 8 * (packed_width - 1) < width <= 8 * packed_width
    ):
        raise ValueError(
            f"{path}: width={width!r} does not fit rows of {packed_width} bytes; the true "
            f"width must be an integer in [{8 * packed_width - 7}, {8 * packed_width}]"
        )
    return int(width)


def _natural_key(path: Path) -> list:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", path.name)]


# --------------------------------------------------------------------------------------------
# bit-packed .npy / .npy.gz


def pack_cube(cube: np.ndarray, bitorder: str = "big") -> np.ndarray:
    """bool (K, H, W) -> uint8 (K, H, ceil(W/8)), packed along the width (padding bits 0)."""
    check_choice("bitorder", bitorder, BITORDERS)
    return np.packbits(cube, axis=-1, bitorder=bitorder)


def unpack_cube(
    packed: np.ndarray, width: int | None = None, bitorder: str = "big", path: str | os.PathLike = "<array>"
) -> np.ndarray:
    """uint8 (K, H, ceil(W/8)) -> bool (K, H, W); the padding bits past ``width`` are dropped."""
    check_choice("bitorder", bitorder, BITORDERS)
    _check_packed(packed.shape, packed.dtype, Path(path))
    width = _check_width(width, packed.shape[2], Path(path))
    return np.unpackbits(packed, axis=-1, count=width, bitorder=bitorder).view(bool)


def _check_packed(shape: tuple[int, ...], dtype: np.dtype, path: Path) -> None:
    if np.dtype(dtype) != np.uint8 or len(shape) != 3 or 0 in shape:
        hint = (
            (
                " (a bool array is an unpacked cube: pack it with np.packbits along the last axis, "
                "or write it with write_cube)"
            )
            if np.dtype(dtype) == np.bool_
            else ""
        )
        raise ValueError(
            f"{path}: holds a {np.dtype(dtype)} array of shape {tuple(shape)}; expected "
            f"uint8 (K, H, ceil(W/8)) bit-packed 1-bit frames{hint}"
        )


def read_npy(
    path: str | os.PathLike, width: int | None = None, bitorder: str = "big", max_frames: int | None = None
) -> np.ndarray:
    """A bit-packed ``.npy`` or ``.npy.gz`` cube -> bool (K, H, W) (the first ``max_frames`` only)."""
    path = Path(path)
    if _format_from_name(path) == "npy.gz":
        packed = _read_npy_gz(path, max_frames)
    else:
        packed = _read_npy_plain(path, max_frames)
    return unpack_cube(packed, width, bitorder, path)


def _read_npy_plain(path: Path, max_frames: int | None) -> np.ndarray:
    try:
        arr = io.load_npy(path, mmap=True)  # only the frames asked for are read
    except (OSError, ValueError, EOFError) as e:
        raise ValueError(f"cannot read photon cube {path}: {e} (truncated, or not a .npy file?)") from e
    if not isinstance(arr, np.ndarray):
        raise ValueError(f"cannot read photon cube {path}: not a .npy array")
    _check_packed(arr.shape, arr.dtype, path)
    return np.array(arr[:max_frames])


def _read_npy_gz(path: Path, max_frames: int | None) -> np.ndarray:
    """Stream a gzip-compressed .npy: header, then only the bytes of the frames asked for."""
    try:
        with gzip.open(path, "rb") as f:
            shape, fortran, dtype = _npy_header(f)
            _check_packed(shape, dtype, path)
            frames = shape[0] if fortran or max_frames is None else min(shape[0], max_frames)
            want = frames * shape[1] * shape[2]
            data = f.read(want)
    except (OSError, EOFError, zlib.error) as e:  # BadGzipFile is an OSError
        raise ValueError(
            f"cannot read photon cube {path}: {type(e).__name__}: {e} (a truncated or "
            f"corrupt gzip file; expected a gzip-compressed .npy)"
        ) from e
    if len(data) < want:
        raise ValueError(
            f"{path}: truncated: the .npy header announces {shape} but the data ends after {len(data)} of {want} bytes"
        )
    arr = np.frombuffer(data, np.uint8).reshape(
        ((frames,) + shape[1:]) if not fortran else shape, order="F" if fortran else "C"
    )
    return np.ascontiguousarray(arr[:max_frames])


def _npy_header(f) -> tuple[tuple[int, ...], bool, np.dtype]:
    fmt = np.lib.format
    try:
        version = fmt.read_magic(f)
        if version == (1, 0):
            return fmt.read_array_header_1_0(f)
        if version == (2, 0):
            return fmt.read_array_header_2_0(f)
    except ValueError as e:
        raise OSError(f"not a .npy stream ({e})") from e
    raise OSError(f"unsupported .npy format version {version}")


def write_npy(path: str | os.PathLike, cube: np.ndarray, bitorder: str = "big", compresslevel: int = 6) -> Path:
    """Write bool (K, H, W) as a bit-packed ``.npy`` (or ``.npy.gz`` by name), atomically."""
    path = Path(path)
    fmt = _format_from_name(path)
    packed = pack_cube(_check_cube(cube, path), bitorder)
    with io.atomic_path(path) as tmp:
        if fmt == "npy.gz":
            with (
                open(tmp, "wb") as raw,
                gzip.GzipFile(fileobj=raw, mode="wb", filename="", compresslevel=compresslevel, mtime=0) as f,
            ):
                np.lib.format.write_array(f, packed, allow_pickle=False)  # mtime 0: same bytes each time
        else:
            with open(tmp, "wb") as f:
                np.lib.format.write_array(f, packed, allow_pickle=False)
    return path


# --------------------------------------------------------------------------------------------
# PNG frame folders


def png_frames(folder: str | os.PathLike) -> list[Path]:
    """The ``*.png`` frames of a folder in natural name order (hidden files skipped)."""
    folder = Path(folder)
    files = sorted(
        (p for p in folder.glob("*") if p.suffix.lower() == ".png" and not p.name.startswith(".")), key=_natural_key
    )
    if not files:
        raise FileNotFoundError(
            f"{folder}: no PNG frames; expected a folder of 0/255 single-channel PNG files, one per binary frame"
        )
    return files


def read_png_frames(folder: str | os.PathLike, max_frames: int | None = None) -> np.ndarray:
    """A folder of 0/255 PNG frames -> bool (K, H, W); every frame must match the first's size."""
    files = png_frames(folder)[:max_frames]
    first = _read_png_frame(files[0])
    cube = np.empty((len(files),) + first.shape, dtype=bool)
    cube[0] = first
    for k, f in enumerate(files[1:], start=1):
        frame = _read_png_frame(f)
        if frame.shape != first.shape:
            raise ValueError(
                f"{f}: frame is {frame.shape[1]}x{frame.shape[0]} (WxH) but {files[0].name} "
                f"is {first.shape[1]}x{first.shape[0]}; all frames of a view must have one size"
            )
        cube[k] = frame
    return cube


def _read_png_frame(path: Path) -> np.ndarray:
    img = io.read_image(path)  # (H, W, C) float32 in [0, 1]
    if img.shape[2] != 1:
        raise ValueError(
            f"{path}: {img.shape[2]} channels; a binary frame is a single-channel image "
            f"(monochrome, or the raw mosaic of a colour-filter sensor)"
        )
    bad = (img != 0.0) & (img != 1.0)
    if bad.any():
        y, x = np.argwhere(bad[:, :, 0])[0]
        raise ValueError(
            f"{path}: {int(bad.sum())} pixels are neither 0 nor full scale (e.g. "
            f"{float(img[y, x, 0]) * 255:.1f}/255 at row {y}, column {x}); binary frames "
            f"hold only 0 and 255"
        )
    return img[:, :, 0] == 1.0


def write_png_frames(folder: str | os.PathLike, cube: np.ndarray) -> Path:
    """Write bool (K, H, W) as ``folder/NNNN.png`` 0/255 8-bit frames (the folder atomically)."""
    folder = Path(folder)
    cube = _check_cube(cube, folder)
    digits = max(4, len(str(len(cube) - 1)))
    with io.atomic_path(folder, is_dir=True) as tmp:
        for k, frame in enumerate(cube):
            io.write_image(tmp / f"{k:0{digits}d}.png", frame[:, :, None].astype(np.float32))
    return folder


# --------------------------------------------------------------------------------------------
# one PNG: a binary frame or the mean of K frames

SIDECAR_KEY = "frames"
MAX_MEAN_FRAMES = 1 << 20  # more frames than any single-PNG mean needs; bounds the level search


@dataclass(frozen=True, eq=False)
class FrameMean:
    """The ones per pixel among K binary frames, read from one monochrome PNG."""

    counts: np.ndarray  # (H, W) int64 in [0, K]
    frames: int  # K
    path: Path
    frames_from: str  # "argument", "sidecar" or "binary" (only 0 and full scale: one frame)
    ambiguous: int = 0  # pixels whose level two counts round to (only when K > the full scale)

    @property
    def mean(self) -> np.ndarray:
        """(H, W) float64 fraction of frames that fired."""
        return self.counts / self.frames


def sidecar_path(path: str | os.PathLike) -> Path:
    """``{name}.json`` beside ``{name}.png``: the sidecar that states K of a K-frame mean."""
    return Path(path).with_suffix(".json")


def read_sidecar_frames(path: str | os.PathLike) -> int | None:
    """K from the sidecar of a frame-mean PNG (None: no sidecar); errors name the sidecar."""
    side = sidecar_path(path)
    if not side.is_file():
        return None
    rec = io.read_json(side)
    value = rec.get(SIDECAR_KEY) if isinstance(rec, dict) else None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(
            f"{side}: {SIDECAR_KEY}={value!r}; the sidecar of {Path(path).name} states the number of binary "
            f'frames its mean holds as a positive integer, e.g. {{"{SIDECAR_KEY}": 16}}'
        )
    return value


def _mono_codes(path: Path) -> tuple[np.ndarray, int]:
    """(H, W) integer levels and full scale of a single-channel PNG (equal RGB channels accepted)."""
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: a frame mean is read from a .png file (8 or 16 bit, one channel)")
    codes, full = io.read_image_codes(path)
    channels = codes.shape[2]
    if channels in (2, 4):  # grey + alpha / RGBA: the alpha must be opaque
        if (codes[:, :, -1] != full).any():
            raise ValueError(f"{path}: its alpha channel is not opaque everywhere; a SPAD frame has no transparency")
        codes = codes[:, :, :-1]
    if codes.shape[2] == 3:
        if not ((codes[:, :, 0] == codes[:, :, 1]) & (codes[:, :, 1] == codes[:, :, 2])).all():
            raise ValueError(
                f"{path}: a colour image (its RGB channels differ); a SPAD frame or frame mean is monochrome, "
                "one value per pixel (a colour-filter sensor's raw mosaic, not a demosaiced image)"
            )
        codes = codes[:, :, :1]
    if codes.shape[2] != 1:
        raise ValueError(f"{path}: {channels} channels; a SPAD frame mean is a single-channel image")
    return codes[:, :, 0], full


def _levels_fit(levels: np.ndarray, full: int, frames: int) -> np.ndarray:
    """Which stored levels lie within half a code of a multiple of full/K (any rounding rule)."""
    nearest = np.rint(levels * frames / full)
    return np.abs(levels - nearest * full / frames) <= 0.5 + 1e-9


def _smallest_k(levels: np.ndarray, full: int, start: int = 1) -> int | None:
    """The smallest K >= start whose multiples of full/K explain every level (None: none up to the full scale)."""
    for k in range(start, full + 1):
        if _levels_fit(levels, full, k).all():
            return k
    return None


def read_frame_mean(path: str | os.PathLike, frames: int | None = None) -> FrameMean:
    """A single binary frame or a K-frame mean stored as one monochrome PNG -> :class:`FrameMean`.

    The PNG holds mean x full scale (255 or 65535), rounded by any rule. K is ``frames`` if given,
    else the sidecar's (:func:`sidecar_path`; both given must agree), else 1 when the PNG holds only
    0 and full scale (a binary frame). Checks, each an error naming the file and the fault: a frame
    stated binary (K = 1) holds only 0 and full scale; every level lies within half a code of a
    multiple of 1/K; and the levels present are not all multiples of g/K for some g > 1 (then the
    file is a K/g-frame mean: the stated K does not match it). With K above the full scale two
    counts can share a level; such pixels are decoded to the nearer count and counted in
    ``ambiguous``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"frame mean {path} does not exist (expected a monochrome PNG)")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 1):
        raise ValueError(f"{path}: frames={frames!r}; the number of binary frames averaged must be a positive integer")
    if frames is not None and frames > MAX_MEAN_FRAMES:
        raise ValueError(f"{path}: frames={frames} is more than {MAX_MEAN_FRAMES} frames in one PNG mean")
    side = read_sidecar_frames(path)
    if frames is not None and side is not None and frames != side:
        raise ValueError(f"{path}: frames={frames} was given but its sidecar {sidecar_path(path).name} says {side}")
    codes, full = _mono_codes(path)
    levels = np.unique(codes)
    binary = bool(np.isin(levels, (0, full)).all())
    k, source = (frames, "argument") if frames is not None else (side, "sidecar") if side is not None else (None, "")
    if k is None:
        if not binary:
            raise ValueError(
                f"{path}: {levels.size} grey levels, so not a binary frame; a K-frame mean needs K: "
                f"state it (frames=K; --frames K on the command line) or write {sidecar_path(path).name} with "
                f'{{"{SIDECAR_KEY}": K}}' + _k_hint(levels, full)
            )
        k, source = 1, "binary"
    if k == 1 and not binary:
        bad = (codes != 0) & (codes != full)
        y, x = np.argwhere(bad)[0]
        raise ValueError(
            f"{path}: not a binary frame: {int(bad.sum())} pixels are neither 0 nor {full} (e.g. {int(codes[y, x])} "
            f"at row {y}, column {x}); a single binary frame (K = 1, {source}) holds only 0 and full scale"
            + _k_hint(levels, full)
        )
    fit = _levels_fit(levels, full, k)
    if not fit.all():
        bad_levels = levels[~fit]
        n_bad = int(np.isin(codes, bad_levels).sum())
        y, x = np.argwhere(codes == bad_levels[0])[0]
        raise ValueError(
            f"{path}: {n_bad} pixels hold levels that are not multiples of 1/{k} (K = {k}, {source}; e.g. "
            f"{int(bad_levels[0])}/{full} at row {y}, column {x}, between counts "
            f"{math.floor(bad_levels[0] * k / full)} and {math.ceil(bad_levels[0] * k / full)} of {k})"
            + _k_hint(levels, full)
        )
    counts = np.rint(codes * k / full).astype(np.int64)
    present = np.unique(counts)
    step = math.gcd(*(int(c) for c in present)) if present.any() else 1
    if k > 1 and step > 1 and k % step == 0 and present.size > 1:
        raise ValueError(
            f"{path}: K = {k} ({source}) does not match the levels present: every count is a multiple of {step}, "
            f"as in {'a single binary frame' if k == step else f'the mean of {k // step} frames'}; "
            "state the K the file was averaged over"
        )
    ambiguous = 0
    if k > full:
        lower = np.abs(levels - (np.rint(levels * k / full) - 1) * full / k) <= 0.5 + 1e-9
        upper = np.abs(levels - (np.rint(levels * k / full) + 1) * full / k) <= 0.5 + 1e-9
        ambiguous = int(np.isin(codes, levels[lower | upper]).sum())
    return FrameMean(counts, k, path, source, ambiguous)


def _k_hint(levels: np.ndarray, full: int) -> str:
    k = _smallest_k(levels, full)
    return f" (its levels fit a mean of K = {k} frames)" if k is not None and k > 1 else ""


def write_frame_mean(path: str | os.PathLike, counts: np.ndarray, frames: int, sidecar: bool = True) -> Path:
    """Write ones per pixel among ``frames`` binary frames as an 8-bit PNG of their mean (16 bit when K > 255,
    exact up to K = 65535), and with ``sidecar`` its ``{name}.json`` stating K; each file atomically."""
    path = Path(path)
    counts = np.asarray(counts)
    if frames < 1 or counts.ndim != 2 or counts.min() < 0 or counts.max() > frames:
        raise ValueError(f"writing {path}: counts {counts.shape} in [{counts.min()}, {counts.max()}] of K = {frames}")
    io.write_image(path, (counts / frames).astype(np.float64)[:, :, None], bits=8 if frames <= 255 else 16)
    if sidecar:
        io.write_json(sidecar_path(path), {SIDECAR_KEY: int(frames)})
    return path


# --------------------------------------------------------------------------------------------
# the project's .npz


def read_npz(path: str | os.PathLike, max_frames: int | None = None) -> np.ndarray:
    """A :func:`spc3d.io.save_frames` file of shape (K, H, W) (or (K, H, W, 1)) -> bool (K, H, W)."""
    path = Path(path)
    packed, shape = io.load_frames(path)
    try:
        frames = spc.unpack_frames(packed, shape)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e
    if frames.ndim == 4 and frames.shape[3] == 1:
        frames = frames[..., 0]
    if frames.ndim != 3:
        hint = (
            (
                " — the simulator's RGB frames (K, H, W, 3): export them as a sensor plane with "
                "spc3d.captures.folders.export_simulated"
            )
            if frames.ndim == 4 and frames.shape[3] == 3
            else ""
        )
        raise ValueError(
            f"{path}: frames of shape {frames.shape}; a photon cube is (K, H, W), one raw value per pixel{hint}"
        )
    return frames[:max_frames]


def write_npz(path: str | os.PathLike, cube: np.ndarray) -> Path:
    path = Path(path)
    io.save_frames(path, *spc.pack_frames(_check_cube(cube, path)))
    return path


# --------------------------------------------------------------------------------------------
# headers


def cube_header(path: str | os.PathLike) -> tuple[int, int, int]:
    """(K, H, W-or-packed-bytes) of a photon cube from its header or listing, no frame read:
    ``.npy`` / ``.npy.gz`` give (K, H, ceil(W/8)) of their packed rows (dtype checked), ``.npz``
    its recorded shape, a PNG folder its file count and the first frame's size."""
    path = Path(path)
    fmt = cube_format(path)
    if fmt == "png":
        files = png_frames(path)
        h, w, _ = io.image_shape(files[0])
        return len(files), h, w
    if fmt == "npz":
        try:
            with np.load(path) as z:
                shape = tuple(int(v) for v in z["shape"])
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(f"cannot read photon cube {path}: {e} (expected an .npz with 'packed' and 'shape')") from e
        if len(shape) == 4 and shape[3] == 1:
            shape = shape[:3]
        if len(shape) != 3:
            raise ValueError(f"{path}: frames of shape {shape}; a photon cube is (K, H, W), one raw value per pixel")
        return shape
    try:
        if fmt == "npy.gz":
            with gzip.open(path, "rb") as f:
                shape, _, dtype = _npy_header(f)
        else:
            arr = io.load_npy(path, mmap=True)
            shape, dtype = arr.shape, arr.dtype
    except (OSError, ValueError, EOFError, zlib.error) as e:
        raise ValueError(f"cannot read photon cube {path}: {e} (truncated, or not a {fmt} file?)") from e
    _check_packed(shape, dtype, path)
    return tuple(int(v) for v in shape)


# --------------------------------------------------------------------------------------------
# entry points


def read_cube(
    path: str | os.PathLike, width: int | None = None, bitorder: str = "big", max_frames: int | None = None
) -> np.ndarray:
    """Any photon cube -> bool (K, H, W), the raw sensor plane.

    path: a ``.npy`` / ``.npy.gz`` (``width`` and ``bitorder`` apply), a ``.npz``, a folder of PNG
    frames, or one binary PNG frame (a one-frame cube).
    max_frames: read only the first frames (a plain ``.npy`` is memory-mapped, a ``.npy.gz``
    streamed, so a long capture costs only what is read).
    """
    if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1):
        raise ValueError(f"max_frames={max_frames!r}: must be a positive integer or None")
    if Path(path).is_file() and Path(path).suffix.lower() == ".png":  # one binary frame
        return read_frame_mean(path, 1).counts.astype(bool)[None]
    fmt = cube_format(path)
    if fmt == "png":
        return read_png_frames(path, max_frames)
    if fmt == "npz":
        return read_npz(path, max_frames)
    return read_npy(path, width, bitorder, max_frames)


def write_cube(path: str | os.PathLike, cube: np.ndarray, fmt: str | None = None, bitorder: str = "big") -> Path:
    """Write bool (K, H, W) in ``fmt`` (default: from the name; a name without a known ending is a
    PNG folder). Returns the path written."""
    path = Path(path)
    if fmt is None:
        try:
            fmt = _format_from_name(path)
        except ValueError:
            fmt = "png"
    check_choice("fmt", fmt, FORMATS)
    if fmt == "png":
        return write_png_frames(path, cube)
    if not path.name.lower().endswith("." + fmt):
        raise ValueError(f"write_cube({path}): fmt={fmt!r} needs a name ending in .{fmt}")
    return write_npz(path, cube) if fmt == "npz" else write_npy(path, cube, bitorder)

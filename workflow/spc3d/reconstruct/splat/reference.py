"""Reference alpha-compositing rasterizer for screen-space Gaussians, pure PyTorch (autograd).

Semantics (3D Gaussian Splatting, shared exactly by :mod:`.native`):

* Gaussian g covers the pixels whose centres lie in its 3-sigma square ``|x - mx| <= r``,
  ``|y - my| <= r`` (``r = radii[g]``; pixel (i, j) is centred at ``(j + 0.5, i + 0.5)``).
* per pixel, ``alpha = min(0.99, opacity · exp(power))`` with ``power = -½ dᵀ Σ'⁻¹ d`` and
  ``d = pixel - mean``; pairs with ``power > 0`` or ``alpha < 1/255`` are skipped;
* Gaussians are composited front to back in ascending depth (ties: lower index first); a
  Gaussian that would bring the transmittance below 1e-4 is not composited and ends the pixel;
* ``image = Σ colour · alpha · T + T_final · background``, ``alpha_out = 1 - T_final``;
* a Gaussian with a non-finite input (centre, conic, opacity, colour, depth, radius) is not
  drawn: it is as if absent, and gets zero gradient (``drawable``).

Opacities are expected in [0, 1] (the sigmoid of a parameter). ``rasterize_reference`` is the
"exact pixel pairs" strategy: enumerate each Gaussian's box pixels, drop pairs below 1/255, sort
the pairs stably by (pixel, depth) and composite with segment-wise cumulative sums of log(1 - α).
``rasterize_dense`` evaluates every Gaussian at every pixel: an independent check for tiny scenes.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0  # 3DGS: contributions below this are skipped
ALPHA_MAX = 0.99  # 3DGS: keeps 1 - alpha >= 0.01 so the backward pass can divide by it
T_MIN = 1e-4  # 3DGS: stop compositing a pixel once its transmittance would fall below this
POWER_MIN = -20.0  # exp below ~-87 is denormal and 10-30x slower; alpha < 1/255 anyway below -5.6


def drawable(means2d: Tensor, conics: Tensor, opacities: Tensor, colors: Tensor, depths: Tensor) -> Tensor:
    """(N,) bool: the Gaussians whose inputs are all finite (the others are not drawn)."""
    with torch.no_grad():
        n = len(means2d)
        ok = torch.isfinite(means2d).all(-1) & torch.isfinite(conics).all(-1) & torch.isfinite(colors).all(-1)
        return ok & torch.isfinite(opacities).reshape(n) & torch.isfinite(depths).reshape(n)


def pixel_boxes(means2d: Tensor, radii: Tensor, height: int, width: int) -> Tensor:
    """Inclusive pixel bounds (N, 4) int64 ``x0, x1, y0, y1`` of each 3-sigma square, clipped.

    Computed once in float64 and shared by both back-ends so that they cover identical pixels.
    Empty boxes (culled, off-image, or a non-finite centre or radius) have ``x1 < x0``.
    """
    with torch.no_grad():
        m, r = means2d.detach().double(), radii.double()
        drawn = (r > 0) & torch.isfinite(r) & torch.isfinite(m).all(-1)
        m, r = torch.where(drawn[:, None], m, 0.0), torch.where(drawn, r, 0.0)  # no NaN cast to int64
        # clamps: keep far-off means inside int64 range; results are clipped to the image anyway
        mx, my = m[:, 0].clamp(-1e9, 1e9), m[:, 1].clamp(-1e9, 1e9)
        x0 = torch.ceil(mx - r - 0.5).clamp(0, width)
        x1 = torch.floor(mx + r - 0.5).clamp(-1, width - 1)
        y0 = torch.ceil(my - r - 0.5).clamp(0, height)
        y1 = torch.floor(my + r - 0.5).clamp(-1, height - 1)
        x1 = torch.where(drawn, x1, x0 - 1)  # culled: empty
        return torch.stack([x0, x1, y0, y1], -1).long()


def _pair_power(means2d: Tensor, conics: Tensor, gid: Tensor, px: Tensor, py: Tensor) -> Tensor:
    """Gaussian exponent -½ dᵀ Σ'⁻¹ d (P,) for pairs (gid, pixel column px, pixel row py)."""
    dx = px.to(means2d.dtype) + 0.5 - means2d[gid, 0]
    dy = py.to(means2d.dtype) + 0.5 - means2d[gid, 1]
    a, b, c = conics[gid].unbind(-1)
    return -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy


def _pair_alpha(means2d, conics, opacities, gid, px, py) -> tuple[Tensor, Tensor]:
    """(alpha (P,), keep (P,) bool): 3DGS alpha of each pair and whether it is composited at all."""
    power = _pair_power(means2d, conics, gid, px, py)
    alpha = (opacities[gid] * torch.exp(power.clamp_min(POWER_MIN))).clamp(max=ALPHA_MAX)
    return alpha, (power <= 0) & (alpha >= ALPHA_MIN)


def _enumerate_pairs(boxes: Tensor, depths: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """All (Gaussian, pixel) pairs of the boxes, Gaussians in ascending depth: gid, px, py (P,)."""
    order = torch.argsort(depths.detach(), stable=True)
    b = boxes[order]
    bw, bh = (b[:, 1] - b[:, 0] + 1).clamp_min(0), (b[:, 3] - b[:, 2] + 1).clamp_min(0)
    counts = bw * bh
    total = int(counts.sum())
    owner = torch.repeat_interleave(torch.arange(len(order)), counts)  # (P,) index into order
    local = torch.arange(total) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
    w = bw[owner].clamp_min(1)
    return order[owner], b[owner, 0] + local % w, b[owner, 2] + local // w


def _segment_exclusive_cumsum(values: Tensor, seg_start: Tensor) -> Tensor:
    """Exclusive cumulative sum (P,) of values within consecutive segments (float64 for accuracy).

    seg_start: (P,) index of the first element of each element's segment.
    """
    v = values.double()
    excl = torch.cumsum(v, 0) - v
    return excl - excl[seg_start]


def _sorted_pairs(means2d, conics, opacities, depths, radii, height, width):
    """Composited pairs in (pixel, depth) order: gid, pixel id, segment start (all (P,), no grad)."""
    with torch.no_grad():
        gid, px, py = _enumerate_pairs(pixel_boxes(means2d, radii, height, width), depths)
        alpha, keep = _pair_alpha(means2d, conics, opacities, gid, px, py)
        gid, pix, alpha = gid[keep], (py * width + px)[keep], alpha[keep]
        pix, perm = torch.sort(pix, stable=True)  # stable: keeps depth order within each pixel
        gid, alpha = gid[perm], alpha[perm]
        first = torch.ones_like(pix, dtype=torch.bool)
        first[1:] = pix[1:] != pix[:-1]
        seg_start = torch.cummax(torch.where(first, torch.arange(len(pix)), 0), 0).values
        log_t = torch.log1p(-alpha.double())
        t_after = _segment_exclusive_cumsum(log_t, seg_start) + log_t
        live = t_after >= math.log(T_MIN)  # a prefix of every segment (log T decreases)
        gid, pix = gid[live], pix[live]
        first = first[live]
        seg_start = torch.cummax(torch.where(first, torch.arange(len(pix)), 0), 0).values
        return gid, pix, seg_start


def rasterize_reference(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    depths: Tensor,
    radii: Tensor,
    height: int,
    width: int,
    background: Tensor,
) -> tuple[Tensor, Tensor]:
    """Composite screen-space Gaussians front to back (exact pixel pairs, autograd).

    means2d (N, 2), conics (N, 3), opacities (N,), colors (N, C), depths (N,), radii (N,) int,
    background (C,). Returns image (H, W, C) and alpha (H, W) in the dtype of ``colors``.
    """
    radii = torch.where(drawable(means2d, conics, opacities, colors, depths), radii, 0)
    gid, pix, seg_start = _sorted_pairs(means2d, conics, opacities, depths, radii, height, width)
    alpha, _ = _pair_alpha(means2d, conics, opacities, gid, pix % width, pix // width)
    log_t = torch.log1p(-alpha)
    t_before = torch.exp(_segment_exclusive_cumsum(log_t, seg_start)).to(alpha.dtype)
    weight = (alpha * t_before)[:, None] * colors[gid]  # (P, C)
    image = colors.new_zeros(height * width, colors.shape[1]).index_add(0, pix, weight)
    log_final = log_t.new_zeros(height * width, dtype=torch.float64).index_add(0, pix, log_t.double())
    t_final = torch.exp(log_final).to(colors.dtype)  # (H*W,)
    image = image + t_final[:, None] * background.to(colors)
    return image.reshape(height, width, -1), (1 - t_final).reshape(height, width)


def rasterize_dense(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    depths: Tensor,
    radii: Tensor,
    height: int,
    width: int,
    background: Tensor,
) -> tuple[Tensor, Tensor]:
    """Same contract as :func:`rasterize_reference`, evaluating every Gaussian at every pixel.

    O(N · H · W) memory: for tests on tiny scenes only.
    """
    radii = torch.where(drawable(means2d, conics, opacities, colors, depths), radii, 0)
    order = torch.argsort(depths.detach(), stable=True)
    n, npix = len(order), height * width
    py, px = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    gid = order[:, None].expand(n, npix).reshape(-1)
    pxf, pyf = px.reshape(1, -1).expand(n, npix).reshape(-1), py.reshape(1, -1).expand(n, npix).reshape(-1)
    alpha, keep = _pair_alpha(means2d, conics, opacities, gid, pxf, pyf)
    box = pixel_boxes(means2d, radii, height, width)[gid]
    keep = keep & (pxf >= box[:, 0]) & (pxf <= box[:, 1]) & (pyf >= box[:, 2]) & (pyf <= box[:, 3])
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha)).reshape(n, npix)
    with torch.no_grad():
        live = torch.cumprod(1 - alpha.double(), 0) >= T_MIN  # prefix along depth per pixel
    alpha = alpha * live
    t = torch.cumprod(1 - alpha, 0)  # (N, P) transmittance after each Gaussian
    t_before = torch.cat([torch.ones_like(t[:1]), t[:-1]], 0)
    image = ((alpha * t_before)[:, :, None] * colors[order][:, None, :]).sum(0)
    t_final = t[-1] if n else torch.ones(npix, dtype=colors.dtype)
    image = image + t_final[:, None] * background.to(colors)
    return image.reshape(height, width, -1), (1 - t_final).reshape(height, width)

"""Per-step set-up of the native rasterizer in numba: records, tight boxes, depth order, tile lists.

``prepare_tiles`` replaces ~20 small numpy calls and a numpy stable argsort (together ~1.5 ms per
10k-Gaussian step, as much as the forward kernel on two threads) by three loops over the
Gaussians (~0.5 ms on one thread: records 0.19, sort 0.17, binning 0.13):

1. record + box per Gaussian (vectorised over local column chunks, on torch's threads). The box
   is the 3-sigma square of :func:`.reference.pixel_boxes` intersected with the bounding box of
   the ellipse outside which ``alpha < 1/255`` for sure:
   ``power >= pmin`` <=> ``dᵀ Q d <= -2 pmin`` (Q = conic), whose half-extents are
   ``sqrt(-2 pmin · Q⁻¹_xx)`` and ``sqrt(-2 pmin · Q⁻¹_yy)``. Inflated by 0.1 % + 1e-3 px so
   float32 rounding in the kernels can never put a composited pair outside it. On the
   benchmark scene this cuts the Gaussian-pixel pairs to 63 % and the tile records to 85 %;
   pairs outside the tight box are exactly those both rasterizers skip, so outputs are unchanged.
2. stable LSD radix sort of the visible Gaussians by depth (8-bit digits of the order-preserving
   integer image of the IEEE bits: ties keep the lower index first, as ``torch.argsort(stable)``).
3. counting-sort binning into TILE x TILE tiles (counts from pass 2), depth order kept per tile,
   with the row layout of the float32 kernels' per-block cache (one row per 4x4 block a record
   touches).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .native_threads import in_shares
from .reference import ALPHA_MIN, POWER_MIN

TILE_SHIFT = 4
TILE = 1 << TILE_SHIFT  # tile edge in pixels (3DGS uses 16)
BLOCK_SHIFT = 2  # the float32 kernels walk a tile in 4x4-pixel blocks (native_simd)
# Per-Gaussian float record ``gs[g]`` (8,): mean x, mean y, conic a, b, c, opacity, pmin (the
# lowest exponent at which alpha can still reach 1/255: a cheap pre-test) and exp(-a) (row decay
# of native.py's float64 kernels).
RECORD = 8
BOX_GROW, BOX_PAD = 1e-3, 1e-3  # relative and absolute (px) inflation of the tight ellipse box


@njit(inline="always")
def _pixel_range(m, ext, size):
    """Inclusive pixel indices (as floats) whose centres lie within ``ext`` of ``m``, clipped to
    [0, size): ``pixel_boxes``' float64 formula (empty: hi < lo)."""
    m = min(max(m, -1e9), 1e9)  # keeps far-off means inside int64 range (clipped anyway)
    lo = min(max(np.ceil(m - ext - 0.5), 0.0), float(size))  # np.ceil: a float, vectorisable
    hi = min(max(np.floor(m + ext - 0.5), -1.0), float(size - 1))
    return lo, hi


CHUNK = 256  # Gaussians per vectorised block (see gather_columns)


@njit(inline="always")
def gather_columns(a, c0, n, buf, row):
    """Rows c0..c0+n-1 of a (N, k) array into rows row..row+k-1, columns 0..n-1, of buf; returns
    row + k. Kernels compute on such local column buffers: LLVM vectorises a loop only when it
    can tell its loads and stores apart, which it cannot for strided rows of argument arrays
    (measured: the projection's forward 3x, its backward 2x faster)."""
    for k in range(a.shape[1]):
        for j in range(n):
            buf[row + k, j] = a[c0 + j, k]
    return row + a.shape[1]


@njit(inline="always")
def _record_and_box(mx, my, a, b, c, op, r, height, width, margin, with_decay):
    """One Gaussian's record (8-tuple, see RECORD) and box (x0, x1, y0, y1 as floats), branch-free."""
    # lowest exponent with alpha >= 1/255: log(1 / (255 op)) minus a rounding margin (the exact
    # test follows in the kernel); POWER_MIN as the reference's clamp; op <= 0: never (1 > 0)
    pmin = max(-math.log(op / ALPHA_MIN) - margin, POWER_MIN) if op > 0.0 else 1.0
    det = a * c - b * b
    kappa = -2.0 * pmin * (1.0 + BOX_GROW)
    pd = (a > 0.0) & (c > 0.0) & (det > 0.0) & (det < np.inf)  # positive definite conic
    ext_x = min(r, math.sqrt(max(kappa * c / det, 0.0)) + BOX_PAD) if pd else r
    ext_y = min(r, math.sqrt(max(kappa * a / det, 0.0)) + BOX_PAD) if pd else r
    x0, x1 = _pixel_range(mx, ext_x, width)
    y0, y1 = _pixel_range(my, ext_y, height)
    never = (r <= 0.0) | (pmin > 0.0) | ~((abs(mx) < np.inf) & (abs(my) < np.inf))
    decay = math.exp(-a) if with_decay else 0.0
    return (mx, my, a, b, c, op, pmin, decay), (x0, x0 - 1.0 if never else x1, y0, y1)


@njit(cache=True, nogil=True, error_model="numpy")
def _records_and_boxes(means2d, conics, opacities, radii, height, width, margin, lo, hi, gs, boxes):
    """Gaussians lo..hi-1 into gs (N, 8) and boxes (N, 4) int64 (x0, x1, y0, y1 inclusive;
    empty: x1 < x0); opacities and radii as (N, 1). ``decay`` (gs[:, 7]) only where gs is
    float64 (the float32 kernels do not use it). Vectorised over chunks of local columns."""
    inp, out = np.empty((7, CHUNK)), np.empty((12, CHUNK))
    with_decay = gs.itemsize == 8
    for c0 in range(lo, hi, CHUNK):
        n = min(CHUNK, hi - c0)
        gather_columns(radii, c0, n, inp, gather_columns(opacities, c0, n, inp, gather_columns(
            conics, c0, n, inp, gather_columns(means2d, c0, n, inp, 0))))
        for j in range(CHUNK):  # the vectorised loop (a full chunk: stale columns are ignored)
            rec, box = _record_and_box(inp[0, j], inp[1, j], inp[2, j], inp[3, j], inp[4, j], inp[5, j], inp[6, j],
                                       height, width, margin, with_decay)
            out[0, j], out[1, j], out[2, j], out[3, j], out[4, j], out[5, j], out[6, j], out[7, j] = rec
            out[8, j], out[9, j], out[10, j], out[11, j] = box
        for j in range(n):
            for k in range(RECORD):
                gs[c0 + j, k] = out[k, j]
            for k in range(4):
                boxes[c0 + j, k] = np.int64(out[RECORD + k, j])


@njit(cache=True, nogil=True)
def _sort_by_depth(bits, boxes, nbytes, tiles_x, counts):
    """Indices of the Gaussians with non-empty boxes in ascending depth, ties by index; counts
    (tiles + 1,) gets counts[t + 1] = Gaussians listed in tile t.

    bits: the depths' IEEE bits as signed ints (int32 or int64 view, ``nbytes`` 4 or 8). Negative
    floats get all bits but the sign flipped, which makes signed-integer order float order
    (-0.0 is mapped to +0.0; NaN sorts last, as in torch). LSD radix sort, 8 bits per pass (the
    top byte's sign bit flipped so negatives come first), stable."""
    top = np.int64(1) << (8 * nbytes - 1)
    idx, key = np.empty(len(boxes), np.int64), np.empty(len(boxes), np.int64)
    n_vis = 0
    for g in range(len(boxes)):
        x0, x1, y0, y1 = boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3]
        if x1 < x0 or y1 < y0:
            continue
        for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
            for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                counts[ty * tiles_x + tx + 1] += 1
        k = np.int64(bits[g])
        if k == -top:
            k = 0  # -0.0
        elif k < 0:
            k ^= top - 1
        idx[n_vis], key[n_vis] = g, k
        n_vis += 1
    idx, key = idx[:n_vis], key[:n_vis]
    idx2, key2 = np.empty_like(idx), np.empty_like(key)
    for p in range(nbytes):
        flip = 0x80 if p == nbytes - 1 else 0
        count = np.zeros(257, np.int64)
        for i in range(n_vis):
            count[(((key[i] >> (8 * p)) & 0xFF) ^ flip) + 1] += 1
        if count.max() == n_vis:  # one digit value for all keys: the pass would move nothing
            continue
        for d in range(256):
            count[d + 1] += count[d]
        for i in range(n_vis):
            d = ((key[i] >> (8 * p)) & 0xFF) ^ flip
            idx2[count[d]], key2[count[d]] = idx[i], key[i]
            count[d] += 1
        idx, idx2, key, key2 = idx2, idx, key2, key
    return idx


@njit(inline="always")
def _tile_blocks(x0, x1, y0, y1, tx, ty):
    """Number of BLOCK x BLOCK pixel blocks of tile (tx, ty) that the box x0..x1, y0..y1 (inclusive
    image pixels, clipped to the image) touches: the blocks the float32 kernels walk."""
    ox, oy = tx << TILE_SHIFT, ty << TILE_SHIFT
    nbx = (min(x1 - ox, TILE - 1) >> BLOCK_SHIFT) - (max(x0 - ox, 0) >> BLOCK_SHIFT) + 1
    return nbx * ((min(y1 - oy, TILE - 1) >> BLOCK_SHIFT) - (max(y0 - oy, 0) >> BLOCK_SHIFT) + 1)


@njit(cache=True, nogil=True)
def _bin_tiles(boxes, order, counts, tiles_x):
    """Per-tile Gaussian lists in ``order`` (counting sort; counts from ``_sort_by_depth``):
    offsets (tiles + 1,) and ids (M,) int32, tile t holds ids[offsets[t]:offsets[t + 1]]; and the
    block layout of the float32 kernels' G cache: record k owns the rows from
    bases[t] + rel[k] on, one per block it touches (``_tile_blocks``), bases (tiles + 1,) int64."""
    offsets = np.cumsum(counts)
    fill = offsets[:-1].copy()
    ids, rel = np.empty(offsets[-1], np.int32), np.empty(offsets[-1], np.int32)
    bases = np.zeros(len(offsets), np.int64)
    for g in order:
        x0, x1, y0, y1 = boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3]
        for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
            for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                t = ty * tiles_x + tx
                ids[fill[t]], rel[fill[t]] = g, bases[t + 1]
                fill[t] += 1
                bases[t + 1] += _tile_blocks(x0, x1, y0, y1, tx, ty)
    for t in range(len(offsets) - 1):
        bases[t + 1] += bases[t]
    return offsets, ids, rel, bases


def prepare_tiles(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray, depths: np.ndarray,
                  radii: np.ndarray, height: int, width: int, dtype) -> tuple:
    """(gs (N, 8) ``dtype``, boxes (N, 4) int64, offsets (tiles + 1,), ids (M,) int32, rel (M,)
    int32, bases (tiles + 1,) int64): see ``_bin_tiles``.

    Any float dtype and memory layout of the inputs (no copies); depths may be float32 or float64.
    Pass 1 runs on torch's threads (contiguous shares), passes 2-3 on this one.
    """
    n = len(means2d)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    gs, boxes = np.empty((n, RECORD), dtype), np.empty((n, 4), np.int64)
    # margin below log(1/(255 op)): float32 kernels evaluate exp as a polynomial
    margin = 1e-9 if dtype == np.float64 else 1e-4
    in_shares(_records_and_boxes, n, (means2d, conics, opacities.reshape(n, 1), radii.reshape(n, 1), height, width,
                                      margin), (gs, boxes))
    if depths.dtype not in (np.float32, np.float64):
        depths = depths.astype(np.float64)
    bits = np.ascontiguousarray(depths).view(np.int32 if depths.dtype == np.float32 else np.int64)
    counts = np.zeros(tiles_x * tiles_y + 1, np.int64)
    order = _sort_by_depth(bits, boxes, bits.itemsize, tiles_x, counts)
    return (gs, boxes, *_bin_tiles(boxes, order, counts, tiles_x))

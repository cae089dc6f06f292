"""Per-step set-up of the native rasterizer in numba: records, tight boxes, tile lists in depth order.

``prepare_tiles`` replaces ~20 small numpy calls and a numpy stable argsort (together as costly as
the forward kernel) by two passes over the Gaussians, both split over torch's threads, and a
sort per tile (faster than a serial global sort and binning):

1. record + box per Gaussian (vectorised over local column chunks). The box is the 3-sigma
   square of :func:`.reference.pixel_boxes` intersected with the bounding box of the ellipse
   outside which ``alpha < 1/255`` for sure:
   ``power >= pmin`` <=> ``dᵀ Q d <= -2 pmin`` (Q = conic), whose half-extents are
   ``sqrt(-2 pmin · Q⁻¹_xx)`` and ``sqrt(-2 pmin · Q⁻¹_yy)``. Inflated by 0.1 % + 1e-3 px so
   float32 rounding in the kernels can never put a composited pair outside it. On the
   benchmark scene this cuts the Gaussian-pixel pairs to 63 % and the tile records to 85 %;
   pairs outside the tight box are exactly those both rasterizers skip, so outputs are unchanged.
   A Gaussian that cannot be drawn (radius <= 0, alpha < 1/255 everywhere, or any non-finite
   input) gets the empty box (0, -1, 0, -1) before the float -> int conversion, and boxes are
   clamped to the image again in integers: every tile index, list length and cache size below
   derives from in-image boxes, whatever the input values.
   The same pass counts each chunk's records per tile, the 4x4 blocks the boxes touch (the size
   of the float32 kernels' per-pair cache) and the depth sort keys.
2. counting-sort binning into TILE x TILE tiles, each chunk of Gaussians into its own slots of
   every tile's list (chunks in index order, so every list is in Gaussian index order).
3. a stable LSD radix sort of each tile's list by depth (``sort_tile``; 8-bit digits of the
   order-preserving integer image of the IEEE bits, ties keep the lower index first, as
   ``torch.argsort(stable)``): done here, or by the float32 forward kernel for the tiles it
   takes, so that it runs in parallel.

The measured set-up times are in docs/benchmarks.md.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from spc3d.reconstruct.splat.native_threads import in_chunks, next_chunk
from spc3d.reconstruct.splat.reference import ALPHA_MIN, POWER_MIN

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
    (it made the projection's forward and backward much faster)."""
    for k in range(a.shape[1]):
        for j in range(n):
            buf[row + k, j] = a[c0 + j, k]
    return row + a.shape[1]


@njit(inline="always")
def _finite(x):
    """x is neither NaN nor ±inf (branch-free, vectorisable)."""
    return abs(x) < np.inf


@njit(inline="always")
def _all_finite(flat, lo, hi):
    """flat[lo:hi] (1-D, contiguous) holds no NaN or ±inf (an and-reduction: vectorised)."""
    ok = True
    for i in range(lo, hi):
        ok &= abs(flat[i]) < np.inf
    return ok


@njit(cache=True, nogil=True)
def all_finite(a, b):
    """Neither 1-D array holds a NaN or ±inf (one vectorised pass over each array: much faster
    than the same test per 256-Gaussian chunk)."""
    return _all_finite(a, 0, len(a)) & _all_finite(b, 0, len(b))


@njit(inline="always")
def mark_non_finite(colors, n_ch, depths, c0, n, buf, row, check):
    """buf[row, j] = 0 if Gaussian c0 + j has a finite depth and colour (colors: (N * n_ch,)
    contiguous, depths (N,) contiguous), else NaN, for j < n; ``check`` False (``all_finite``
    said so): all 0 without looking."""
    for j in range(CHUNK):
        buf[row, j] = 0.0
    if not check:
        return
    for j in range(n):
        if not (_all_finite(colors, (c0 + j) * n_ch, (c0 + j + 1) * n_ch) and abs(depths[c0 + j]) < np.inf):
            buf[row, j] = np.nan


@njit(inline="always")
def _record_and_box(mx, my, a, b, c, op, r, rest, height, width, margin, with_decay):
    """One Gaussian's record (8-tuple, see RECORD) and box (x0, x1, y0, y1 as floats), branch-free.

    The box is empty, (0, -1, 0, -1), unless the Gaussian can be drawn: radius > 0, an opacity
    that can reach 1/255, and finite centre, conic and opacity (so no NaN or inf ever reaches the
    float -> int conversion of the box, which would be undefined, nor a kernel). Its corners are
    then finite floats inside [0, size] / [-1, size - 1]. ``rest``: 0 where the Gaussian's other
    inputs (colour, depth) are finite (see ``mark_non_finite``)."""
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
    # r > 0, pmin <= 0 rather than "not <= 0", "not > 0": NaN compares false, so culls too
    drawn = (r > 0.0) & (r < np.inf) & (pmin <= 0.0) & _finite(mx) & _finite(my) & _finite(a) & _finite(b) \
        & _finite(c) & _finite(op) & _finite(x0) & _finite(x1) & _finite(y0) & _finite(y1) & (rest == 0.0)
    decay = math.exp(-a) if with_decay else 0.0
    # one select per corner (a select of the tuple made LLVM branch: the set-up took 8 % longer)
    return (mx, my, a, b, c, op, pmin, decay), ((x0 if drawn else 0.0), (x1 if drawn else -1.0),
                                                (y0 if drawn else 0.0), (y1 if drawn else -1.0))


@njit(inline="always")
def _depth_key(bits, nbytes):
    """Order-preserving integer image of a float's IEEE bits (signed int of ``nbytes`` 4 or 8):
    negative floats get all bits but the sign flipped, so signed-integer order is float order
    (-0.0 maps to +0.0; NaN sorts last, as in torch)."""
    top = np.int64(1) << (8 * nbytes - 1)
    k = np.int64(bits)
    if k == -top:
        return np.int64(0)  # -0.0
    return k ^ (top - 1) if k < 0 else k


@njit(cache=True, nogil=True, error_model="numpy")
def _records_and_boxes(means2d, conics, opacities, radii, colors, n_ch, depths, check, bits, height, width, tiles_x,
                       margin, counter, total, gs, boxes, keys, counts, blocks):
    """The chunks of CHUNK of the ``total`` Gaussians this worker takes (``next_chunk``) into gs
    (N, 8), boxes (N, 4) int64 (x0, x1, y0, y1 inclusive; empty: x1 < x0) and keys (N,)
    (``_depth_key`` of bits, the depths' IEEE bits as signed ints); opacities and radii as
    (N, 1). Gaussians with a non-finite input get an empty box: they are in no tile list (colors
    (N * n_ch,) and depths (N,), both contiguous, are only looked at where ``check``). Chunk c's
    records per tile into counts[c] (chunks, tiles), its 4x4 blocks (summed over tiles: blocks
    are tile-aligned) into blocks[c]. ``decay`` (gs[:, 7]) only where gs is float64 (the float32
    kernels do not use it). Vectorised over chunks of local columns."""
    inp, out = np.empty((8, CHUNK)), np.empty((12, CHUNK))
    with_decay = gs.itemsize == 8
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        c = c0 // CHUNK
        gather_columns(radii, c0, n, inp, gather_columns(opacities, c0, n, inp, gather_columns(
            conics, c0, n, inp, gather_columns(means2d, c0, n, inp, 0))))
        mark_non_finite(colors, n_ch, depths, c0, n, inp, 7, check)
        for j in range(CHUNK):  # the vectorised loop (a full chunk: stale columns are ignored)
            rec, box = _record_and_box(inp[0, j], inp[1, j], inp[2, j], inp[3, j], inp[4, j], inp[5, j], inp[6, j],
                                       inp[7, j], height, width, margin, with_decay)
            out[0, j], out[1, j], out[2, j], out[3, j], out[4, j], out[5, j], out[6, j], out[7, j] = rec
            out[8, j], out[9, j], out[10, j], out[11, j] = box
        n_blocks = 0  # summed locally: neighbouring chunks' blocks[c] share a cache line
        for j in range(n):
            g = c0 + j
            for k in range(RECORD):
                gs[g, k] = out[k, j]
            # finite here (``_record_and_box``); clamped to the image again, in integers, so that no
            # input can make a tile index below leave [0, tiles)
            x0, x1 = max(np.int64(out[8, j]), 0), min(np.int64(out[9, j]), width - 1)
            y0, y1 = max(np.int64(out[10, j]), 0), min(np.int64(out[11, j]), height - 1)
            boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3] = x0, x1, y0, y1
            keys[g] = _depth_key(bits[g], bits.itemsize)
            if x1 < x0 or y1 < y0:
                continue
            for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
                for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                    counts[c, ty * tiles_x + tx] += 1
            bw, bh = (x1 >> BLOCK_SHIFT) - (x0 >> BLOCK_SHIFT) + 1, (y1 >> BLOCK_SHIFT) - (y0 >> BLOCK_SHIFT) + 1
            n_blocks += bw * bh
        blocks[c] = n_blocks


@njit(cache=True, nogil=True)
def _bin_chunks(boxes, tiles_x, counter, total, fills, ids):
    """The chunks of CHUNK Gaussians this worker takes into the tile lists, in index order: chunk
    c's next slot in tile t is fills[c, t]."""
    while True:
        c0, n = next_chunk(counter, total, CHUNK)
        if n <= 0:
            break
        c = c0 // CHUNK
        for g in range(c0, c0 + n):
            x0, x1, y0, y1 = boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3]
            if x1 < x0 or y1 < y0:
                continue
            for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
                for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                    t = ty * tiles_x + tx
                    ids[fills[c, t]] = g
                    fills[c, t] += 1


@njit(inline="always")
def sort_tile(ids, keys, lo, hi, nbytes, buf_ids, buf_keys, count):
    """Stable LSD radix sort of ids[lo:hi] by keys[ids] (8-bit digits, the top one's sign bit
    flipped so that negative keys come first; a digit equal for all keys is skipped). Scratch:
    buf_ids (int32) and buf_keys (int64) of at least 2 (hi - lo), count (257,) int64."""
    n = hi - lo
    if n < 2:
        return
    for i in range(n):
        buf_ids[i], buf_keys[i] = ids[lo + i], keys[ids[lo + i]]
    src = 0  # the keys and ids are in buf[src:src + n]
    for p in range(nbytes):
        flip = 0x80 if p == nbytes - 1 else 0
        for d in range(257):
            count[d] = 0
        for i in range(src, src + n):
            count[(((buf_keys[i] >> (8 * p)) & 0xFF) ^ flip) + 1] += 1
        if count.max() == n:  # one digit value for all keys: the pass would move nothing
            continue
        dst = n - src
        count[0] = dst
        for d in range(256):
            count[d + 1] += count[d]
        for i in range(src, src + n):
            d = ((buf_keys[i] >> (8 * p)) & 0xFF) ^ flip
            buf_ids[count[d]], buf_keys[count[d]] = buf_ids[i], buf_keys[i]
            count[d] += 1
        src = dst
    for i in range(n):
        ids[lo + i] = buf_ids[src + i]


@njit(inline="always")
def sort_scratch(offsets):
    """Scratch arrays (buf_ids, buf_keys, count) for ``sort_tile`` on any of these tile lists."""
    longest = max(1, np.max(offsets[1:] - offsets[:-1]))
    return np.empty(2 * longest, np.int32), np.empty(2 * longest, np.int64), np.empty(257, np.int64)


@njit(cache=True, nogil=True)
def sort_tiles(ids, keys, offsets, nbytes):
    """``sort_tile`` for every tile list."""
    buf_ids, buf_keys, count = sort_scratch(offsets)
    for t in range(len(offsets) - 1):
        sort_tile(ids, keys, offsets[t], offsets[t + 1], nbytes, buf_ids, buf_keys, count)


MAX_RECORDS = (1 << 31) - 2  # tile-list entries: the kernels store list positions + 1 as int32


def check_sizes(height, width) -> tuple[int, int]:
    """(height, width) as ints >= 1, or a ValueError naming them."""
    if type(height) is int and type(width) is int and height > 0 and width > 0:
        return height, width
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (height, width)) \
            or height < 1 or width < 1:
        raise ValueError(f"image size height={height!r}, width={width!r}: both must be integers >= 1")
    return int(height), int(width)


def check_shapes(n: int, **arrays) -> None:
    """Every array has n rows and the named shape: a ValueError naming the first that does not
    (the kernels index them by Gaussian and column without bounds checks)."""
    for name, (a, cols) in arrays.items():
        shape = a.shape
        if (shape == (n,)) if cols == 0 else (len(shape) == 2 and shape[0] == n and (cols < 0 or shape[1] == cols)):
            continue  # the usual case, fast
        shape = tuple(shape)
        if cols == 0:  # one value per Gaussian
            ok = shape in ((n,), (n, 1))
        else:
            ok = len(shape) == 2 and shape[0] == n and (cols < 0 or shape[1] == cols)
        if not ok:
            want = f"({n},)" if cols == 0 else f"({n}, {cols if cols > 0 else 'C'})"
            raise ValueError(f"{name} has shape {shape}, expected {want} (N = {n} Gaussians)")


def prepare_tiles(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray, depths: np.ndarray,
                  radii: np.ndarray, height: int, width: int, dtype, sort: bool = True,
                  colors: np.ndarray | None = None) -> tuple:
    """(gs (N, 8) ``dtype``, boxes (N, 4) int64, offsets (tiles + 1,), ids (M,) int32, keys (N,)
    int64, key bytes, blocks): tile t lists ids[offsets[t]:offsets[t + 1]], in depth order
    (``sort=False``: in index order, for the caller to ``sort_tile`` by keys), blocks: the
    4x4-pixel blocks all lists touch (rows of the float32 kernels' per-pair cache).

    Any float dtype and memory layout of the inputs (no copies); depths may be float32 or float64.
    Passes 1 and 2 run on torch's threads, which take chunks of CHUNK Gaussians as they go.
    Any values: a Gaussian with a non-finite input (colors (N, C) too, when given), radius <= 0
    or an opacity below 1/255 is in no list; shapes and sizes are checked (ValueError).
    """
    n = len(means2d)
    height, width = check_sizes(height, width)
    colors = np.empty((n, 0), np.float32) if colors is None else colors
    if colors.ndim != 2:
        raise ValueError(f"colors has shape {colors.shape}, expected ({n}, C) (N = {n} Gaussians)")
    check_shapes(n, means2d=(means2d, 2), conics=(conics, 3), opacities=(opacities, 0), depths=(depths, 0),
                 radii=(radii, 0), colors=(colors, -1))
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    gs, boxes, keys = np.empty((n, RECORD), dtype), np.empty((n, 4), np.int64), np.empty(n, np.int64)
    if depths.dtype not in (np.float32, np.float64):
        depths = depths.astype(np.float64)
    depths = np.ascontiguousarray(depths).reshape(n)
    bits = depths.view(np.int32 if depths.dtype == np.float32 else np.int64)
    n_chunks = max(1, -(-n // CHUNK))
    counts, blocks = np.zeros((n_chunks, tiles_x * tiles_y), np.int64), np.zeros(n_chunks, np.int64)
    # margin below log(1/(255 op)): float32 kernels evaluate exp as a polynomial
    margin = 1e-9 if dtype == np.float64 else 1e-4
    flat_colors = np.ascontiguousarray(colors).reshape(-1)
    check = not all_finite(flat_colors, depths)  # usually all finite: no per-Gaussian test
    in_chunks(_records_and_boxes, n, (means2d, conics, opacities.reshape(n, 1), radii.reshape(n, 1), flat_colors,
                                      colors.shape[1], depths, check, bits, height, width, tiles_x, margin),
              (gs, boxes, keys, counts, blocks))
    starts = np.zeros(counts.size + 1, np.int64)  # first slot per (tile, chunk), tile-major
    starts[1:] = np.cumsum(counts.T)
    offsets = starts[::n_chunks].copy()
    if offsets[-1] > MAX_RECORDS:
        raise ValueError(f"prepare_tiles: {offsets[-1]} Gaussian-tile pairs ({n} Gaussians, {height}x{width} "
                         f"pixels), more than the {MAX_RECORDS} the kernels can index")
    fills = starts[:-1].reshape(-1, n_chunks).T.copy()  # (chunk, tile): the chunk's first slot
    ids = np.empty(offsets[-1], np.int32)
    in_chunks(_bin_chunks, n, (boxes, tiles_x), (fills, ids))
    if sort:
        sort_tiles(ids, keys, offsets, bits.itemsize)
    return gs, boxes, offsets, ids, keys, bits.itemsize, int(blocks.sum())

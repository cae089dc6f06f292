"""float32 tile kernels for :mod:`.native`, written so that LLVM vectorises them (SIMD).

The float64 kernels of :mod:`.native` walk each pixel row with data-dependent branches and a
sequential exp recurrence, and spend most of their time on mispredicted branches.
Here a Gaussian updates 4x4-pixel blocks of the tile, 16 lanes at once: every lane computes its
pair branch-free (the tests become masks and selects), exp is a short polynomial instead of a
libm call, and all loops run over the 16 lanes of fixed-size per-tile buffers, so each block is
a few dozen vector instructions (AVX2 / AVX-512). Lanes outside the Gaussian's box are masked
off, so the semantics are exactly those of :mod:`.reference` (same tests, same order, float32).

Why 4x4 blocks: the boxes are small (radii 2-10 px) and tightened to the visible ellipse
(:mod:`.native_prep`), so 16-pixel tile rows left most lanes idle; on the benchmark scene 4x4
blocks need fewer visits per forward than 16-pixel rows or 2x2 blocks of 8-pixel half rows.
Per-tile state (transmittance, colour behind, last contributor, dL/dimage) is copied into
contiguous [block, lane] buffers at the start of a tile and back at its end.
Per-Gaussian gradient sums are kept per lane (``acc``) and reduced once per Gaussian and tile.
The forward stores each visited pair's G = exp(power) (0 where the pair is skipped or outside
the box) in a cache, one 16-lane row per record and block; the backward reads it instead of
evaluating the exponent and the box tests again, so its alpha is the forward's, bit for bit.
RGB only (3 channels written out, so that one loop carries everything): other channel counts
use native.py's kernels.

What it takes for LLVM to vectorise (each checked: without it the code ran much slower):
``error_model="numpy"`` (the default "python" model tests every float division for zero and
raises), no array views created in the hot loops (``T[r]`` or ``acc[:] = 0`` cost atomic
reference counts; index ``T[b, j]``), one loop holding the channels, lane indices that LLVM can
prove non-negative (numba's wraparound of negative indices otherwise makes every address
data-dependent), and a constant trip count of 16. What makes it fast: record parameters
loaded once per record (LLVM cannot hoist them past stores to the tile buffers), fused
multiply-adds (``fastmath={"contract"}`` only), exponents in log2 units (exp2 needs no
Cody-Waite reduction), one flat loop over a record's blocks (one loop exit to predict instead of
one per block row), all float tile state as views of one buffer indexed by unsigned block and
row numbers (separate allocations made LLVM test at run time, before every block, whether any
two of them overlap), and the finished-pixel count added in int32 (numba widened it to int64,
and LLVM then vectorised only 8 lanes wide). docs/benchmarks.md says what each measurement
decided; the A/B figures of code versions gone are in its git history.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core.extending import intrinsic

from spc3d.reconstruct.splat.native_prep import sort_scratch, sort_tile
from spc3d.reconstruct.splat.native_threads import next_item, next_items
from spc3d.reconstruct.splat.reference import ALPHA_MAX, ALPHA_MIN, POWER_MIN, T_MIN

L = 16  # tile edge, and lanes per 4x4 block
F = np.float32
_LOG2E = F(1.4426950408889634)
_C1, _C2, _C3, _C4, _C5, _C6 = (F(math.log(2.0) ** k / math.factorial(k)) for k in range(1, 7))
_HALF, _ONE, _ZERO = F(0.5), F(1.0), F(0.0)
_AMAX, _AMIN, _TMIN, _PMIN2 = F(ALPHA_MAX), F(ALPHA_MIN), F(T_MIN), F(POWER_MIN * math.log2(math.e))


@intrinsic
def _pow2_neg(typingctx, m):
    """2^-m as float32 for an int32 m in [-126, 126]: the IEEE bits (127 - m) << 23. An intrinsic
    because numba widens int32 arithmetic to int64 (int64 vector shifts and conversions)."""
    if m != types.int32:
        return None

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        bits = builder.shl(builder.sub(ir.Constant(i32, 127), args[0]), ir.Constant(i32, 23))
        return builder.bitcast(bits, ir.FloatType())

    return types.float32(types.int32), codegen


@njit(inline="always")
def _exp2(x):
    """2^x for x in [POWER_MIN log2(e), 0] (clamped), float32, relative error < 3e-7: x = r - m
    with m an integer (r in [-1/2, 1/2], exact), degree-6 Taylor of exp(r ln 2), times 2^-m
    (m <= 29: exact, from its IEEE bits). Exponents arrive in log2 units (the conic is scaled
    once per record), which saves the range reduction and a multiply per lane over exp."""
    x = min(_ZERO, max(_PMIN2, x))  # this order maps NaN to _PMIN2: m below is always in [0, 29]
    m = np.int32(_HALF - x)
    r = x + F(m)
    p = _ONE + r * (_C1 + r * (_C2 + r * (_C3 + r * (_C4 + r * (_C5 + r * _C6)))))
    return p * _pow2_neg(m)


@njit(inline="always")
def _lane_alpha(a, b, c, opacity, pmin, dx, dy):
    """(alpha, G, ok, shape_ok) of one pair, conic (a, b, c) and pmin in log2 units (times log2 e):
    ok = composited if the pixel is live (power in [pmin, 0], alpha >= 1/255); shape_ok = alpha
    not clamped (gradient reaches opacity and shape)."""
    power = -_HALF * (a * dx * dx + c * dy * dy) - b * dx * dy
    G = _exp2(power)
    raw = opacity * G
    alpha = min(_AMAX, raw)
    ok = (power <= _ZERO) & (power >= pmin) & (alpha >= _AMIN)
    return alpha, G, ok, raw <= _AMAX


@njit(inline="always")
def _local_span(boxes, g, tx0, ty0, w, h):
    """Gaussian g's box inside the tile in tile coordinates: x0, x1, y0, y1 (inclusive)."""
    return (max(boxes[g, 0] - tx0, 0), min(boxes[g, 1] - tx0, w - 1),
            max(boxes[g, 2] - ty0, 0), min(boxes[g, 3] - ty0, h - 1))


# lane j of a 4x4 block: column j % 4, row j // 4 (as float32: all lane arithmetic stays in one
# 16 x float32 vector; integer lane indices would take int64 vectors and conversions)
_LANE_X = np.array([j & 3 for j in range(L)], np.float32)
_LANE_Y = np.array([j >> 2 for j in range(L)], np.float32)


@njit(inline="always")
def _block_origin(b, tx0, ty0):
    """Block b's corner as float32: tile-local column and row, and the image coordinates of its
    first pixel centre."""
    bx, by = (b & 3) << 2, (b >> 2) << 2
    return F(bx), F(by), F(tx0 + bx) + _HALF, F(ty0 + by) + _HALF


@njit(inline="always")
def _blocks(span):
    """The 4x4 blocks a tile-local span covers: first block column and row, blocks per row, count."""
    bx0, by0 = span[0] >> 2, span[2] >> 2
    nbx = (span[1] >> 2) - bx0 + 1
    return bx0, by0, nbx, nbx * ((span[3] >> 2) - by0 + 1)


@njit(inline="always")
def _block(q, bx0, by0, nbx):
    """Index of the q-th block (row-major) of a span's blocks."""
    by, bx = divmod(q, nbx)
    return ((by0 + by) << 2) + bx0 + bx


@njit(inline="always")
def _record(gs, colors, boxes, g, tx0, ty0, w, h):
    """Gaussian g's tile-local span (ints, for the block loop) and, loaded once per tile record
    (loads inside the block loops would be repeated: LLVM cannot prove the tile buffers do not
    alias gs), its parameters as float32 scalars: mean x, y, conic a, b, c and pmin in log2 units
    (times log2 e, for ``_lane_alpha``), opacity, colour 0-2, and the span x0, x1, y0, y1."""
    span = _local_span(boxes, g, tx0, ty0, w, h)
    rec = (gs[g, 0], gs[g, 1], gs[g, 2] * _LOG2E, gs[g, 3] * _LOG2E, gs[g, 4] * _LOG2E, gs[g, 6] * _LOG2E, gs[g, 5],
           colors[g, 0], colors[g, 1], colors[g, 2], F(span[0]), F(span[1]), F(span[2]), F(span[3]))
    return span, rec


@njit(inline="always")
def _fwd_block(rec, k, b, tx0, ty0, T, last, img, gcache, o):
    """One Gaussian (``_record``) over the 16 lanes of block b: updates T, last (16, 16) and img
    (3, 16, 16) [block, lane], and stores the pairs' G = exp(power) in gcache[o] (0 where the pair
    is skipped or outside the box) for the backward. Returns the number of pixels that finished
    here. Scalar indexing only: array views in hot loops would cost atomic reference counts."""
    mx, my, la, lb, lc, lpmin, opacity, c0, c1, c2, x0, x1, y0, y1 = rec
    bx, by, fx, fy = _block_origin(b, tx0, ty0)
    k1 = np.int32(k + 1)
    # unsigned (no negative-index wraparound) and b masked to 0..15 (a no-op): LLVM can then prove
    # that the parts of the tile buffer do not overlap and drops its run-time alias checks
    b, o = np.uint64(b) & np.uint64(L - 1), np.uint64(o)
    n_stop = np.int32(0)
    for j in range(L):
        lx, ly = bx + _LANE_X[j], by + _LANE_Y[j]  # exact: small integers
        # pixel centre - mean with one rounding, as the reference (fx + lane is exact)
        alpha, G, ok, _ = _lane_alpha(la, lb, lc, opacity, lpmin, (fx + _LANE_X[j]) - mx, (fy + _LANE_Y[j]) - my)
        ok = ok & (lx >= x0) & (lx <= x1) & (ly >= y0) & (ly <= y1)
        gcache[o, j] = G if ok else _ZERO
        t = T[b, j]
        ok = ok & (t > _ZERO)
        t_next = t * (_ONE - alpha)
        stop = ok & (t_next < _TMIN)
        use = ok & (t_next >= _TMIN)
        w = alpha * t if use else _ZERO
        img[0, b, j] += c0 * w
        img[1, b, j] += c1 * w
        img[2, b, j] += c2 * w
        T[b, j] = -t if stop else (t_next if use else t)
        last[b, j] = k1 if use else last[b, j]
        n_stop = np.int32(n_stop + np.int32(stop))  # int32 lanes (numba would widen the sum to int64)
    return n_stop


ROWS = 256  # G-cache rows a worker reserves at a time


def cache_rows(blocks: int, workers: int) -> int:
    """G-cache rows that ``forward_tiles32`` may reserve for lists touching ``blocks`` 4x4 blocks:
    a worker takes ROWS at a time and leaves fewer than L (the most one record needs) unused."""
    return blocks + (blocks // (ROWS - L) + 1 + workers) * ROWS


@njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def forward_tiles32(gs, boxes, colors, bg, offsets, ids, tiles, counter, height, width, tiles_x, image, alpha_out,
                    t_final, n_contrib, keys, key_bytes, rows, gcache, reserved):
    """Front-to-back compositing, float32: one worker takes tiles[counter[0]++] until none are left.

    gs (N, 8) float32 records (see native_prep.py), boxes (N, 4) int64, colors (N, 3), bg (3,).
    Writes image (H, W, 3) with background, alpha_out (H, W), t_final (H, W) and n_contrib (H, W)
    (int32: tile-list position after the last contributor). key_bytes > 0: the tile lists are
    in index order and each is first sorted by depth here (``native_prep.sort_tile``), in place,
    for the backward too. For the backward, the pairs' G: record k's blocks in gcache rows
    rows[k]..., taken ROWS at a time from reserved[0] (``cache_rows`` gives enough); records
    behind the last one a tile visits get none, the backward never reads them.
    """
    last, tb = np.empty((L, L), np.int32), np.empty((4, L, L), np.float32)
    T, img = tb[0], tb[1:4]  # one buffer: LLVM sees that its parts cannot overlap
    buf_ids, buf_keys, count = sort_scratch(offsets)
    o, o_end = 0, 0
    while True:
        i = next_item(counter)
        if i >= len(tiles):
            break
        t = tiles[i]
        if key_bytes > 0:
            sort_tile(ids, keys, offsets[t], offsets[t + 1], key_bytes, buf_ids, buf_keys, count)
        tx0, ty0 = (t % tiles_x) * L, (t // tiles_x) * L
        w, h = min(L, width - tx0), min(L, height - ty0)
        T[:], last[:], img[:] = _ONE, 0, _ZERO
        n_live = w * h
        for k in range(offsets[t], offsets[t + 1]):
            g = ids[k]
            span, rec = _record(gs, colors, boxes, g, tx0, ty0, w, h)
            bx0, by0, nbx, nb = _blocks(span)
            if o + nb > o_end:
                o = next_items(reserved, ROWS)
                o_end = o + ROWS
                if o_end > len(gcache):
                    raise RuntimeError("forward_tiles32: G cache too small (allocate cache_rows(blocks, workers))")
            rows[k] = o
            for q in range(nb):  # one loop over the blocks: one loop exit to predict, not one per row
                n_live -= _fwd_block(rec, k, _block(q, bx0, by0, nbx), tx0, ty0, T, last, img, gcache, o + q)
            o += nb
            if n_live == 0:
                break
        _store_tile(img, T, last, bg, tx0, ty0, w, h, image, alpha_out, t_final, n_contrib)


@njit(inline="always")
def _store_tile(img, T, last, bg, tx0, ty0, w, h, image, alpha_out, t_final, n_contrib):
    for r in range(h):
        for i in range(w):
            b, j = ((r >> 2) << 2) + (i >> 2), ((r & 3) << 2) + (i & 3)
            tf = abs(T[b, j])
            t_final[ty0 + r, tx0 + i] = tf
            alpha_out[ty0 + r, tx0 + i] = _ONE - tf
            n_contrib[ty0 + r, tx0 + i] = last[b, j]
            for ch in range(3):
                image[ty0 + r, tx0 + i, ch] = img[ch, b, j] + tf * bg[ch]


@njit(inline="always")
def _load_tile(t_final, n_contrib, grad_image, grad_alpha, bg, tx0, ty0, w, h, T, last, gimg, gtail, behind, dbg, t):
    """Tile state for the backward pass, [block, lane] as in the forward; lanes outside the image
    get last = 0 (never used). Writes the tile's dL/dbackground = Σ T_final · dL/dimage to dbg[t]."""
    T[:], last[:], gimg[:], gtail[:], behind[:] = _ONE, 0, _ZERO, _ZERO, _ZERO
    for ch in range(3):
        dbg[t, ch] = _ZERO
    for r in range(h):
        for i in range(w):
            b, j = ((r >> 2) << 2) + (i >> 2), ((r & 3) << 2) + (i & 3)
            tf = t_final[ty0 + r, tx0 + i]
            T[b, j] = tf
            last[b, j] = n_contrib[ty0 + r, tx0 + i]
            g_bg = _ZERO
            for ch in range(3):
                gc = grad_image[ty0 + r, tx0 + i, ch]
                gimg[ch, b, j] = gc
                g_bg += gc * bg[ch]
                dbg[t, ch] += tf * gc
            gtail[b, j] = tf * (grad_alpha[ty0 + r, tx0 + i] - g_bg)


@njit(inline="always")
def _bwd_block(rec, k, b, tx0, ty0, T, last, gimg, gtail, behind, acc, gcache, o):
    """One Gaussian over the 16 lanes of block b, back to front: recovers T, updates the colour
    behind (3, 16, 16) and adds the pair's gradient terms per lane into acc (9, 16): d_power
    times dx, dy, dx², dx·dy, dy² (see ``_reduce_lanes``), dL/dopacity, dL/dcolour 0-2 (as
    native.py's ``_backward_tile``). G comes from the forward (gcache[o], 0: pair skipped), so
    alpha and every test are those of the forward, bit for bit."""
    mx, my, la, lb, lc, lpmin, opacity, c0, c1, c2, x0, x1, y0, y1 = rec
    bx, by, fx, fy = _block_origin(b, tx0, ty0)
    k32 = np.int32(k)
    # unsigned (no negative-index wraparound) and b masked to 0..15 (a no-op): LLVM can then prove
    # that the parts of the tile buffer do not overlap and drops its run-time alias checks
    b, o = np.uint64(b) & np.uint64(L - 1), np.uint64(o)
    for j in range(L):
        dx, dy = (fx + _LANE_X[j]) - mx, (fy + _LANE_Y[j]) - my
        G = gcache[o, j]
        raw = opacity * G
        alpha = min(_AMAX, raw)
        use = (G > _ZERO) & (k32 < last[b, j])
        inv = _ONE / (_ONE - alpha)
        t = T[b, j] * inv if use else T[b, j]  # now the transmittance in front of g
        T[b, j] = t
        al = alpha if use else _ZERO
        g0, g1, g2 = gimg[0, b, j], gimg[1, b, j], gimg[2, b, j]
        b0, b1, b2 = behind[0, b, j], behind[1, b, j], behind[2, b, j]
        w = al * t
        acc[6, j] += w * g0
        acc[7, j] += w * g1
        acc[8, j] += w * g2
        d_alpha = ((c0 - b0) * g0 + (c1 - b1) * g1 + (c2 - b2) * g2) * t + gtail[b, j] * inv
        behind[0, b, j] = al * c0 + (_ONE - al) * b0
        behind[1, b, j] = al * c1 + (_ONE - al) * b1
        behind[2, b, j] = al * c2 + (_ONE - al) * b2
        da = d_alpha if use & (raw <= _AMAX) else _ZERO  # clamped alpha: no gradient to opacity, shape
        d_power = da * alpha
        px, py = d_power * dx, d_power * dy
        acc[0, j] += px
        acc[1, j] += py
        acc[2, j] += px * dx
        acc[3, j] += px * dy
        acc[4, j] += py * dy
        acc[5, j] += da * G


@njit(inline="always")
def _lane_sum(acc, j):
    """Sum of acc[j] over the 16 lanes: a pairwise tree (short dependency chains)."""
    return ((((acc[j, 0] + acc[j, 8]) + (acc[j, 4] + acc[j, 12]))
             + ((acc[j, 2] + acc[j, 10]) + (acc[j, 6] + acc[j, 14])))
            + (((acc[j, 1] + acc[j, 9]) + (acc[j, 5] + acc[j, 13]))
               + ((acc[j, 3] + acc[j, 11]) + (acc[j, 7] + acc[j, 15]))))


@njit(inline="always")
def _reduce_lanes(acc, g, gs, drec, k):
    """The gradient of tile record k (Gaussian g) from the lane sums of acc (9, 16) into drec[k]:
    dL/d(mean x, y, conic a, b, c, opacity, colour 0-2). The lanes carry the
    first and second moments of d_power = dL/dpower about the mean, Σ d_power·(dx, dy, dx², dx·dy,
    dy²); the mean and conic gradients follow from them once per record: dL/dmean = Q Σ d_power·d
    (Q = conic), dL/d(a, b, c) = -(½ Σ d_power·dx², Σ d_power·dx·dy, ½ Σ d_power·dy²)."""
    s0, s1 = _lane_sum(acc, 0), _lane_sum(acc, 1)
    a, bc, c = gs[g, 2], gs[g, 3], gs[g, 4]  # the conic in natural units
    drec[k, 0] = a * s0 + bc * s1
    drec[k, 1] = bc * s0 + c * s1
    drec[k, 2] = -_HALF * _lane_sum(acc, 2)
    drec[k, 3] = -_lane_sum(acc, 3)
    drec[k, 4] = -_HALF * _lane_sum(acc, 4)
    for j in range(5, 9):
        drec[k, j] = _lane_sum(acc, j)


@njit(nogil=True, cache=True, fastmath={"contract"}, error_model="numpy")
def backward_tiles32(gs, boxes, colors, bg, offsets, ids, tiles, counter, height, width, tiles_x, t_final, n_contrib,
                     rows, gcache, grad_image, grad_alpha, drec, dbg):
    """Gradients per tile-list record, tiles taken as in ``forward_tiles32``: drec (M, 9) gets
    record k's dL/d(mean x, y, conic a, b, c, opacity, colour 0-2) (zeros behind the tile's last
    contributor), dbg (tiles, 3) tile t's dL/dbackground. Nothing is summed across tiles here,
    so the result does not depend on which worker took which tile (see ``sum_records``)."""
    last = np.empty((L, L), np.int32)
    tb = np.empty((9, L, L), np.float32)  # one buffer: LLVM sees that its parts cannot overlap
    T, gimg, gtail, behind, acc = tb[0], tb[1:4], tb[4], tb[5:8], tb[8, :9]
    while True:
        i = next_item(counter)
        if i >= len(tiles):
            break
        t = tiles[i]
        tx0, ty0 = (t % tiles_x) * L, (t // tiles_x) * L
        w, h = min(L, width - tx0), min(L, height - ty0)
        _load_tile(t_final, n_contrib, grad_image, grad_alpha, bg, tx0, ty0, w, h, T, last, gimg, gtail, behind, dbg, t)
        stop = max(last.max(), offsets[t])
        for k in range(stop, offsets[t + 1]):  # behind the last contributor: no gradient
            for j in range(9):
                drec[k, j] = _ZERO
        for k in range(stop - 1, offsets[t] - 1, -1):
            g = ids[k]
            span, rec = _record(gs, colors, boxes, g, tx0, ty0, w, h)
            for q in range(9):  # not acc[:] = 0: a slice is a view (atomic reference counts)
                for j in range(L):
                    acc[q, j] = _ZERO
            bx0, by0, nbx, nb = _blocks(span)
            o = rows[k]
            for q in range(nb):
                _bwd_block(rec, k, _block(q, bx0, by0, nbx), tx0, ty0, T, last, gimg, gtail, behind, acc, gcache, o + q)
            _reduce_lanes(acc, g, gs, drec, k)


@njit(nogil=True, cache=True, error_model="numpy")
def sum_records(ids, drec, n):
    """Per-Gaussian gradients from per-record ones: dgs (n, 6), dcol (n, 3), summed in list order
    (one fixed order: the same bits for any number of threads)."""
    dgs, dcol = np.zeros((n, 6), np.float32), np.zeros((n, 3), np.float32)
    for k in range(len(ids)):
        g = ids[k]
        for j in range(6):
            dgs[g, j] += drec[k, j]
        for j in range(3):
            dcol[g, j] += drec[k, 6 + j]
    return dgs, dcol

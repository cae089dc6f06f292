"""Tile-based Gaussian rasterizer with hand-written gradients in numba (CPU), autograd-wrapped.

``rasterize_native`` has exactly the signature, outputs and semantics of
:func:`.reference.rasterize_reference` (see that module). float32 RGB inputs (training) run the
vectorised float32 kernels of :mod:`.native_simd`; any other dtype or channel count runs the
float64 kernels of this module (so float64 inputs give a float64 path for gradcheck) and
returns the dtype of ``colors``. Both follow the algorithm below.

Algorithm (the 3DGS CUDA rasterizer, mapped to CPU threads):

1. set-up (:func:`.native_prep.prepare_tiles`, two numba passes on all threads): per-Gaussian
   records, pixel boxes (the 3-sigma square of :func:`.reference.pixel_boxes` tightened to the
   ellipse outside which alpha < 1/255, so no composited pair is lost) and per-tile lists:
   every TILE x TILE tile lists the Gaussians whose box touches it, in depth order (a stable
   radix sort per list; the float32 forward sorts each list itself, in parallel).
2. forward (float64: ``_forward_tile``; float32: 4x4-pixel SIMD blocks, :mod:`.native_simd`):
   the tile's list is walked front to back, Gaussian-major: each Gaussian updates the
   still-unfinished pixels of its box inside the tile (its parameters stay in registers; no
   pixel tests Gaussians whose box misses it). Pairs with alpha < 1/255 are skipped; a pixel
   stops before its transmittance would drop below 1e-4. Per pixel it stores the final
   transmittance and the list position after its last contributor; the float32 forward also
   keeps every visited pair's G = exp(power) for the backward (~4 MB at 10k Gaussians, 128x96).
3. backward (``_backward_tile`` / :mod:`.native_simd`): the list is walked back to front from the
   last contributor, recovering ``T_k = T_{k+1} / (1 - alpha_k)`` (alpha <= 0.99 keeps this
   stable) and the colour composited behind, accumulating dL/d(means2d, conics, opacities,
   colors) per Gaussian, then once into the worker's buffer; dL/dbackground = Σ T_final · dL/dimage.
4. float64 kernels evaluate exp(power) by a per-row recurrence (``_row_step``); the float32
   kernels use a polynomial exp2 on exponents in log2 units (the backward reuses the forward's).

Threads: ``torch.get_num_threads()`` workers. The float32 kernels take tiles from a shared atomic
counter, longest tile lists first (a worker that starts late or runs slower takes fewer tiles,
which beat a fixed round-robin deal), and write gradients per tile-list record, which
``native_simd.sum_records`` adds up per Gaussian in list order: no races, and the same bits for
any thread count. The set-up and projection passes deal chunks of 256 Gaussians the same way.
The float64 kernels deal tiles round-robin, each worker adding into its own gradient buffers,
summed at the end. The workers are the threads of torch's own OpenMP team
(:mod:`.native_threads`): separate threads competed with torch's spin-waiting OpenMP workers for
the cores. ``parallel=True`` / ``prange`` is avoided on purpose: numba's OpenMP layer made every
parallel region wait for torch's pool, and forcing numba's process-global threading layer would
change other users.

Speed: ``benchmarks/rasterizer.py`` times training steps against the PyTorch reference
(docs/benchmarks.md shows its recorded output and the choices earlier measurements made; their
figures, per region and per kernel generation, are in that file's git history).

Any input values (numba does not check bounds, so this is what keeps the kernels in bounds): the
set-up draws a Gaussian only if its centre, conic, opacity, colour and depth are finite, its
radius is > 0 and its opacity can reach 1/255; anything else gets an empty box before any float
becomes an integer (a NaN converted to int64 is INT64_MIN: it once sent a tile index far outside
its array, SIGSEGV). Boxes are clamped to the image again in integers, so every tile index, list
length and G-cache row derives from in-image boxes; the kernels' exponent arithmetic maps NaN
(overflowing conics) to "skip". Non-finite Gaussians are thus absent: zero gradient, no effect on
the others. Sizes and shapes are checked (ValueError), as is a finite background; cameras are
checked by the projections (:class:`.project.CameraError`).

Densification: the view-space positional gradient of 3DGS is ``means2d.grad`` (in pixels; call
``means2d.retain_grad()`` before ``backward``); nothing extra is returned.

Why numba rather than a C++/OpenMP torch extension: nothing to compile at install time (no
compiler or matching torch headers on the user's machine), plain Python files, portable across
platforms and torch versions, and ``cache=True`` stores the machine code next to the source.
The costs: numba as a dependency and a first-call JIT compile of all splat kernels, far shorter
when loaded from the cache (``benchmarks/rasterizer.py`` times both in fresh processes).
Kernels use no fast-math except ``contract`` (fused multiply-add) in the float32 kernels: IEEE
semantics otherwise, so NaN / inf and the clamps behave as in the reference.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit
from torch import Tensor

from spc3d.reconstruct.splat.native_prep import TILE, prepare_tiles
from spc3d.reconstruct.splat.native_simd import backward_tiles32, cache_rows, forward_tiles32, sum_records
from spc3d.reconstruct.splat.native_threads import n_workers, run_parallel
from spc3d.reconstruct.splat.reference import ALPHA_MAX, ALPHA_MIN, T_MIN


@njit(inline="always")
def _row_step(a, b, c, decay, pmin, dx, dy, g_next, e_next, in_run):
    """One pixel of a walk along a pixel row: returns (G, g_next, e_next, in_run), G = exp(power)
    of the Gaussian at offset (dx, dy) = pixel centre - mean, or 0 where the pair is skipped.

    Along a row, G(dx + 1) = G(dx) · E(dx) and E(dx + 1) = E(dx) · exp(-a) (``decay``), so exp is
    evaluated twice per run of pixels instead of once per pixel: exp dominated both kernels.
    Relative error ~1e-15 over a run (runs stay inside one 16-px tile). The
    forward and backward kernels walk identical pixel sequences, so they get identical G.
    """
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    if not pmin <= power <= 0.0:  # alpha < 1/255 for sure, a non-PSD conic, or NaN (overflow): skip
        return 0.0, 0.0, 0.0, False
    if not in_run:
        g_next = math.exp(power)
        e_next = math.exp(-0.5 * a * (2.0 * dx + 1.0) - b * dy)
    g, e = g_next * e_next, e_next * decay
    # the run goes on only while the recurrence stays finite (it overflows for extreme conics)
    return g_next, g, e, (abs(g) < np.inf) & (abs(e) < np.inf)


@njit(inline="always")
def _span(boxes, g, rect):
    """Pixel bounds x0, x1, y0, y1 (inclusive) of Gaussian g's box inside a tile rectangle."""
    return max(rect[0], boxes[g, 0]), min(rect[1], boxes[g, 1]), max(rect[2], boxes[g, 2]), min(rect[3], boxes[g, 3])


@njit(inline="always")
def _tile_rect(t, tiles_x, tile, height, width):
    """Pixel bounds x0, x1, y0, y1 (inclusive) of tile t."""
    ty, tx = t // tiles_x, t % tiles_x
    return tx * tile, min(tx * tile + tile, width) - 1, ty * tile, min(ty * tile + tile, height) - 1


@njit(inline="always")
def _forward_tile(gs, boxes, colors, ids, start, stop, rect, image, t_final, n_contrib):
    """Composite one tile, Gaussian-major: each listed Gaussian (front to back) updates the
    still-live pixels of its box inside the tile, so parameters load once per tile and only
    overlapping pairs are visited. Per-pixel state lives in t_final / n_contrib (H, W)."""
    tx0, tx1, ty0, ty1 = rect
    n_live = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
    row_live = np.full(ty1 - ty0 + 1, tx1 - tx0 + 1)  # unfinished pixels per row: skip dead rows
    for k in range(start, stop):
        g = ids[k]
        mx, my, a, b, c = gs[g, 0], gs[g, 1], gs[g, 2], gs[g, 3], gs[g, 4]
        opacity, pmin, decay = gs[g, 5], gs[g, 6], gs[g, 7]
        x0, x1, y0, y1 = _span(boxes, g, rect)
        for py in range(y0, y1 + 1):
            if row_live[py - ty0] == 0:
                continue
            dy = py + 0.5 - my
            g_next, e_next, in_run = 0.0, 0.0, False
            for px in range(x0, x1 + 1):
                G, g_next, e_next, in_run = _row_step(a, b, c, decay, pmin, px + 0.5 - mx, dy, g_next, e_next, in_run)
                T = t_final[py, px]
                if G == 0.0 or T < 0.0:  # skipped pair, or pixel finished (negative transmittance)
                    continue
                alpha = min(ALPHA_MAX, opacity * G)
                if alpha < ALPHA_MIN:
                    continue
                t_next = T * (1.0 - alpha)
                if t_next < T_MIN:
                    t_final[py, px] = -T
                    n_live -= 1
                    row_live[py - ty0] -= 1
                    continue
                w = alpha * T
                for ch in range(colors.shape[1]):
                    image[py, px, ch] += colors[g, ch] * w
                t_final[py, px] = t_next
                n_contrib[py, px] = k + 1
        if n_live == 0:
            break


@njit(nogil=True, cache=True, fastmath=False)
def _forward_tiles(gs, boxes, colors, offsets, ids, tiles, height, width, tile, tiles_x, image, t_final, n_contrib):
    """Front-to-back compositing of the listed tiles (one worker's share).

    gs: (N, 8) float64 records; boxes (N, 4); colors (N, C); tiles (T,) tile indices. Writes
    image (H, W, C) (without background), t_final (H, W) (negated where a pixel stopped early)
    and n_contrib (H, W): tile-list position after the last contributor.
    """
    for t in tiles:
        _forward_tile(gs, boxes, colors, ids, offsets[t], offsets[t + 1], _tile_rect(t, tiles_x, tile, height, width),
                      image, t_final, n_contrib)


@njit(inline="always")
def _backward_tile(gs, boxes, colors, ids, start, rect, t_final, n_contrib, grad_image, g_tail, T, behind, dgs, dcol):
    """Back-to-front gradients of one tile, Gaussian-major (see module docstring).

    g_tail (H, W) = T_final · (dL/dalpha_out - background · dL/dimage): the gradient terms
    through the final transmittance, which reach every alpha_k as g_tail / (1 - alpha_k).
    T (H, W) and behind (H, W, C) are scratch: the transmittance in front of the current
    Gaussian and the colour composited behind it, per pixel. Adds into dgs (N, 6), dcol (N, C).
    """
    tx0, tx1, ty0, ty1 = rect
    n_ch = colors.shape[1]
    row_stop = np.zeros(ty1 - ty0 + 1, np.int64)  # per row: list position after its last contributor
    for py in range(ty0, ty1 + 1):
        for px in range(tx0, tx1 + 1):
            T[py, px] = t_final[py, px]
            behind[py, px, :] = 0.0
            row_stop[py - ty0] = max(row_stop[py - ty0], n_contrib[py, px])
    stop = row_stop.max()
    for k in range(stop - 1, start - 1, -1):
        g = ids[k]
        mx, my, a, b, c = gs[g, 0], gs[g, 1], gs[g, 2], gs[g, 3], gs[g, 4]
        opacity, pmin, decay = gs[g, 5], gs[g, 6], gs[g, 7]
        d_mx = d_my = d_a = d_b = d_c = d_op = 0.0
        x0, x1, y0, y1 = _span(boxes, g, rect)
        for py in range(y0, y1 + 1):
            if k >= row_stop[py - ty0]:
                continue
            dy = py + 0.5 - my
            g_next, e_next, in_run = 0.0, 0.0, False
            for px in range(x0, x1 + 1):
                dx = px + 0.5 - mx
                G, g_next, e_next, in_run = _row_step(a, b, c, decay, pmin, dx, dy, g_next, e_next, in_run)
                if G == 0.0 or k >= n_contrib[py, px]:
                    continue
                alpha = min(ALPHA_MAX, opacity * G)
                if alpha < ALPHA_MIN:
                    continue
                inv = 1.0 / (1.0 - alpha)
                T[py, px] *= inv  # now the transmittance in front of g
                w = alpha * T[py, px]
                d_alpha = 0.0
                for ch in range(n_ch):
                    gc = grad_image[py, px, ch]
                    dcol[g, ch] += w * gc
                    d_alpha += (colors[g, ch] - behind[py, px, ch]) * gc
                    behind[py, px, ch] = alpha * colors[g, ch] + (1.0 - alpha) * behind[py, px, ch]
                d_alpha = d_alpha * T[py, px] + g_tail[py, px] * inv
                if opacity * G > ALPHA_MAX:  # clamped alpha: no gradient to opacity or shape
                    continue
                d_op += d_alpha * G
                d_power = d_alpha * alpha
                d_mx += d_power * (a * dx + b * dy)
                d_my += d_power * (b * dx + c * dy)
                d_a += -0.5 * d_power * dx * dx
                d_b += -d_power * dx * dy
                d_c += -0.5 * d_power * dy * dy
        dgs[g, 0] += d_mx
        dgs[g, 1] += d_my
        dgs[g, 2] += d_a
        dgs[g, 3] += d_b
        dgs[g, 4] += d_c
        dgs[g, 5] += d_op


@njit(nogil=True, cache=True, fastmath=False)
def _backward_tiles(gs, boxes, colors, offsets, ids, tiles, t_final, n_contrib, grad_image, g_tail,
                    height, width, tile, tiles_x, T, behind, dgs, dcol):
    """Gradients of the listed tiles (one worker's share), added into that worker's own buffers
    dgs (N, 6) (mean x, mean y, conic a, b, c, opacity) and dcol (N, C). T (H, W) and behind
    (H, W, C) are scratch shared by all workers (tiles own disjoint pixels)."""
    for t in tiles:
        _backward_tile(gs, boxes, colors, ids, offsets[t], _tile_rect(t, tiles_x, tile, height, width),
                       t_final, n_contrib, grad_image, g_tail, T, behind, dgs, dcol)


def _run_workers(kernel, n_tiles: int, args_for) -> None:
    """Run ``kernel(*args_for(worker, tiles))`` on tiles dealt round-robin to
    :func:`.native_threads.n_workers` workers (torch's OpenMP team; the kernels release the GIL)."""
    n = n_workers(n_tiles)
    run_parallel(lambda w: kernel(*args_for(w, np.arange(w, n_tiles, n))), n)


def _forward(gs, boxes, cols, bg, offsets, ids, height, width, tiles_x):
    """image (H, W, C), final transmittance (H, W), n_contrib (H, W) (see ``_forward_tiles``)."""
    image = np.zeros((height, width, cols.shape[1]))
    t_final = np.ones((height, width))
    n_contrib = np.zeros((height, width), np.int64)
    _run_workers(_forward_tiles, len(offsets) - 1, lambda w, tiles: (
        gs, boxes, cols, offsets, ids, tiles, height, width, TILE, tiles_x, image, t_final, n_contrib))
    np.abs(t_final, out=t_final)
    image += t_final[:, :, None] * bg
    return image, t_final, n_contrib


def _backward(gs, boxes, cols, bg, offsets, ids, t_final, n_contrib, g_img, g_alpha, height, width, tiles_x):
    """dgs (N, 6), dcol (N, C), dbg (C,): per-worker buffers summed at the end."""
    n_work = n_workers(len(offsets) - 1)
    dgs = np.zeros((n_work, len(gs), 6))
    dcol = np.zeros((n_work, len(gs), cols.shape[1]))
    T, behind = np.empty((height, width)), np.empty((height, width, cols.shape[1]))
    g_tail = t_final * (g_alpha - g_img @ bg)  # (H, W)
    _run_workers(_backward_tiles, len(offsets) - 1, lambda w, tiles: (
        gs, boxes, cols, offsets, ids, tiles, t_final, n_contrib, g_img, g_tail, height, width, TILE,
        tiles_x, T, behind, dgs[w], dcol[w]))
    return dgs.sum(0), dcol.sum(0), np.einsum("hw,hwc->c", t_final, g_img)


def _dynamic(kernel, head: tuple, tail: tuple, tiles: np.ndarray) -> None:
    """``kernel(*head, tiles, counter, *tail)`` on every worker: the tiles, in the order of
    ``tiles``, are dealt out dynamically from a shared counter."""
    counter = np.zeros(1, np.int64)
    run_parallel(lambda w: kernel(*head, tiles, counter, *tail), n_workers(len(tiles)))


def _forward32(gs, boxes, cols, bg, lists, height, width, tiles_x):
    """float32 path (:mod:`.native_simd`; lists = (offsets, ids, keys, key bytes, blocks) of
    ``prepare_tiles(sort=False)``: the workers sort the lists they take): image (H, W, C) with
    background, alpha, t_final, n_contrib, and for the backward the tile order (longest lists
    first, so the last tiles taken are short), each record's first G-cache row, the G cache."""
    offsets, ids, keys, key_bytes, blocks = lists
    tiles = np.argsort(offsets[:-1] - offsets[1:], kind="stable")
    image = np.empty((height, width, cols.shape[1]), np.float32)
    alpha, t_final = np.empty((height, width), np.float32), np.empty((height, width), np.float32)
    n_contrib = np.empty((height, width), np.int32)
    rows, gcache = np.empty(len(ids), np.int64), np.empty((cache_rows(blocks, n_workers(len(tiles))), TILE), np.float32)
    _dynamic(forward_tiles32, (gs, boxes, cols, bg, offsets, ids), (height, width, tiles_x, image, alpha, t_final,
             n_contrib, keys, key_bytes, rows, gcache, np.zeros(1, np.int64)), tiles)
    return image, alpha, t_final, n_contrib, tiles, rows, gcache


def _backward32(gs, boxes, cols, bg, lists, t_final, n_contrib, tiles, rows, gcache, g_img, g_alpha, height, width,
                tiles_x):
    """float32 path: dgs (N, 6), dcol (N, 3), dbg (3,): per tile-list record and per tile, then
    summed in one fixed order (bit-identical for any thread count)."""
    offsets, ids = lists[:2]
    drec = np.empty((len(ids), 9), np.float32)
    dbg = np.empty((len(offsets) - 1, cols.shape[1]), np.float32)
    _dynamic(backward_tiles32, (gs, boxes, cols, bg, offsets, ids),
             (height, width, tiles_x, t_final, n_contrib, rows, gcache, g_img, g_alpha, drec, dbg), tiles)
    dgs, dcol = sum_records(ids, drec, len(gs))
    return dgs, dcol, dbg.sum(0)


def _np(t: Tensor, dtype) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy(), dtype=dtype)


class _RasterizeNative(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, background, depths, radii, height, width):
        # float32 RGB: the SIMD kernels of native_simd; anything else: the float64 kernels here
        f32 = colors.dtype == torch.float32 and colors.shape[1] == 3
        dt = np.float32 if f32 else np.float64
        cols, bg = _np(colors, dt), _np(background.reshape(-1), dt)
        if not math.isfinite(bg.sum()) and not np.isfinite(bg).all():  # the sum: a faster test
            raise ValueError(f"rasterize_native: the background must be finite, got {bg.tolist()}")
        gs, boxes, *lists = prepare_tiles(means2d.detach().numpy(), conics.detach().numpy(),
                                          opacities.detach().numpy(), depths.detach().numpy(), radii.numpy(),
                                          height, width, dt, sort=not f32, colors=cols)
        tiles_x = -(-width // TILE)
        ctx.sizes = (height, width, tiles_x)
        ctx.dtypes = (means2d.dtype, conics.dtype, opacities.dtype, colors.dtype, background.dtype)
        if f32:
            image, alpha, t_final, n_contrib, *cache = _forward32(gs, boxes, cols, bg, lists, height, width, tiles_x)
            ctx.kernel_args = (gs, boxes, cols, bg, lists, t_final, n_contrib, *cache)
            return torch.from_numpy(image), torch.from_numpy(alpha)
        offsets, ids = lists[:2]
        image, t_final, n_contrib = _forward(gs, boxes, cols, bg, offsets, ids, height, width, tiles_x)
        ctx.kernel_args = (gs, boxes, cols, bg, offsets, ids, t_final, n_contrib)
        return torch.from_numpy(image).to(colors.dtype), torch.from_numpy(1.0 - t_final).to(colors.dtype)

    @staticmethod
    def backward(ctx, grad_image, grad_alpha):
        dt = ctx.kernel_args[0].dtype
        g_img, g_a = _np(grad_image, dt), _np(grad_alpha, dt)
        if dt == np.float32:
            dgs, dcol, dbg = _backward32(*ctx.kernel_args, g_img, g_a, *ctx.sizes)
        else:
            dgs, dcol, dbg = _backward(*ctx.kernel_args, g_img, g_a, *ctx.sizes)
        dgs, t_m, t_c, t_o, t_col, t_bg = torch.from_numpy(dgs), *ctx.dtypes
        return (dgs[:, 0:2].to(t_m), dgs[:, 2:5].to(t_c), dgs[:, 5].to(t_o), torch.from_numpy(dcol).to(t_col),
                torch.from_numpy(dbg).to(t_bg), None, None, None, None)


def rasterize_native(
    means2d: Tensor, conics: Tensor, opacities: Tensor, colors: Tensor, depths: Tensor, radii: Tensor,
    height: int, width: int, background: Tensor,
) -> tuple[Tensor, Tensor]:
    """Composite screen-space Gaussians (numba kernels); same contract as ``rasterize_reference``.

    means2d (N, 2), conics (N, 3), opacities (N,), colors (N, C), depths (N,), radii (N,) int,
    background (C,). Returns image (H, W, C) and alpha (H, W) in the dtype of ``colors``.
    Any values are safe: a Gaussian with a non-finite input is not drawn and gets zero gradient;
    wrong shapes, sizes < 1 or a non-finite background raise a ValueError.
    """
    if means2d.device.type != "cpu":
        raise ValueError(f"rasterize_native runs on CPU tensors, got means2d on {means2d.device}; "
                         "use backend='reference' (any device) or move the tensors to the CPU")
    # sizes and the other shapes: prepare_tiles
    if colors.dim() != 2 or background.numel() != colors.shape[1]:
        raise ValueError(f"colors {tuple(colors.shape)} and background {tuple(background.shape)}: expected (N, C) "
                         "and C values")
    return _RasterizeNative.apply(means2d, conics, opacities, colors, background, depths, radii, height, width)

"""Speed of the SPC simulator against a plain memory copy of its (bit-packed) output.

    python benchmarks/spc_simulator.py [--width 1024 --height 768 --frames 8 --repeats 5]

For each mode ("bernoulli", "paper"), image size (the given one and a quarter-size one) and K in
{1, --frames}, it times ``spc.simulate_frames`` (median of ``--repeats`` after a warm-up) and
prints the time per frame, the output rate in MB/s of packed bits (1 bit per pixel and channel),
and the time of ``np.copyto`` of an equally sized uint8 array (median of many repeats) as the ratio
simulator / memcpy. The ratio is large by design: the simulator is bound by the random-number
rate (one uint32 per bit in bernoulli mode, one float64 normal per bit in paper mode) plus a
per-image setup (sRGB decode, detection probabilities, thresholds) that K = 1 pays in full, not by
memory bandwidth. The last line, ``ratio_bernoulli_1024x768_K1: <ratio>``, is machine-readable.
``--smoke``: 32x24 px, K = 2, one repeat (seconds; its ratios mean nothing).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from spc3d.physics import spc
from spc3d.physics.flux_scale import calibrate_flux_scale


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up: page faults, caches, lazy allocations
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _memcpy_time(nbytes: int) -> float:
    """Median time of copying ``nbytes`` between two preallocated uint8 arrays."""
    src = np.random.default_rng(0).integers(0, 256, nbytes, dtype=np.uint8)
    dst = np.empty_like(src)
    return _median_time(lambda: np.copyto(dst, src), repeats=max(51, 2_000_000 // max(nbytes, 1)))


def _scene(height: int, width: int) -> np.ndarray:
    """A smooth float32 sRGB test image (H, W, 3): gradients spanning dark to bright."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    img = np.stack([x / max(width - 1, 1), y / max(height - 1, 1), 0.5 + 0.5 * np.sin(x / 17 + y / 23)], -1)
    return img.astype(np.float32)


def run_case(mode: str, height: int, width: int, frames: int, repeats: int) -> dict:
    img = _scene(height, width)
    params = spc.SPCParams(mode=mode, frames=frames)
    scale = calibrate_flux_scale([img], params, 0.5)
    rng = spc.view_rng(0, "benchmark", 0)
    t_sim = _median_time(lambda: spc.simulate_frames(img, scale, params, rng), repeats)
    nbytes = -(-frames * img.size // 8)  # packed output: 1 bit per pixel and channel
    t_copy = _memcpy_time(nbytes)
    return {
        "mode": mode,
        "size": f"{width}x{height}",
        "K": frames,
        "ms_per_frame": 1e3 * t_sim / frames,
        "MB_per_s": nbytes / t_sim / 1e6,
        "memcpy_ms": 1e3 * t_copy,
        "ratio": t_sim / t_copy,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1024)
    ap.add_argument("--height", type=int, default=768)
    ap.add_argument("--frames", type=int, default=8, help="the larger K (K = 1 is always run)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(width=32, height=24, frames=2, repeats=1)
    sizes = [(args.height, args.width), (max(args.height // 4, 1), max(args.width // 4, 1))]
    rows = [
        run_case(mode, h, w, k, args.repeats) for mode in spc.MODES for h, w in sizes for k in sorted({1, args.frames})
    ]
    print(f"{'mode':<10} {'size':>10} {'K':>3} {'ms/frame':>9} {'MB/s':>8} {'memcpy ms':>10} {'sim/memcpy':>11}")
    for r in rows:
        print(
            f"{r['mode']:<10} {r['size']:>10} {r['K']:>3} {r['ms_per_frame']:>9.2f} {r['MB_per_s']:>8.1f} "
            f"{r['memcpy_ms']:>10.4f} {r['ratio']:>11.0f}"
        )
    head = rows[0]  # bernoulli, the given size, K = 1
    print(f"ratio_{head['mode']}_{head['size']}_K{head['K']}: {head['ratio']:.1f}")


if __name__ == "__main__":
    main()

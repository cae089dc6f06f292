"""Speed of the Gaussian-splatting rasterizers: numba native vs the pure-PyTorch reference.

    python benchmarks/rasterizer.py [--threads 1 --repeats 5 --min-seconds 1.5 --sizes 2000,10000,30000]

For each Gaussian count and image size (64x64, 128x96) it builds a random forward-facing scene
(camera at the origin looking down +z, fx = fy = W, depths 2-6, positions spread over the view,
anisotropic scales giving 3-sigma radii of about 2-10 px, opacities sigmoid(N(0, 1.5))), and times
one training step forward+backward: projection + rasterization + L1 loss to a random target,
gradients w.r.t. means, scales, quaternions, opacities, colours and background, for three variants:

    native         project_gaussians_native + rasterize(backend="native")
    native raster  project_gaussians (PyTorch)  + rasterize(backend="native")
    reference      project_gaussians (PyTorch)  + rasterize(backend="reference")  (exact pixel pairs)

It prints the median iterations/s (the variants take turns in runs of 4 consecutive steps, so all
see the same load from other jobs; the first step after a switch is not timed), the speed-up
native / reference, and the numba
first-call compile time measured in fresh processes with an empty cache and with the cache filled.
The last line, ``speedup_10k_128x96: <ratio>``, is machine-readable.
``--smoke``: 300 Gaussians, one run, no compile timing in fresh processes (seconds; its rates mean nothing).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import torch

from spc3d.reconstruct.splat import project_gaussians, project_gaussians_native, rasterize

SIZES = ((64, 64), (96, 128))  # (height, width)


def make_scene(n: int, height: int, width: int, seed: int = 0) -> dict:
    """Random forward-facing Gaussians (leaf tensors requiring grad) and camera for one view."""
    g = torch.Generator().manual_seed(seed)
    f = float(width)
    z = 2 + 4 * torch.rand(n, generator=g)
    u = (-0.05 + 1.1 * torch.rand(n, generator=g)) * width  # a little beyond the borders
    v = (-0.05 + 1.1 * torch.rand(n, generator=g)) * height
    means = torch.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], -1)
    sigma_px = 0.4 * 5 ** torch.rand(n, 1, generator=g)  # 0.4..2 px -> radii ~2..10 px
    scales = sigma_px * z[:, None] / f * torch.exp(0.3 * torch.randn(n, 3, generator=g))
    leaves = {
        "means": means,
        "scales": scales,
        "quats": torch.randn(n, 4, generator=g),
        "opacities": torch.sigmoid(1.5 * torch.randn(n, generator=g)),
        "colors": torch.rand(n, 3, generator=g),
        "background": torch.rand(3, generator=g),
    }
    leaves = {k: t.requires_grad_() for k, t in leaves.items()}
    w2c = torch.cat([torch.eye(3), torch.zeros(3, 1)], 1)
    camera = dict(w2c=w2c, fx=f, fy=f, cx=width / 2, cy=height / 2, height=height, width=width)
    return {"leaves": leaves, "camera": camera, "target": torch.rand(height, width, 3, generator=g)}


# name -> (projection, rasterizer back-end)
VARIANTS = {
    "native": (project_gaussians_native, "native"),
    "native raster": (project_gaussians, "native"),
    "reference": (project_gaussians, "reference"),
}


def train_step(scene: dict, variant: str) -> None:
    """One forward+backward; gradients land in the leaves (cleared first)."""
    project, backend = VARIANTS[variant]
    p, cam = scene["leaves"], scene["camera"]
    for t in p.values():
        t.grad = None
    proj = project(p["means"], p["scales"], p["quats"], **cam)
    image, _ = rasterize(
        proj.means2d,
        proj.conics,
        p["opacities"],
        p["colors"],
        proj.depths,
        proj.radii,
        cam["height"],
        cam["width"],
        p["background"],
        backend=backend,
    )
    (image - scene["target"]).abs().mean().backward()


def iterations_per_s(scene: dict, backends: tuple[str, ...], repeats: int, min_seconds: float, run: int = 4) -> dict:
    """Median it/s per variant over at least ``repeats`` runs of ``run`` consecutive steps each
    (and ``min_seconds`` in all). The variants take turns run by run, so that all see the same
    machine load; the first step of each run is not timed: right after a switch it pays for the
    other variant's cache and allocator churn (the reference moves ~100 MB per step), which a
    training loop, running one variant step after step, never sees."""
    times = {b: [] for b in backends}
    start = time.perf_counter()
    while min(len(t) for t in times.values()) < repeats * run or time.perf_counter() - start < min_seconds:
        for b in backends:
            train_step(scene, b)
            for _ in range(run):
                t0 = time.perf_counter()
                train_step(scene, b)
                times[b].append(time.perf_counter() - t0)
    return {b: 1.0 / statistics.median(t) for b, t in times.items()}


def compile_seconds(cache_dir: str) -> float:
    """Seconds of the first native forward+backward in a fresh process using ``cache_dir``."""
    code = (
        f"import time, torch, sys; torch.set_num_threads({torch.get_num_threads()}); sys.path.insert(0, 'benchmarks');"
        "from rasterizer import make_scene, train_step;"
        "s = make_scene(50, 16, 16); t0 = time.perf_counter(); train_step(s, 'native');"
        "print(time.perf_counter() - t0)"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--min-seconds", type=float, default=1.5)
    ap.add_argument("--sizes", default="2000,10000,30000", help="comma-separated Gaussian counts")
    ap.add_argument("--threads", type=int, default=0, help="torch (and native) threads; 0: torch's default")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(sizes="300", repeats=1, min_seconds=0.0)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.smoke:
        print("numba first call: not timed (--smoke)")
    else:
        with tempfile.TemporaryDirectory() as cache:
            cold, warm = compile_seconds(cache), compile_seconds(cache)
        print(
            f"numba first call: {cold:.1f} s with an empty cache, {warm:.2f} s from the cache "
            f"(torch threads {torch.get_num_threads()})"
        )
    print(
        f"{'gaussians':>9} {'size':>7} {'native':>8} {'native raster':>14} {'reference':>10} {'speedup':>8}"
        "   (iterations/s; speedup = native / reference)"
    )
    speedups = {}
    for n in (int(s) for s in args.sizes.split(",")):
        for height, width in SIZES:
            scene = make_scene(n, height, width)
            rates = iterations_per_s(scene, tuple(VARIANTS), args.repeats, args.min_seconds)
            nat, mixed, ref = rates["native"], rates["native raster"], rates["reference"]
            speedups[(n, height, width)] = nat / ref
            row = f"{n:>9} {width:>3}x{height:<3} {nat:>8.1f} {mixed:>14.1f} {ref:>10.2f} {nat / ref:>7.1f}x"
            print(row, flush=True)
    key = (10000, 96, 128)
    print(f"speedup_10k_128x96: {speedups[key]:.1f}" if key in speedups else "speedup_10k_128x96: n/a")


if __name__ == "__main__":
    main()

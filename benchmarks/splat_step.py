"""Cost of a full 3DGS training step against the native rasterizer's forward+backward alone.

    python benchmarks/splat_step.py [--threads 1 --repeats 5 --min-seconds 2 --sizes 4000,10000,30000]

For each Gaussian count N it builds a :class:`SplatTrainer` on the built-in ``tabletop`` scene (a
training scene: no speed choice looks at an evaluation scene; 9 views rendered at 128x96, 6 of them
for training; objective 0.8 L1 + 0.2 (1 - SSIM), SH degree 3 active, density control off
(densify_until: 0) so that N stays fixed), initialised with N random points, runs a few warm-up steps (Adam
state, numba compile), then times two variants on the same Gaussians:

    raster  project_gaussians_native + rasterize(backend="native") + L1 to the target, backward
            (the "native" variant of benchmarks/rasterizer.py): the floor a step is measured against
    step    SplatTrainer.step: SH colour, projection, rasterization, L1 + SSIM loss, backward,
            densification statistics, Adam, the training PSNR

The raster variant uses the trainer's current Gaussians as leaves (means, activated scales,
quaternions, opacities, colours from SH of view 0, background), so both composite the same
footprints. The process keeps freed memory for reuse, as a workflow job does
(:func:`spc3d.runtime.keep_freed_memory`). The variants take turns in runs of 4 consecutive
steps (the first step of each run is not timed), so that both see the same load from other jobs. It prints the median
iterations/s of each and the ratio step / raster (time per step over time per raster pass); the
last line, ``step_over_raster_10k: <ratio>``, is machine-readable.
``--smoke``: 300 Gaussians, one run (seconds; its rates mean nothing).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import torch

from spc3d.cameras import split_views
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct.gaussians import GaussianConfig
from spc3d.reconstruct.objectives import RGBObjective
from spc3d.reconstruct.splat import eval_sh, project_gaussians_native, rasterize
from spc3d.reconstruct.splatting import SplatTrainer
from spc3d.reconstruct.views import Views
from spc3d.runtime import keep_freed_memory

HEIGHT, WIDTH = 96, 128
SHRINK = 0.25  # initial scales x this: 3-sigma radii of ~2-10 px, as benchmarks/rasterizer.py's scene


def make_views() -> Views:
    scene = render_scene("tabletop", HEIGHT, WIDTH, views=9, supersample=1)
    train, _ = split_views(len(scene.names))
    return Views(torch.tensor(scene.images[train]), scene.cameras.subset(train), [scene.names[i] for i in train])


def make_trainer(views: Views, n: int, warmup: int = 5) -> SplatTrainer:
    """A trainer on ``views`` with ``n`` Gaussians that stay ``n`` (no density control), SH degree
    3 active, after ``warmup`` steps."""
    big = 10**9
    cfg = GaussianConfig(iterations=big, init_points=n, densify_until=0, opacity_reset_every=big)
    trainer = SplatTrainer(views, RGBObjective("l1", cfg.ssim_weight), cfg, seed=0)
    m, g = trainer.model, torch.Generator().manual_seed(0)
    with torch.no_grad():  # footprints and opacities of a trained model, not of the coarse start
        m.log_scales.add_(math.log(SHRINK) + 0.3 * torch.randn(m.log_scales.shape, generator=g))
        m.opacity_logits.copy_(1.5 * torch.randn(m.opacity_logits.shape, generator=g))
        m.sh_rest.copy_(0.05 * torch.randn(m.sh_rest.shape, generator=g))
    m.active_degree = cfg.sh_degree
    for it in range(1, warmup + 1):
        trainer.step(it)
    return trainer


def raster_leaves(trainer: SplatTrainer) -> dict:
    """The trainer's Gaussians as detached leaves requiring grad (colours as seen from view 0)."""
    m, cams = trainer.model, trainer.views.cameras
    with torch.no_grad():
        centre = torch.as_tensor(cams.centers[0], dtype=torch.float32)
        sh = torch.cat([m.sh_dc, m.sh_rest], 1)
        leaves = {
            "means": m.means.detach().clone(),
            "scales": m.scales.detach().clone(),
            "quats": m.quats.detach().clone(),
            "opacities": m.opacities.detach().clone(),
            "colors": eval_sh(m.active_degree, sh, m.means - centre),
            "background": trainer.background.clone(),
        }
    return {k: t.requires_grad_() for k, t in leaves.items()}


def raster_step(trainer: SplatTrainer, leaves: dict, i: int) -> None:
    """project_gaussians_native + native rasterizer + L1 loss of view ``i``, forward+backward."""
    cams = trainer.views.cameras
    for t in leaves.values():
        t.grad = None
    fx, fy, cx, cy = map(float, cams.intrinsics[i])
    w2c = torch.as_tensor(cams.w2c[i], dtype=torch.float32)
    p = leaves
    proj = project_gaussians_native(p["means"], p["scales"], p["quats"], w2c, fx, fy, cx, cy, cams.height, cams.width)
    image, _ = rasterize(
        proj.means2d,
        proj.conics,
        p["opacities"],
        p["colors"],
        proj.depths,
        proj.radii,
        cams.height,
        cams.width,
        p["background"],
        backend="native",
    )
    (image - trainer.views.targets[i]).abs().mean().backward()


def iterations_per_s(trainer: SplatTrainer, repeats: int, min_seconds: float, run: int = 4) -> dict:
    """Median it/s of ``raster`` and ``step`` over at least ``repeats`` runs of ``run`` timed
    steps each (and ``min_seconds`` in all), taking turns run by run."""
    leaves = raster_leaves(trainer)
    it, view = 100, 0  # step numbers: past the warm-up
    n_views = len(trainer.views.cameras)

    def raster() -> None:
        nonlocal view
        view = (view + 1) % n_views
        raster_step(trainer, leaves, view)

    def step() -> None:
        nonlocal it
        it += 1
        trainer.step(it)

    variants = {"raster": raster, "step": step}
    times = {k: [] for k in variants}
    start = time.perf_counter()
    while min(len(t) for t in times.values()) < repeats * run or time.perf_counter() - start < min_seconds:
        for name, fn in variants.items():
            fn()
            for _ in range(run):
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
    return {k: 1.0 / statistics.median(t) for k, t in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--min-seconds", type=float, default=2.0)
    ap.add_argument("--sizes", default="4000,10000,30000", help="comma-separated Gaussian counts")
    ap.add_argument("--threads", type=int, default=1, help="torch (and native) threads; 0: torch's default")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(sizes="300", repeats=1, min_seconds=0.0)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    keep_freed_memory()  # as every workflow job does at its start (spc3d.jobs): no page faults per step
    views = make_views()
    print(f"{HEIGHT}x{WIDTH} training views, torch threads {torch.get_num_threads()}")
    print(f"{'gaussians':>9} {'raster':>8} {'step':>8} {'step/raster':>12}   (iterations/s)")
    ratios = {}
    for n in (int(s) for s in args.sizes.split(",")):
        trainer = make_trainer(views, n)
        rates = iterations_per_s(trainer, args.repeats, args.min_seconds)
        ratios[n] = rates["raster"] / rates["step"]
        print(f"{n:>9} {rates['raster']:>8.1f} {rates['step']:>8.1f} {ratios[n]:>12.2f}", flush=True)
    print(f"step_over_raster_10k: {ratios[10000]:.2f}" if 10000 in ratios else "step_over_raster_10k: n/a")


if __name__ == "__main__":
    main()

"""Held-out quality and wall time of the grid NeRF trained on ground-truth RGB (gt+nerf-grid).

Builds each training scene as the workflow does (built-in layout, 128x96, 24 views, 3x
supersampling; cached under ``--cache``), trains ``gt+nerf-grid`` through
``spc3d.reconstruct.RECONSTRUCTORS`` with config.yaml's ``stage2.nerf-grid`` block plus ``--set``
overrides, single-threaded as the workflow's jobs are, and prints per scene the held-out PSNR /
SSIM (every 8th view), the training and rendering seconds, the iterations and the grid capacity,
then the mean over the scenes. A fixed matmul timing before and after each run (``ref_ms``) shows
how loaded the machine was. Only the training scenes are allowed here: tuning never looks at the
evaluation scenes. The scene cache is keyed by name and width only: delete it after a layout change.

    python benchmarks/nerf_grid_quality.py                                   # config.yaml's settings
    python benchmarks/nerf_grid_quality.py --set n_samples=48 --set batch_rays=2048 --seeds 0 1
    python benchmarks/nerf_grid_quality.py --model nerf-mlp --set n_iters=300  # the MLP NeRF instead
``--smoke``: gallery at 32 px wide, 3 iterations of 64 rays on a 12-voxel grid (seconds).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from spc3d import llff
from spc3d.cameras import split_views
from spc3d.evaluation import metrics
from spc3d.inputs.build import named_spec, prepare_scene
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.sources import load_source

REPO = Path(__file__).resolve().parents[1]
TRAINING_SCENES = ("tabletop", "orchard", "gallery")


def build_scene(name: str, width: int, cache: Path) -> Path:
    """The scene folder of built-in layout ``name`` (rendered once into ``cache``)."""
    if name not in TRAINING_SCENES:
        raise SystemExit(f"--scenes {name}: only the training scenes {TRAINING_SCENES} may be used for tuning")
    scene_dir = cache / f"{name}_w{width}"
    if not scene_dir.is_dir():  # prepare_scene writes atomically
        prepare_scene(named_spec(name, width, REPO), scene_dir)
    return scene_dir


def machine_ref_ms(n: int = 384, repeats: int = 20) -> float:
    """Median milliseconds of one n x n float32 matmul (a load indicator for the shared cores)."""
    a = torch.randn(n, n, generator=torch.Generator().manual_seed(0))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        a @ a
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def warm_up_kernels(model: str) -> None:
    """Compile (or load from numba's cache) the grid's kernels on a tiny grid, so that the first
    training step's time does not include it (the workflow pays it once per code change)."""
    if model != "nerf-grid":
        return
    from spc3d.reconstruct.nerf_grid import GridConfig, GridNeRF

    tiny = GridNeRF(GridConfig(res_schedule=((0, 4),), n_samples=8))
    rays = torch.tensor([[0.0, 0.0, -1.0]]), torch.tensor([[0.0, 0.0, 2.0]])
    tiny(*rays, train=True)["rgb"].sum().backward()
    if hasattr(tiny, "add_tv_grad"):  # absent before the numba kernels: the old code can be timed too
        tiny.add_tv_grad()


def held_out(trainer, scene) -> tuple[float, float, float]:
    """Mean held-out PSNR, SSIM and the seconds spent rendering the held-out views."""
    _, test = split_views(len(scene.names))
    t0 = time.perf_counter()
    renders = [trainer.render(scene.cameras, int(i)).numpy() for i in test]
    seconds = time.perf_counter() - t0
    psnr = float(np.mean([metrics.psnr(r, scene.images[i]) for r, i in zip(renders, test)]))
    ssim = float(np.mean([metrics.ssim(r, scene.images[i]) for r, i in zip(renders, test)]))
    return psnr, ssim, seconds


def train_one(model: str, scene_dir: Path, settings: dict, seed: int, every: int = 0) -> dict:
    """Train ``gt+model`` on one scene; returns the row's numbers (``every``: also print the
    held-out PSNR every that many iterations, not counted in the training time)."""
    ref0 = machine_ref_ms()
    t_setup = time.perf_counter()
    warm_up_kernels(model)
    src = load_source("gt", scene_dir)
    trainer, iterations, _ = RECONSTRUCTORS[model](src.views, src.objective, settings, seed)
    scene = llff.read_scene(scene_dir)
    setup = time.perf_counter() - t_setup
    train_s = cpu_s = 0.0
    for it in range(1, iterations + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        stats = trainer.step(it)
        train_s, cpu_s = train_s + time.perf_counter() - t0, cpu_s + time.process_time() - c0
        if every and it % every == 0 and it < iterations:
            print(f"  it {it:5d} {train_s:6.1f}s held-out {held_out(trainer, scene)[0]:6.2f} {trainer.capacity()}")
    psnr, ssim, render_s = held_out(trainer, scene)
    cap = trainer.capacity()
    return {
        "psnr": psnr,
        "ssim": ssim,
        "train_psnr": stats["psnr"],
        "iters": iterations,
        "setup_s": setup,
        "train_s": train_s,
        "cpu_s": cpu_s,
        "render_s": render_s,
        "ref_ms": 0.5 * (ref0 + machine_ref_ms()),
        "cap": cap,
    }


def parse_sets(pairs: list[str]) -> dict:
    """``key=value`` pairs (values parsed as YAML: 64, 1e-3, [[0, 32], [70, 64]], true)."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"--set {pair!r}: expected key=value")
        v = yaml.safe_load(value)
        if isinstance(v, str):  # YAML 1.1 reads 1e-3 as a string
            try:
                v = float(v)
            except ValueError:
                pass
        out[key.strip()] = v
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(TRAINING_SCENES), choices=TRAINING_SCENES)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--model", default="nerf-grid", choices=["nerf-grid", "nerf-mlp"])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override of the config block")
    ap.add_argument("--config", default=str(REPO / "config.yaml"), help="base settings: its stage2.<model> block")
    ap.add_argument("--no-config", action="store_true", help="start from the dataclass defaults instead")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--cache", default="/tmp/spc3d_nerf_grid_scenes", help="folder the scenes are built into")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--label", default="", help="name of this variant in the output")
    ap.add_argument("--every", type=int, default=0, help="also print the held-out PSNR every N iterations")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(
            scenes=["gallery"], width=32, set=[*args.set, "n_iters=3", "batch_rays=64", "res_schedule=[[0, 12]]"]
        )
    torch.set_num_threads(args.threads)
    base = {} if args.no_config else dict(yaml.safe_load(Path(args.config).read_text())["stage2"].get(args.model) or {})
    settings = {**base, **parse_sets(args.set)}
    print(f"variant {args.label or '-'}: {args.model} {settings}  ({args.threads} thread(s), width {args.width})")
    print(
        f"{'scene':<9} {'seed':>4} {'PSNR':>6} {'SSIM':>6} {'trainPSNR':>9} {'iters':>5} {'setup_s':>7} "
        f"{'train_s':>7} {'cpu_s':>6} {'render_s':>8} {'ref_ms':>6}  capacity"
    )
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        for name in args.scenes:
            r = train_one(args.model, build_scene(name, args.width, cache), settings, seed, args.every)
            rows.append(r)
            print(
                f"{name:<9} {seed:>4} {r['psnr']:6.2f} {r['ssim']:6.3f} {r['train_psnr']:9.2f} {r['iters']:5d} "
                f"{r['setup_s']:7.1f} {r['train_s']:7.1f} {r['cpu_s']:6.1f} {r['render_s']:8.1f} {r['ref_ms']:6.2f}  "
                f"{r['cap']}",
                flush=True,
            )
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("psnr", "ssim", "train_s", "cpu_s", "render_s", "ref_ms")}
    print(
        f"{'mean':<9} {'':>4} {mean['psnr']:6.2f} {mean['ssim']:6.3f} {'':>9} {'':>5} {'':>7} "
        f"{mean['train_s']:7.1f} {mean['cpu_s']:6.1f} {mean['render_s']:8.1f} {mean['ref_ms']:6.2f}"
    )


if __name__ == "__main__":
    main()

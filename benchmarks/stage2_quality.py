"""Held-out quality vs training time of stage-2 combinations on a built-in scene (or real LLFF).

Builds the scene and its SPC frames like the workflow does (default: courtyard, 128x96, 24 views,
K = 16, calibrated exposure), trains each combination with the config's settings and prints the
mean held-out PSNR (every 8th view) at fixed wall-clock marks, then the final PSNR / SSIM and the
capacity. Single-threaded by default, as the workflow runs each job (`threads: 1`).

    python benchmarks/stage2_quality.py                                   # gt+3dgs gt+nerf-grid ...
    python benchmarks/stage2_quality.py --combos gt+3dgs --scene fern --width 504 --marks 60 300
    python benchmarks/stage2_quality.py --combos gt+3dgs --scene flower --width 126 \
        --config workflow/presets/findings-llff.yaml --set 3dgs.iterations=6000 --steps 600 1500 3000
``--smoke``: 32 px wide, gt+3dgs and bernoulli+nerf-grid for 3 iterations (seconds).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from spc3d import llff
from spc3d.cameras import split_views
from spc3d.evaluation import metrics
from spc3d.inputs.build import named_spec, prepare_scene, simulate_scene
from spc3d.inputs.exposure import calibrate_display, write_display
from spc3d.physics.spc import SPCParams
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.sources import load_source

REPO = Path(__file__).resolve().parents[1]
LLFF_ROOT = REPO.parent / "shared" / "data" / "llff"


def build_scene(name: str, width: int, work: Path) -> tuple[Path, Path]:
    scene_dir, spc_dir = work / "scenes" / name, work / "spc" / name
    spec = named_spec(name, width, LLFF_ROOT)
    if spec is None:
        raise SystemExit(f"--scene {name}: neither a built-in layout nor a folder in {LLFF_ROOT}")
    prepare_scene(spec, scene_dir)
    simulate_scene(scene_dir, spc_dir, SPCParams(frames=16), seed=0)
    # The mle / bernoulli sources' display: its level fitted on this scene itself (a benchmark, not a row).
    calibrate_display([scene_dir], [spc_dir], 1, work / "display-k1.json")
    write_display(spc_dir, work / "display-k1.json", 1, work / "mle" / name / "k1")
    return scene_dir, spc_dir


def held_out_psnr(trainer, scene) -> tuple[float, float]:
    _, test = split_views(len(scene.names))
    renders = [trainer.render(scene.cameras, int(i)).numpy() for i in test]
    return (
        float(np.mean([metrics.psnr(r, scene.images[i]) for r, i in zip(renders, test)])),
        float(np.mean([metrics.ssim(r, scene.images[i]) for r, i in zip(renders, test)])),
    )


def train_combo(
    combo: str, scene_dir: Path, spc_dir: Path, settings: dict, marks: list[float], steps: list[int] = ()
) -> str:
    """One fit: held-out PSNR at each wall-clock mark (seconds) or, with ``steps``, at each of those iterations."""
    source, model = combo.split("+")
    display = scene_dir.parents[1] / "mle" / scene_dir.name / "k1"
    src = load_source(source, scene_dir, spc_dir, frames=1, display_dir=display)
    trainer, iterations, _ = RECONSTRUCTORS[model](src.views, src.objective, settings.get(model, {}), 0)
    scene = llff.read_scene(scene_dir)
    at, pending, clock, it = [], list(steps or marks), 0.0, 0
    while it < iterations:
        t0 = time.perf_counter()
        it += 1
        trainer.step(it)
        clock += time.perf_counter() - t0
        if pending and (it if steps else clock) >= pending[0]:
            at.append(f"{held_out_psnr(trainer, scene)[0]:6.2f}@{it}")
            pending.pop(0)
    psnr, ssim = held_out_psnr(trainer, scene)
    at += ["     -"] * len(pending)
    return (
        f"{combo:<18} {' '.join(f'{a:>11}' for a in at)} {psnr:8.2f} {ssim:7.4f} {it:6d} {clock:8.1f}  "
        f"{trainer.capacity()}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="courtyard")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument(
        "--combos",
        nargs="+",
        default=["gt+3dgs", "gt+nerf-grid", "none+3dgs", "none+nerf-grid", "mle+3dgs", "bernoulli+3dgs"],
    )
    ap.add_argument("--marks", nargs="+", type=float, default=[30, 60, 120], help="seconds of training")
    ap.add_argument("--steps", nargs="+", type=int, default=[], help="iterations to score at instead of --marks")
    ap.add_argument("--set", nargs="*", default=[], metavar="MODEL.KEY=VALUE", help="override a stage2 setting")
    ap.add_argument("--config", default=str(REPO / "config.yaml"), help="settings from its stage2 section")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(
            width=32,
            combos=["gt+3dgs", "bernoulli+nerf-grid"],
            steps=[2],
            set=[
                *args.set,
                "3dgs.iterations=3",
                "nerf-grid.n_iters=3",
                "nerf-grid.batch_rays=64",
                "nerf-grid.res_schedule=[[0, 12]]",
            ],
        )
    torch.set_num_threads(args.threads)
    settings = yaml.safe_load(Path(args.config).read_text())["stage2"]
    settings["nerf-mlp"] = settings.get("nerf-mlp", {})
    for item in args.set:
        key, _, value = item.partition("=")
        model, _, field = key.partition(".")
        settings.setdefault(model, {})[field] = yaml.safe_load(value)
    heads = [f"{m:>10d}it" for m in args.steps] if args.steps else [f"{m:>10.0f}s" for m in args.marks]
    print(f"scene {args.scene} width {args.width}, {args.threads} thread(s); PSNR (dB) @ iteration at each mark")
    print(f"{'combination':<18} {' '.join(heads)} {'PSNR':>8} {'SSIM':>7} {'iters':>6} {'train_s':>8}  capacity")
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir, spc_dir = build_scene(args.scene, args.width, Path(tmp))
        for combo in args.combos:
            print(train_combo(combo, scene_dir, spc_dir, settings, args.marks, args.steps), flush=True)


if __name__ == "__main__":
    main()

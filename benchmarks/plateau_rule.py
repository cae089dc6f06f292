"""Choosing the stage-2 plateau rule on the training scenes: where it would stop and what that costs.

    python benchmarks/plateau_rule.py [--scenes tabletop orchard] [--models 3dgs nerf-grid]
                                      [--targets gt blur noisy] [--seeds 0] [--out plateau.json]

Each (scene, target, model, seed) is trained to config.yaml's full budget once, single-threaded,
with the held-out PSNR (against the ground truth; training scenes only) and the training seconds
logged at the end of every plateau window. Every candidate rule (``--gains`` x ``--patiences``) is
then replayed on that run's own window curve with :class:`spc3d.training.Plateau` itself, so each
rule's stop step, the training time it saves and its held-out PSNR change (at the stop vs at the
budget) are paired on the same run. Targets stand for the kinds of images stage 2 fits:

    gt      the ground-truth views (the oracle row)
    blur    the ground truth blurred with a Gaussian of sigma 2 px (a translator's soft output)
    noisy   the ground truth plus N(0, 0.1) noise per pixel (a noisy single-frame estimate)

The evaluation scenes are refused: the rule is chosen here and then frozen.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from nerf_grid_quality import REPO, build_scene, held_out, warm_up_kernels

from spc3d import llff
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.sources import load_source
from spc3d.training import Plateau
from spc3d.translate.prior import PhysicsPrior

WINDOW_FIELD = "plateau_window"


def target_images(kind: str, images: torch.Tensor, seed: int) -> torch.Tensor:
    """The training targets of one ``--targets`` kind from ground-truth views (N, H, W, 3)."""
    if kind == "gt":
        return images
    if kind == "blur":
        x = torch.as_tensor(images).permute(0, 3, 1, 2)
        return PhysicsPrior(2.0).blur(x).permute(0, 2, 3, 1).contiguous()
    if kind == "noisy":
        g = torch.Generator().manual_seed(seed)
        return (images + 0.1 * torch.randn(images.shape, generator=g)).clamp(0, 1)
    raise SystemExit(f"--targets {kind}: choose from gt, blur, noisy")


def settings_of(model: str) -> dict:
    """config.yaml's stage2 block of ``model`` (the default budget the rule must fit)."""
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    return dict(cfg["stage2"].get(model, {}))


def observe(model: str, scene_dir: Path, kind: str, seed: int) -> dict:
    """Train to the budget; per window: step, plateau value, held-out PSNR, training seconds."""
    warm_up_kernels(model)
    src = load_source("gt", scene_dir)
    src.views.targets = target_images(kind, src.views.targets, seed)
    trainer, iterations, cfg = RECONSTRUCTORS[model](src.views, src.objective, settings_of(model), seed)
    trainer.plateau.patience = 0  # observe only
    scene = llff.read_scene(scene_dir)
    window, train_s, rows = getattr(cfg, WINDOW_FIELD), 0.0, []
    for it in range(1, iterations + 1):
        t0 = time.process_time()
        trainer.step(it)
        train_s += time.process_time() - t0
        if it % window == 0:
            rows.append(
                {"step": it, "value": trainer.plateau.curve[-1][1], "psnr": held_out(trainer, scene)[0], "s": train_s}
            )
    return {
        "model": model,
        "target": kind,
        "seed": seed,
        "start": trainer.plateau.start,
        "window": window,
        "rows": rows,
    }


def replay(run: dict, gain: float, patience: int) -> dict:
    """Where the rule (gain, patience) stops ``run``, the seconds it saves and its PSNR change."""
    rule = Plateau(run["window"], patience, gain, run["start"])
    stop = run["rows"][-1]
    for row in run["rows"]:
        rule.update(row["step"], row["value"])  # one value per window: the window's own mean
        if rule.should_stop():
            stop = row
            break
    last = run["rows"][-1]
    return {"step": stop["step"], "saved": 1 - stop["s"] / last["s"], "dpsnr": stop["psnr"] - last["psnr"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["tabletop"])
    ap.add_argument("--models", nargs="+", default=["3dgs", "nerf-grid"])
    ap.add_argument("--targets", nargs="+", default=["gt", "blur", "noisy"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--gains", nargs="+", type=float, default=[0.005, 0.01, 0.02, 0.03])
    ap.add_argument("--patiences", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_scenes")
    ap.add_argument("--out", type=Path, help="also write every run's window curve here (JSON)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    runs = []
    for scene in args.scenes:
        scene_dir = build_scene(scene, 128, args.cache)
        for model in args.models:
            for kind in args.targets:
                for seed in args.seeds:
                    run = observe(model, scene_dir, kind, seed) | {"scene": scene}
                    last = run["rows"][-1]
                    print(
                        f"{scene} {model} {kind} seed {seed}: {last['step']} it {last['s']:.0f} s {last['psnr']:.2f} dB"
                    )
                    runs.append(run)
    if args.out:
        args.out.write_text(json.dumps(runs, indent=1))
    print("\nmodel      gain   patience  runs  mean stop  time saved  dPSNR mean  dPSNR worst")
    for model in args.models:
        for gain in args.gains:
            for patience in args.patiences:
                res = [replay(r, gain, patience) for r in runs if r["model"] == model]
                saved, d = [x["saved"] for x in res], [x["dpsnr"] for x in res]
                steps = np.mean([x["step"] for x in res])
                print(
                    f"{model:10s} {gain:5.3f}  {patience:8d}  {len(res):4d}  {steps:9.0f}  {np.mean(saved):9.0%}"
                    f"  {np.mean(d):+10.2f}  {min(d):+11.2f}"
                )


if __name__ == "__main__":
    main()

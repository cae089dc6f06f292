"""Choosing the stage-2 plateau rule on the training scenes: where it would stop and what that costs.

    python benchmarks/plateau_rule.py [--scenes gallery] [--models 3dgs nerf-grid] [--seeds 0]
                                      [--targets gt prior blur noisy] [--results results] [--out plateau.json]

Each (scene, target, model, seed) is trained to config.yaml's full budget once, single-threaded,
with the held-out PSNR (against the ground truth; training scenes only) and the training seconds
logged at the end of every plateau window. Every candidate rule (``--gains`` x ``--patiences``) is
then replayed on that run's own window curve with :class:`spc3d.training.Plateau` itself, so each
rule's stop step, the training time it saves and its held-out PSNR change (at the stop vs at the
budget) are paired on the same run. Targets stand for the kinds of images stage 2 fits:

    gt      the ground-truth views (the oracle row)
    bernoulli  frame 0 through the SPAD likelihood (``--results``: its SPC frames and display
            calibration), the objective whose floor the rule subtracts
    prior   the physics prior of frame 0 (a finished run's ``--results``: its SPC frames and augmented
            pairs of the training scenes, gain fitted on those pairs): what every residual translator
            starts from and, through 3D, scores within 0.1 dB of (docs/results.md)
    blur    the ground truth blurred with a Gaussian of sigma 2 px (a translator's soft output)
    noisy   the ground truth plus N(0, 0.1) noise per pixel (a noisy single-frame estimate)

The evaluation scenes are refused: the rule is chosen here and then frozen.
``--smoke``: 3DGS on gt targets, 4 iterations in windows of 2, one rule (seconds).
"""

from __future__ import annotations

import argparse
import itertools
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


def prior_targets(results: Path, scene: str, names: list[str]) -> torch.Tensor:
    """The physics prior (sigma 2 px, the translators' default) of frame 0 of views ``names``."""
    from spc3d.reconstruct.sources import bit_fractions
    from spc3d.translate.data import load_pairs

    train = [p.name for p in (results / "augment").iterdir() if p.is_dir()]
    prior = PhysicsPrior(2.0)
    prior.fit(zip(*load_pairs([results / "augment" / s for s in train], 1)))
    binary = torch.as_tensor(bit_fractions(results / "spc" / scene, names, 1)).permute(0, 3, 1, 2)
    with torch.no_grad():
        return prior(binary).clamp(0.0, 1.0).permute(0, 2, 3, 1).contiguous()


def bernoulli_source(scene_dir: Path, results: Path | None, scene: str):
    """The bernoulli source of frame 0, its display metered as the workflow does (training scenes'
    calibration of the run in ``results``)."""
    from spc3d.inputs.exposure import write_display

    if results is None:
        raise SystemExit("--targets bernoulli needs --results (a finished run's results folder)")
    display = scene_dir.parent / f"{scene}_display_k1"
    if not display.is_dir():
        write_display(results / "spc" / scene, results / "calibration" / "display-k1.json", 1, display)
    return load_source("bernoulli", scene_dir, results / "spc" / scene, None, 1, display)


def target_images(kind: str, src, seed: int, results: Path | None, scene: str) -> torch.Tensor:
    """The training targets of one ``--targets`` kind for the source ``src`` of ground-truth views."""
    images = src.views.targets
    if kind == "gt":
        return images
    if kind == "prior":
        if results is None:
            raise SystemExit("--targets prior needs --results (a finished run's results folder)")
        return prior_targets(results, scene, src.views.names)
    if kind == "blur":
        x = torch.as_tensor(images).permute(0, 3, 1, 2)
        return PhysicsPrior(2.0).blur(x).permute(0, 2, 3, 1).contiguous()
    if kind == "noisy":
        g = torch.Generator().manual_seed(seed)
        return (images + 0.1 * torch.randn(images.shape, generator=g)).clamp(0, 1)
    raise SystemExit(f"--targets {kind}: choose from gt, blur, noisy")


def settings_of(model: str, overrides: dict | None = None) -> dict:
    """config.yaml's stage2 block of ``model`` (the default budget the rule must fit), with
    ``overrides`` (``--set``: e.g. plateau_views=2, the rule judged on training views held out)."""
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    return dict(cfg["stage2"].get(model, {})) | (overrides or {})


def parse_sets(items: list[str]) -> dict:
    """``KEY=VALUE`` pairs, values read as YAML (numbers, lists)."""
    bad = [x for x in items if "=" not in x]
    if bad:
        raise SystemExit(f"--set {bad[0]!r}: write KEY=VALUE, e.g. plateau_views=2")
    return {k: yaml.safe_load(v) for k, v in (x.split("=", 1) for x in items)}


def observe(
    model: str, scene_dir: Path, kind: str, seed: int, results: Path | None = None, overrides: dict | None = None
) -> dict:
    """Train to the budget; per window: step, plateau value, held-out PSNR, training seconds."""
    warm_up_kernels(model)
    scene_name = scene_dir.name.rsplit("_w", 1)[0]
    if kind == "bernoulli":
        src = bernoulli_source(scene_dir, results, scene_name)
    else:
        src = load_source("gt", scene_dir)
        src.views.targets = target_images(kind, src, seed, results, scene_name)
    trainer, iterations, cfg = RECONSTRUCTORS[model](src.views, src.objective, settings_of(model, overrides), seed)
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


def replay(run: dict, gain: float, patience: int, tol: float) -> dict:
    """Where the rule (gain, patience, tol) stops ``run``, the seconds it saves and its PSNR change."""
    rule = Plateau(run["window"], patience, gain, run["start"], tol)
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
    ap.add_argument("--scenes", nargs="+", default=["gallery"])
    ap.add_argument("--results", type=Path, help="a finished run's results/ (for --targets prior)")
    ap.add_argument("--tols", nargs="+", type=float, default=[0.0, 1e-5, 1e-4])
    ap.add_argument("--models", nargs="+", default=["3dgs", "nerf-grid"])
    ap.add_argument("--targets", nargs="+", default=["gt", "blur", "noisy"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--gains", nargs="+", type=float, default=[0.005, 0.01, 0.02, 0.03])
    ap.add_argument("--patiences", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_scenes")
    ap.add_argument("--out", type=Path, help="also write every run's window curve here (JSON)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="override the models' settings")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        sets = [*args.set, "iterations=4", "plateau_window=2"]  # --set applies to every model: 3DGS alone
        vars(args).update(models=["3dgs"], targets=["gt"], gains=[0.01], tols=[0.0], patiences=[1], set=sets)
    torch.set_num_threads(1)
    sets, runs = parse_sets(args.set), []
    for scene in args.scenes:
        scene_dir = build_scene(scene, 128, args.cache)
        for model in args.models:
            for kind in args.targets:
                for seed in args.seeds:
                    run = observe(model, scene_dir, kind, seed, args.results, sets) | {"scene": scene}
                    last = run["rows"][-1]
                    print(
                        f"{scene} {model} {kind} seed {seed}: {last['step']} it {last['s']:.0f} s {last['psnr']:.2f} dB"
                    )
                    runs.append(run)
    if args.out:
        args.out.write_text(json.dumps(runs, indent=1))
    print("\nmodel      gain    tol     patience  runs  stops (per run)       time saved  dPSNR mean  dPSNR worst")
    for model in args.models:
        for gain, tol, patience in itertools.product(args.gains, args.tols, args.patiences):
            res = [replay(r, gain, patience, tol) for r in runs if r["model"] == model]
            saved, d = [x["saved"] for x in res], [x["dpsnr"] for x in res]
            stops = " ".join(str(x["step"]) for x in res)
            print(
                f"{model:10s} {gain:5.3f}  {tol:7.0e}  {patience:8d}  {len(res):4d}  {stops:20s} {np.mean(saved):9.0%}"
                f"  {np.mean(d):+10.2f}  {min(d):+11.2f}"
            )


if __name__ == "__main__":
    main()

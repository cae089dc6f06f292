"""Choosing the joint rows' prior weight on the training scenes: held-out PSNR against the schedule.

    python benchmarks/joint_weight.py --results RUN/results [--scenes tabletop orchard gallery]
                                      [--model 3dgs] [--seeds 0] [--out joint.json]
                                      [--method restormer] [--configfile preset.yaml]

A joint row fits the SPAD likelihood of frame 0 plus ``w(t)`` times the model's two-stage image loss
towards a stage-1 output (spc3d.reconstruct.objectives.JointObjective). Here the stage-1 output is
the run's untrained ``prior`` model (the translators' start) applied to each training scene's
frames by the workflow's own translate_scene, and the likelihood's gain is the run's metered
display (results/calibration/display-k1.json), both written once under ``--cache``. The prior has
no network: a translator's output on its own training scenes would be in-sample (``--method``
allows one, marked so). A translator trained with ``stage1.validation.hold_out`` (e.g. by
benchmarks/scene_holdout_curves.py) never saw the scenes it held out: on those its output is out of
sample, as on an evaluation scene. Each schedule is fitted once per (scene, seed) at config.yaml's budget
(its stage2 block of the model, overlaid by ``--configfile``: e.g. a preset's larger budget),
single-threaded, and scored on the held-out views against the ground truth (training scenes only:
the evaluation scenes of the merged configuration, config.yaml overlaid by ``--configfile`` as
Snakemake merges it, are refused; with a leave-one-out preset every scene is one, so ``--fold SCENE``
names the fold explored: SCENE is refused, the others allowed, and the fold's models and display level
are read, ``models-without-SCENE``). This is an exploratory tool: the workflow makes the choice itself,
inside each fold (rule choose_joint_weight, ``stage2.joint.choose``). Two schedules are the rows the
joint one lies between:

    likelihood   w = 0: the bernoulli row (its objective exactly)
    prior only   the likelihood off: the prior + model two-stage row's objective, on the render's sRGB

``--results``: a finished default run's results folder (its training scenes, their SPC frames, the
trained ``prior`` model and the display calibration). Prints one row per schedule: PSNR per scene, mean, and mean
paired difference against the likelihood row and against the prior-only row, with CPU seconds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from nerf_grid_quality import REPO, held_out, warm_up_kernels
from plateau_rule import settings_of

from spc3d import llff
from spc3d.config import workflow_config
from spc3d.inputs.exposure import calibrate_display, write_display
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.sources import Source, load_source
from spc3d.translate.apply import translate_scene

# name -> stage2.joint settings; "likelihood" and "prior only" bracket the joint schedules.
SCHEDULES = {
    "likelihood": {"weight": 0.0, "weight_final": 0.0},
    "prior only": {"likelihood": False},
    "w 0.1": {"weight": 0.1, "weight_final": 0.1},
    "w 0.03": {"weight": 0.03, "weight_final": 0.03},
    "w 0.3": {"weight": 0.3, "weight_final": 0.3},
    "w 1": {"weight": 1.0, "weight_final": 1.0},
    "w 3": {"weight": 3.0, "weight_final": 3.0},
    "w 10": {"weight": 10.0, "weight_final": 10.0},
    "w 1 -> 0.1 by 0.5": {"weight": 1.0, "weight_final": 0.1, "decay_until": 0.5},
    "w 3 -> 0.3 by 0.5": {"weight": 3.0, "weight_final": 0.3, "decay_until": 0.5},
    "w 1 -> 0 by 0.8": {"weight": 1.0, "weight_final": 0.0, "decay_until": 0.8},
}


def refused(scenes: list[str], cfg: dict, fold: str | None) -> str | None:
    """Why ``scenes`` may not choose a schedule under ``cfg`` (None: they may): an evaluation scene
    of the configuration, or, exploring the fold of left-out scene ``fold``, that scene."""
    if fold:
        loo = cfg["scenes"].get("leave_one_out") and fold in cfg["scenes"]["train"] and fold in cfg["scenes"]["eval"]
        if not loo:
            return f"--fold {fold}: not a left-out scene of this configuration (scenes.leave_one_out, train and eval)"
        return f"--scenes {fold}: the fold's left-out scene" if fold in scenes else None
    bad = sorted(set(scenes) & set(cfg["scenes"]["eval"]))
    if bad:
        hint = (
            " (a leave-one-out preset: name the fold explored with --fold SCENE)"
            if cfg["scenes"].get("leave_one_out")
            else ""
        )
        return f"--scenes {bad}: evaluation scenes; the schedule is chosen on training scenes only{hint}"
    return None


def joint_source(
    results: Path, scene: str, method: str, schedule: dict, cache: Path, calibration: Path, models: str = "models"
) -> Source:
    """The ``joint-<method>`` source of a training scene: frame 0, the display gain of
    ``calibration``, and ``method``'s translation of its views (written once under ``cache``)."""
    spc_dir, folder = results / "spc" / scene, cache / f"{results.resolve().parent.name}-{scene}"
    display, images = folder / "display-k1", folder / method
    if not display.is_dir():
        write_display(spc_dir, calibration, 1, display)
    if not images.is_dir():
        translate_scene(results / models / method, spc_dir, results / "scenes" / scene, images, frames=1)
    joint = f"joint-{method}"
    return load_source(joint, results / "scenes" / scene, spc_dir, images / "images", 1, display, schedule)


def sample_kind(results: Path, method: str, scene: str, models: str = "models") -> str:
    """Whether ``method``'s model saw ``scene`` in training ("in-sample") or held it out ("out of sample")."""
    if method == "prior":
        return "no network"
    record = json.loads((results / models / method / "train.json").read_text())
    validation = record.get("validation") or {}
    held = {v.split("/")[0] for v in validation.get("views", [])} if validation.get("hold_out") else set()
    return "out of sample" if scene in held else "in-sample"


def fit(model: str, scene_dir: Path, src: Source, seed: int, settings: dict) -> dict:
    """One joint fit at the budget ``settings``: held-out PSNR and CPU seconds."""
    trainer, iterations, _ = RECONSTRUCTORS[model](src.views, src.objective, settings, seed)
    t0 = time.process_time()
    for it in range(1, iterations + 1):
        trainer.step(it)
    cpu_s = time.process_time() - t0
    return {"psnr": held_out(trainer, llff.read_scene(scene_dir))[0], "cpu_s": cpu_s, "iterations": iterations}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, required=True, help="a finished default run's results/")
    ap.add_argument("--scenes", nargs="+", default=None, help="training scenes (default: config.yaml's scenes.train)")
    ap.add_argument("--model", default="3dgs", choices=sorted(RECONSTRUCTORS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--schedules", nargs="+", default=list(SCHEDULES), help=f"from {list(SCHEDULES)}")
    ap.add_argument("--method", default="prior", help="the stage-1 model of the run (not prior: in-sample)")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_joint")
    ap.add_argument("--out", type=Path, help="also write every fit (JSON)")
    ap.add_argument("--configfile", type=Path, help="a preset whose stage2 block of the model overlays config.yaml's")
    ap.add_argument("--fold", help="a leave-one-out preset's left-out scene: explore its fold (its models, display)")
    ap.add_argument(
        "--calibrate",
        nargs="+",
        metavar="SCENE",
        help="fit the display level on these scenes of the run (default: its results/calibration/display-k1.json)",
    )
    args = ap.parse_args()
    settings = settings_of(args.model)
    cfg = workflow_config(*([args.configfile] if args.configfile else []))  # as --configfile merges it
    settings |= cfg["stage2"].get(args.model) or {}
    fold = f"-without-{args.fold}" if args.fold else ""
    scenes = args.scenes or [s for s in cfg["scenes"]["train"] if s != args.fold]
    why = refused(scenes, cfg, args.fold)
    if why:
        raise SystemExit(why)
    unknown = [s for s in args.schedules if s not in SCHEDULES]
    if unknown:
        raise SystemExit(f"--schedules {unknown}: choose from {list(SCHEDULES)}")
    calibration = args.results / f"calibration{fold}" / "display-k1.json"
    if args.calibrate:
        calibration = args.cache / f"{args.results.resolve().parent.name}-display-k1-{'+'.join(args.calibrate)}.json"
        if not calibration.is_file():
            scene_dirs, spc_dirs = ([str(args.results / k / s) for s in args.calibrate] for k in ("scenes", "spc"))
            calibration.parent.mkdir(parents=True, exist_ok=True)
            calibrate_display(scene_dirs, spc_dirs, 1, calibration)
    torch.set_num_threads(1)
    warm_up_kernels(args.model)
    runs = []
    kinds = {scene: sample_kind(args.results, args.method, scene, f"models{fold}") for scene in scenes}
    for scene, kind in kinds.items():
        print(f"{scene}: {args.method} {kind}")
    for scene in scenes:
        for seed in args.seeds:
            for name in args.schedules:
                src = joint_source(
                    args.results, scene, args.method, SCHEDULES[name], args.cache, calibration, f"models{fold}"
                )
                run = fit(args.model, args.results / "scenes" / scene, src, seed, settings)
                where = {"scene": scene, "seed": seed, "schedule": name, "sample": kinds[scene]}
                runs.append(run | where | {"method": args.method})
                print(f"{scene} seed {seed} {name}: {run['psnr']:.2f} dB, {run['cpu_s']:.0f} CPU s", flush=True)
    if args.out:
        args.out.write_text(json.dumps(runs, indent=1))
    print(table(runs, args.model))


def table(runs: list[dict], model: str) -> str:
    """One row per schedule: PSNR per (scene, seed), mean, paired Δ vs the two bracketing rows."""
    units = sorted({(r["scene"], r["seed"]) for r in runs})
    by = {(r["schedule"], r["scene"], r["seed"]): r for r in runs}
    names = list(dict.fromkeys(r["schedule"] for r in runs))
    head = " ".join(f"{s}/{k:<6}" for s, k in units)
    what = f"joint-{runs[0]['method']}+{model}: held-out PSNR (dB) on the training scenes"
    lines = [f"{what}, n = {len(units)} (scene, seed) units, descriptive"]
    lines.append(f"{'schedule':20s} {head}   mean  Δ likelihood  Δ prior only  CPU s")
    for name in names:
        psnr = np.array([by[(name, *u)]["psnr"] if (name, *u) in by else np.nan for u in units])
        cells = " ".join(f"{v:>{len(s) + 7}.2f}" for v, (s, _) in zip(psnr, units))
        deltas = []
        for ref in ("likelihood", "prior only"):
            other = np.array([by[(ref, *u)]["psnr"] if (ref, *u) in by else np.nan for u in units])
            deltas.append(np.nanmean(psnr - other) if np.isfinite(other).any() else np.nan)
        cpu = np.mean([by[(name, *u)]["cpu_s"] for u in units if (name, *u) in by])
        lines.append(f"{name:20s} {cells} {np.nanmean(psnr):6.2f}  {deltas[0]:+11.2f}  {deltas[1]:+12.2f}  {cpu:5.0f}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()

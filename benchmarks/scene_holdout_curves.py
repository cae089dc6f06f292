"""Learning curves that measure generalisation: translators validated on training scenes they never saw.

    python benchmarks/scene_holdout_curves.py WORKDIR [--preset workflow/presets/findings-llff.yaml]
        [--methods pix2pix restormer] [--steps 2000] [--every 100] [--train-size 2] [--jobs 2]
        [--at 100 300 500 1000 1500 2000] [--report-only]

The validation the presets train with (held-out views of the training scenes) shares its content
with the training data: on the real scenes its curve kept rising while the gain on a scene left
out fell (docs/stage1.md). Here the curve is drawn one fold deeper, inside the training scenes
only. For every subset S of ``--train-size`` of the preset's training scenes, each method trains on
S alone with the workflow's own rule (``snakemake results/models/{method}`` in ``WORKDIR/{S}``;
``stage1.validation.hold_out``: the scenes outside S are kept out of the training and every view of
each is validated, per scene) for ``--steps`` steps at a constant learning rate, validated every
``--every`` steps from step 0 and never stopped early.

The curve of the fold that evaluates scene E is the mean, over the subsets S without E and the
scenes V outside S and E, of V's validation PSNR minus the untrained prior's on V: E is never
trained on nor validated on, so a budget read off it is a choice made on E's training scenes only.
Prints per fold and method the gain at step 0 and each of ``--at`` (the last validation at or
before it), the best gain and its step, and the mean over folds; writes
``WORKDIR/scene_holdout_curves.csv`` (per fold), ``..._runs.csv`` (per subset and validation
scene) and a figure ``WORKDIR/scene_holdout_curves.png``.
"""

from __future__ import annotations

import argparse
import itertools
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pandas as pd
import yaml
from snakemake.utils import update_config

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))
sys.path.insert(0, str(Path(__file__).parent))

from learning_curves import trained  # noqa: E402

from spc3d.jobs import training_scene_names  # noqa: E402
from spc3d.plotting import pyplot, save_png  # noqa: E402


def preset_scenes(preset: Path) -> list[str]:
    """The training scenes the preset lists (its folds are drawn from them)."""
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    update_config(config, yaml.safe_load(preset.read_text()))  # as --configfile merges it
    return training_scene_names(config)


def overrides(subset: tuple, scenes: list[str], args) -> dict:
    """A subset's config over the preset: trained on ``subset``, the other scenes validated whole."""
    rest = [s for s in scenes if s not in subset]
    train = {"iterations": args.steps, "decay_from": 1.0, "log_every": args.every}
    validation = {"every": args.every, "patience": 0, "hold_out": len(rest)}
    # a method's own blocks (the preset's restormer.train) would override the common ones
    stage1 = {"train": train, "validation": validation} | {
        m: {"train": dict(train), "validation": dict(validation)} for m in args.methods
    }
    # evaluated: a built-in scene no job here builds (the targets are the models alone)
    return {"scenes": {"train": [*subset, *rest], "eval": ["courtyard"], "leave_one_out": False}, "stage1": stage1}


def train(work: Path, config: dict, args) -> None:
    work.mkdir(parents=True, exist_ok=True)
    (work / "holdout.yaml").write_text(yaml.safe_dump(config))
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(work)]
    cmd += ["--cores", str(args.cores), "--configfile", str(args.preset), str(work / "holdout.yaml")]
    proc = subprocess.run([*cmd, "--", *(f"results/models/{m}" for m in args.methods)], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"{work.name}: snakemake failed (log in {work}/.snakemake/log):\n{proc.stderr[-3000:]}")


def runs(work: Path, subset: tuple, method: str) -> list[dict]:
    """One row per validation scene and validation: the gain over the prior's PSNR on that scene."""
    record, per_step = trained(work, method)
    curve, prior = record["validation"]["curve"], record.get("prior") or {}
    held = list(dict.fromkeys(v.split("/")[0] for v in record["validation"]["views"]))
    rows = []
    for scene in held:
        key = f"val_psnr:{scene}" if len(held) > 1 else "val_psnr"
        for point in curve:
            rows.append(
                {
                    "method": method,
                    "trained_on": "+".join(subset),
                    "validated_on": scene,
                    "step": point["iteration"],
                    "gain": point[key] - prior[key],
                    "prior_psnr": prior[key],
                    "cpu_s_per_step": per_step,
                }
            )
    return rows


def fold_curves(table: pd.DataFrame, scenes: list[str]) -> pd.DataFrame:
    """Per fold (the evaluation scene E) and method, the mean gain over the (subset, scene) pairs
    that never touch E, by step."""
    parts = []
    for scene in scenes:
        untouched = ~table["trained_on"].str.split("+").apply(lambda s, e=scene: e in s)
        mine = table[untouched & (table["validated_on"] != scene)]
        mean = mine.groupby(["method", "step"], as_index=False).agg(gain=("gain", "mean"), pairs=("gain", "size"))
        parts.append(mean.assign(fold=f"without-{scene}"))
    return pd.concat(parts, ignore_index=True)


def summary(folds: pd.DataFrame, at: list[int]) -> pd.DataFrame:
    rows = []
    for (fold, method), g in folds.groupby(["fold", "method"], sort=False):
        row = {"fold": fold, "method": method, "pairs": int(g["pairs"].iloc[0])}
        for s in [0, *at]:
            seen = g[g["step"] <= s]
            row[f"Δ@{s}"] = round(float(seen["gain"].iloc[-1]), 2) if s <= g["step"].max() else None
        best = g.loc[g["gain"].idxmax()]
        rows.append(row | {"best_Δ": round(float(best["gain"]), 2), "best_step": int(best["step"])})
    table = pd.DataFrame(rows)
    means = table.drop(columns=["fold", "pairs"]).groupby("method", as_index=False, sort=False).mean().round(2)
    table = pd.concat([table, means.assign(fold="mean of folds")], ignore_index=True)
    return table.astype({"pairs": "Int64", "best_step": "Int64"})


def figure(folds: pd.DataFrame, path: Path) -> None:
    methods = folds["method"].nunique()
    fig, axes = pyplot().subplots(1, methods, figsize=(4.2 * methods, 3.4), squeeze=False)
    for ax, (method, g) in zip(axes[0], folds.groupby("method")):
        for fold, f in g.groupby("fold"):
            ax.plot(f["step"], f["gain"], marker="o", ms=2, lw=1, label=fold)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set(title=f"{method}: scenes it never saw", xlabel="training step", ylabel="gain over the prior (dB)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--preset", type=Path, default=REPO / "workflow" / "presets" / "findings-llff.yaml")
    parser.add_argument("--methods", nargs="+", default=["pix2pix", "restormer"])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--train-size", type=int, default=None, help="scenes per subset (default: all but two)")
    parser.add_argument("--jobs", type=int, default=2, help="subsets trained at once")
    parser.add_argument("--cores", type=int, default=1, help="Snakemake cores per subset")
    parser.add_argument("--at", nargs="+", type=int, default=[100, 300, 500, 1000, 1500, 2000])
    parser.add_argument("--report-only", action="store_true", help="summarise what WORKDIR holds; train nothing")
    args = parser.parse_args()
    args.preset = args.preset.resolve()
    scenes = preset_scenes(args.preset)
    size = args.train_size or len(scenes) - 2
    if not 1 <= size <= len(scenes) - 2:
        sys.exit(f"--train-size {size}: need 1 .. {len(scenes) - 2} of the {len(scenes)} scenes {scenes}")
    subsets = list(itertools.combinations(scenes, size))
    works = {s: args.workdir / "+".join(s) for s in subsets}
    if not args.report_only:
        with ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda s: train(works[s], overrides(s, scenes, args), args), subsets))
    table = pd.DataFrame([row for s in subsets for m in args.methods for row in runs(works[s], s, m)])
    folds = fold_curves(table, scenes)
    result = summary(folds, args.at)
    print(result.to_string(index=False))
    cpu = table.groupby("method")["cpu_s_per_step"].mean().round(3)
    print("\nCPU s / step (validation included):", cpu.to_dict())
    table.to_csv(args.workdir / "scene_holdout_curves_runs.csv", index=False)
    result.to_csv(args.workdir / "scene_holdout_curves.csv", index=False)
    figure(folds, args.workdir / "scene_holdout_curves.png")
    print(f"\nwritten: {args.workdir}/scene_holdout_curves.csv, _runs.csv, .png")


if __name__ == "__main__":
    main()

"""Learning curves of the stage-1 methods: validation gain over their untrained start, and CPU cost.

    python benchmarks/learning_curves.py WORKDIR [--steps 10000] [--every 100]
        [--methods pix2pix restormer ...] [--variants paper no-gan] [--configfile extra.yaml ...]
        [--cores 2] [--at 100 300 1000 3000 10000]

Trains each method with the workflow's own rule (``snakemake results/models/{method}``) on the
training scenes of the default config (plus any ``--configfile``) for ``--steps`` steps at a
constant learning rate (``decay_from: 1``: the curve of one long run reads as "what a budget of
s steps reaches", without the final decay a run of that budget would add), validated every
``--every`` steps from step 0 (the untrained start: the prior for the residual networks) and
never stopped early. Variants, each in ``WORKDIR/{variant}``: ``paper`` (each method's own
losses), ``no-gan`` (Pix2Pix without its adversarial term, ``lambda_gan: 0``), ``pixel``
(Pix2PixHD with a pixel L1 beside its losses, ``lambda_L1: 100``; CycleGAN on aligned pairs with
``lambda_pixel: 10``, its cycle terms' weight) and ``mean4`` (the diffusion
stand-in returning the mean of 4 samples, ``samples: 4``) and ``published`` (each method's
published network, the workflow's ``{method}-pub`` model: ``prior_sigma: 0``, no physics prior
under it; its gain is over the untrained prior's PSNR, from ``results/models/prior``). A second
call reuses what a first built (Snakemake reruns nothing).

Prints per method and variant the validation PSNR gain over the physics prior's own validation
PSNR at step 0 and at each of ``--at`` (the last validation at or before it), the best gain and its
step, and the training's CPU seconds per
step (user + sys of Snakemake's ``benchmarks/train_translator``, validation included), then writes
``WORKDIR/learning_curves.csv`` and a figure ``WORKDIR/learning_curves.png``. Choices made from it
are made on the training scenes' held-out views only: no evaluation scene is trained or scored.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml

REPO = Path(__file__).resolve().parents[1]
METHODS = ["pix2pixhd", "pix2pix", "cyclegan", "restormer", "diffusion"]
# variant -> per-method overrides; a method missing from a variant's dict is not run in it
VARIANTS = {
    "paper": {m: {} for m in METHODS},
    "no-gan": {"pix2pix": {"lambda_gan": 0.0}},
    "pixel": {"pix2pixhd": {"lambda_L1": 100.0}, "cyclegan": {"lambda_pixel": 10.0}},
    "mean4": {"diffusion": {"samples": 4}},
    "published": {m: {} for m in METHODS},  # trains the model folders "{method}-pub" (prior_sigma 0)
}


def folder(variant: str, method: str) -> str:
    """The model folder a variant trains for ``method``: its published network in ``published``."""
    return f"{method}-pub" if variant == "published" else method


def overrides(args, variant: str) -> dict:
    """The config a variant's folder runs: the long constant-rate budget, validation from step 0."""
    stage1 = {
        "train": {"iterations": args.steps, "decay_from": 1.0, "log_every": args.every},
        "validation": {"every": args.every, "patience": 0},
    }
    for method in args.methods:
        if method in VARIANTS[variant]:
            # a method's own validation block (diffusion's) would override the common one
            stage1[method] = {**VARIANTS[variant][method], "validation": {"every": args.every, "patience": 0}}
    return {"stage1": stage1}


def train(work: Path, variant: str, methods: list[str], args) -> None:
    work.mkdir(parents=True, exist_ok=True)
    (work / "curves.yaml").write_text(yaml.safe_dump(overrides(args, variant)))
    configs = ["--configfile", *map(str, args.configfile), str(work / "curves.yaml")]
    # the published networks have no prior of their own: the untrained prior's folder gives the baseline
    folders = [folder(variant, m) for m in methods] + (["prior"] if variant == "published" else [])
    targets = [f"results/models/{f}" for f in folders]
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(work)]
    proc = subprocess.run([*cmd, "--cores", str(args.cores), *configs, "--", *targets], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"{variant}: snakemake failed (log in {work}/.snakemake/log):\n{proc.stderr[-3000:]}")


def trained(work: Path, method: str) -> tuple[dict, float]:
    """A workflow folder's trained method: its train.json and its CPU seconds per step (user + sys
    of Snakemake's ``benchmarks/train_translator``, validation included)."""
    record = json.loads((work / "results" / "models" / method / "train.json").read_text())
    bench = pd.read_csv(work / "benchmarks" / "train_translator" / f"{method}.tsv", sep="\t")
    cpu = float(bench["user_s"].iloc[-1] + bench["sys_s"].iloc[-1])
    return record, cpu / max(int(record["stopped"]["step"]), 1)


def curve(work: Path, method: str) -> tuple[pd.DataFrame, float, float]:
    """A trained method's validation curve (iteration, val_psnr), its CPU seconds per step and its
    physics prior's own validation PSNR (the translators' common baseline)."""
    record, per_step = trained(work, method)
    frame = pd.DataFrame(record["validation"]["curve"])[["iteration", "val_psnr"]]
    if frame["iteration"].iloc[0] != 0:
        raise ValueError(f"{work}/results/models/{method}: no validation at step 0 (trained by older code?)")
    prior = (record.get("prior") or {}).get("val_psnr")
    if prior is None:  # a published network (prior_sigma 0): the prior's own folder, same validation views
        prior = json.loads((work / "results" / "models" / "prior" / "train.json").read_text())["prior"]["val_psnr"]
    return frame, per_step, float(prior)


def summary(frame: pd.DataFrame, at: list[int], prior: float) -> dict:
    """Gain over the physics prior's validation PSNR at step 0 and at each budget of ``at`` (the last
    validation at or before it); the best gain and its step. A residual network starts at the prior
    (step 0 ~ 0 dB); the diffusion stand-in starts from one sample of an untrained network."""
    row = {"prior_psnr": round(prior, 2)}
    for s in [0, *at]:
        seen = frame[frame["iteration"] <= s]
        reached = s <= frame["iteration"].max()
        row[f"Δ@{s}"] = round(float(seen["val_psnr"].iloc[-1]) - prior, 2) if reached else None
    best = frame.loc[frame["val_psnr"].idxmax()]
    return row | {"best_Δ": round(float(best["val_psnr"]) - prior, 2), "best_step": int(best["iteration"])}


def figure(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for (method, variant), gain in curves.items():  # iteration, val_psnr minus the prior's
        style = "-" if variant == "paper" else "--"
        ax.plot(gain["iteration"].clip(lower=1), gain["val_psnr"], ls=style, label=f"{method} ({variant})")
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set(xscale="log", xlabel="training step (step 0 drawn at 1)", ylabel="validation PSNR − the prior's (dB)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--steps", type=int, default=10000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--configfile", nargs="*", type=Path, default=[])
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--at", nargs="+", type=int, default=[100, 300, 1000, 3000, 10000])
    parser.add_argument("--report-only", action="store_true", help="summarise what WORKDIR holds; train nothing")
    args = parser.parse_args()
    rows, curves = [], {}
    for variant in args.variants:
        methods = [m for m in args.methods if m in VARIANTS[variant]]
        if not methods:
            continue
        work = args.workdir / variant
        if not args.report_only:
            train(work, variant, methods, args)
        for method in methods:
            frame, per_step, prior = curve(work, folder(variant, method))
            curves[(method, variant)] = frame.assign(val_psnr=frame["val_psnr"] - prior)
            row = {"method": method, "variant": variant, **summary(frame, args.at, prior)}
            rows.append(row | {"cpu_s_per_step": round(per_step, 3)})
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    table.to_csv(args.workdir / "learning_curves.csv", index=False)
    figure(curves, args.workdir / "learning_curves.png")
    print(f"\nwritten: {args.workdir / 'learning_curves.csv'}, {args.workdir / 'learning_curves.png'}")


if __name__ == "__main__":
    main()

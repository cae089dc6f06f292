"""Stage 1 on fixed pairs against online samples: the same translators, steps and seed.

    python benchmarks/stage1_data.py WORKDIR [--iterations 300] [--methods pix2pix restormer]
                                     [--configfile extra.yaml ...] [--cores 1]

Runs the workflow's own stage 1 (``snakemake results/stage1/{scene}/{method}.json``, ``scene`` the
first of ``scenes.eval``) twice, in ``WORKDIR/fixed`` (``stage1.data: fixed``) and
``WORKDIR/online``, on the default config plus any ``--configfile``, with validation every 25
steps (a method's own ``validation`` block, e.g. diffusion's, still applies) and no early
stopping (``patience: 0``: both train the whole budget; the best validated model is kept).
Prints per mode and method the stage-1 PSNR / SSIM of the evaluation scene's held-out views, the
validation PSNR (best and last) on the training scenes' held-out views, the distinct samples
seen, and the training job's CPU seconds (user + sys, Snakemake's ``benchmarks/train_translator``:
robust on a busy machine). A second call reuses what a first one built (Snakemake reruns nothing).
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


def run_mode(work: Path, mode: str, args) -> None:
    """Stage 1 of every method in ``work`` with ``stage1.data: mode``."""
    work.mkdir(parents=True, exist_ok=True)
    overrides = {
        "stage1": {"data": mode, "train": {"iterations": args.iterations}, "validation": {"every": 25, "patience": 0}}
    }
    (work / "mode.yaml").write_text(yaml.safe_dump(overrides))
    scenes = [yaml.safe_load(p.read_text()).get("scenes", {}) for p in [REPO / "config.yaml", *args.configfile]]
    scene = [s["eval"] for s in scenes if "eval" in s][-1][0]  # the (last configured) first evaluation scene
    targets = [f"results/stage1/{scene}/{m}.json" for m in args.methods]
    configs = ["--configfile", *map(str, args.configfile), str(work / "mode.yaml")]
    cmd = [
        sys.executable,
        "-m",
        "snakemake",
        "-s",
        str(REPO / "Snakefile"),
        "--directory",
        str(work),
        "--cores",
        str(args.cores),
        *targets,
        *configs,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"{mode}: snakemake failed:\n{proc.stderr[-3000:]}")


def row(work: Path, mode: str, method: str) -> dict:
    """The scores, validation and cost of one trained method."""
    record = json.loads((work / "results" / "models" / method / "train.json").read_text())
    scores = next((work / "results" / "stage1").glob(f"*/{method}.json"))
    mean = json.loads(scores.read_text())["mean"]
    curve = record["validation"]["curve"]
    bench = pd.read_csv(work / "benchmarks" / "train_translator" / f"{method}.tsv", sep="\t")
    return {
        "mode": mode,
        "method": method,
        "eval_psnr": round(mean["psnr"], 2),
        "eval_ssim": round(mean["ssim"], 3),
        "val_best": round(record["validation"]["best_psnr"], 2),
        "best_step": record["validation"]["best_step"],
        "val_last": round(curve[-1]["val_psnr"], 2),
        "distinct_samples": record["data"]["distinct_samples"],
        "cpu_s": round(float(bench["user_s"].iloc[-1] + bench["sys_s"].iloc[-1]), 1),  # spc3d.jobs TSV columns
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--configfile", nargs="*", type=Path, default=[])
    parser.add_argument("--cores", type=int, default=1)
    args = parser.parse_args()
    rows = []
    for mode in ("fixed", "online"):
        run_mode(args.workdir / mode, mode, args)
        rows += [row(args.workdir / mode, mode, m) for m in args.methods]
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    wide = table.pivot(index="method", columns="mode", values="eval_psnr").loc[args.methods]
    print("\nevaluation-scene PSNR, online - fixed (dB):")
    print((wide["online"] - wide["fixed"]).round(2).to_string())


if __name__ == "__main__":
    main()

"""The trade of adaptive stage-2 budgets, paired over seeds: time saved and held-out PSNR change.

    python benchmarks/stopping_trade.py RUN [--rows gt+3dgs pix2pixhd+3dgs ...] [--seeds 0 1 2 3 4 5]
                                        [--jobs 2] [--out RUN/trade]

``RUN`` is a finished workflow run (the folder holding ``results/``; made by code that records each
fit's job in ``train.json``). Every chosen row of every scene in ``RUN/results/recon`` is fitted
again with each seed in observe mode (:class:`spc3d.reconstruct.stage2.ReconstructJob` with
``observe_plateau``): it trains to its full budget and renders the held-out views both where its
plateau rule stopped it and at the budget, and both are scored (:func:`spc3d.evaluation.evaluate`).
The inputs (scenes, SPC frames, translations, metered displays) are the run's own, so only the stage-2
fit varies with the seed, and each fit gives one paired unit. ``OUT/results/tables/stopping.*`` is the
table (:mod:`spc3d.evaluation.stopping`); ``workflow/tools/readme_results.py --run trade=OUT`` copies it
into the README. Fits run ``--jobs`` at a time, one thread each (as the workflow's jobs).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from spc3d import io
from spc3d.evaluation.evaluate import evaluate
from spc3d.evaluation.stopping import stopping_table


def fits(run: Path, rows: list[str] | None, seeds: list[int], out: Path) -> list[tuple[dict, Path, Path]]:
    """(job fields, fit folder, metrics file) for every chosen row, scene and seed of ``run``."""
    todo = []
    for train_json in sorted((run / "results" / "recon").glob("*/*/train.json")):
        rec = io.read_json(train_json)
        combo = train_json.parent.name
        if rows and combo not in rows or "-seed" in combo:
            continue
        if "job" not in rec:
            raise SystemExit(f"{train_json}: no 'job' record (made by older code): rerun the workflow first")
        job = {k: (str(run / v) if k.endswith("_dir") and v is not None else v) for k, v in rec["job"].items()}
        scene = train_json.parent.parent.name
        for seed in seeds:
            name = f"{scene}/{combo}-fit{seed}"
            todo.append((job | {"seed": seed}, out / "results" / "recon" / name, out / "results" / "eval" / name))
    return todo


def fit_and_score(job: dict, recon_dir: Path, eval_dir: Path, lpips_dir: str | None) -> str:
    """One observed fit and its scores; skipped when its metrics exist already (a rerun resumes)."""
    import torch

    from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct

    metrics = eval_dir / "metrics.json"
    if not metrics.exists():
        torch.set_num_threads(1)
        if not (recon_dir / "train.json").exists():
            reconstruct(ReconstructJob(out_dir=recon_dir, observe_plateau=True, **job))
        evaluate(recon_dir, job["scene_dir"], metrics, lpips_dir=lpips_dir)
    return str(metrics)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path, help="a finished workflow run (the folder holding results/)")
    ap.add_argument("--rows", nargs="+", help="combinations to fit (default: every row with a stopping rule)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, help="default: RUN/trade")
    args = ap.parse_args()
    run = args.run.resolve()
    out = (args.out or run / "trade").resolve()
    lpips = run / "results" / "cache" / "lpips"  # the run's converted LPIPS weights (rule lpips_weights)
    todo = fits(run, args.rows, args.seeds, out)
    print(f"{len(todo)} fits ({len(args.seeds)} seeds) from {run} into {out}, {args.jobs} at a time")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        lp = str(lpips) if lpips.is_dir() else None
        done = list(pool.map(fit_and_score, *zip(*todo), [lp] * len(todo)))
    table = stopping_table(done, out / "results" / "tables" / "stopping")
    print(f"{len(done)} fits in {time.perf_counter() - t0:.0f} s wall ({os.cpu_count()} CPUs)\n")
    print((out / "results" / "tables" / "stopping.md").read_text())
    return table


if __name__ == "__main__":
    main()

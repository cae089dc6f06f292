"""What a translator's early-stopping patience costs and saves, replayed from recorded validation curves.

    python benchmarks/translator_patience.py MODELS [MODELS ...] [--patience 1 2 3 4]

``MODELS`` are folders of trained translators (a run's ``results/models``; repeats with ``seeds: N``
add ``{method}-seed{N}`` folders, each one independent run). Every ``train.json`` holds the
validation curve on the training scenes' held-out views (:mod:`spc3d.translate.validate`), which
does not depend on the patience: training up to a step is the same whatever rule would stop it
later. So a smaller patience ``p`` is replayed exactly on a curve recorded with patience ``P >= p``:
the run would have stopped ``p`` validations after its best, keeping the best model up to there.

Printed per method and patience, over the runs (one curve = one unit): n, the mean stop step
against the budget, the steps saved against the recorded run, and the change of the kept model's
validation PSNR (mean, 95 % sign-flip interval, :func:`spc3d.evaluation.findings.interval`;
unbounded below 6 runs) with how many runs lost their best model. Only training-scene views are
read: a patience is chosen here, never on an evaluation scene.
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.evaluation.findings import interval


def replay(curve: list[tuple[int, float]], patience: int) -> tuple[int, float]:
    """(stop step, best PSNR kept) of a validation ``curve`` [(step, psnr)] under ``patience``
    validations without a better PSNR (0: never stop)."""
    best, since = -math.inf, 0
    for step, value in curve:
        if value > best:
            best, since = value, 0
        else:
            since += 1
            if patience and since >= patience:
                return step, best
    return curve[-1][0], best


def read_runs(folders: list[Path]) -> dict[str, list[dict]]:
    """Method -> the runs whose train.json records a validation curve: {name, patience, of, curve}."""
    runs: dict[str, list[dict]] = {}
    for folder in folders:
        for path in sorted(folder.glob("*/train.json")):
            rec = io.read_json(path)
            val = rec.get("validation")
            if not isinstance(val, dict) or not val.get("curve") or not rec["stopped"]["of"]:
                continue  # a run without validation, or the prior (validated once, never trained)
            curve = [(int(e["iteration"]), float(e["val_psnr"])) for e in val["curve"]]
            method = re.sub(r"-seed\d+$", "", path.parent.name)
            run = {"name": str(path.parent), "patience": int(val["patience"]), "of": int(rec["stopped"]["of"])}
            runs.setdefault(method, []).append(run | {"curve": curve})
    return runs


def replayable(run: dict, patience: int) -> bool:
    """A curve replays any patience when it reached the budget (or was never stopped), else any
    nonzero patience up to the one it was recorded with."""
    complete = run["patience"] == 0 or run["curve"][-1][0] >= run["of"]
    return complete or 0 < patience <= run["patience"]


def summarise(runs: list[dict], patience: int) -> dict | None:
    """One table row of ``runs`` under ``patience`` (None when a run's curve ends before the replay could)."""
    if not all(replayable(r, patience) for r in runs):
        return None
    stops, saved, delta, lost = [], [], [], 0
    for r in runs:
        rec_stop, rec_best = replay(r["curve"], r["patience"])
        stop, best = replay(r["curve"], patience)
        stops.append(stop / r["of"])
        saved.append((rec_stop - stop) / r["of"])
        delta.append(best - rec_best)
        lost += best < rec_best
    d = np.array(delta)
    lo, hi = interval(d)
    summary = {"n": len(runs), "stop": np.mean(stops), "saved": np.mean(saved), "delta": d.mean()}
    return summary | {"lo": lo, "hi": hi, "lost": lost}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", type=Path, help="folders of trained translators (results/models)")
    ap.add_argument("--patience", nargs="+", type=int, default=[1, 2, 3, 4])
    args = ap.parse_args()
    runs = read_runs(args.models)
    if not runs:
        raise SystemExit(f"no train.json with a validation curve under {', '.join(map(str, args.models))}")
    head = ["method", "patience", "n", "stop (of budget)", "steps saved", "Δ val PSNR (dB) [95 %]"]
    print("| " + " | ".join(head + ["runs that lost their best"]) + " |")
    print("|---" * (len(head) + 1) + "|")
    for method in sorted(runs):
        recorded = sorted({r["patience"] for r in runs[method]})
        for p in args.patience:
            s = summarise(runs[method], p)
            if s is None:
                print(f"| {method} | {p} | recorded with patience {recorded}: cannot replay |||||")
                continue
            span = "n < 6" if math.isinf(s["lo"]) else f"{s['lo']:+.3f}, {s['hi']:+.3f}"
            print(
                f"| {method} | {p} | {s['n']} | {s['stop']:.0%} | {s['saved']:.0%} | {s['delta']:+.3f} [{span}] "
                f"| {s['lost']}/{s['n']} |"
            )


if __name__ == "__main__":
    main()

"""Every choice each leave-one-out fold made, read from a run's files, as Markdown tables.

    python workflow/tools/fold_choices.py RESULTS_DIR [--out RESULTS_DIR/tables/fold_choices.md]

For each fold (``results/*-without-{scene}``): the training scene its translators were validated on
and its joint weights chosen on, the classical denoiser it chose (``models-without-*/classical``),
its display levels (``calibration-without-*/display-k*.json``), the step each translator kept and
why it stopped (``models-without-*/{method}/train.json``), and each joint row's weight with every
candidate's mean PSNR (``choices-without-*/*.json``). Nothing is typed: the tables are the files'.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from spc3d import io  # noqa: E402


def folds(results: Path) -> list[str]:
    """The left-out scenes of the run's folds, sorted."""
    return sorted({m.group(1) for p in results.glob("*-without-*") if (m := re.search(r"-without-(.+)$", p.name))})


def summary_table(results: Path) -> str:
    lines = ["| left out | joint weights chosen on | classical denoiser | display level k (K) |", "|---|---|---|---|"]
    for scene in folds(results):
        choices = sorted((results / f"choices-without-{scene}").glob("*.json"))
        held = sorted({s for c in choices for s in io.read_json(c)["scenes"]})
        classical = results / f"models-without-{scene}" / "classical" / "train.json"
        chosen = io.read_json(classical)["selection"]["chosen"] if classical.is_file() else "–"
        levels = [io.read_json(p) for p in sorted((results / f"calibration-without-{scene}").glob("display-k*.json"))]
        shown = ", ".join(f"{c['level']:.3f} ({c['K']})" for c in levels) or "–"
        lines.append(f"| {scene} | {', '.join(held) or '–'} | {chosen} | {shown} |")
    return "\n".join(lines)


def translator_table(results: Path) -> str:
    runs = {
        (scene, p.parent.name): io.read_json(p)
        for scene in folds(results)
        for p in sorted((results / f"models-without-{scene}").glob("*/train.json"))
    }
    methods = sorted({m for _, m in runs if m not in ("prior", "classical")})
    lines = ["| left out | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for scene in folds(results):
        cells = []
        for m in methods:
            rec = runs.get((scene, m))
            stop = (rec or {}).get("stopped") or {}
            cells.append(f"{rec['model_step']} of {stop.get('of', '?')} ({stop.get('reason', '?')})" if rec else "–")
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def joint_table(results: Path) -> str:
    lines = ["| left out | row | weight chosen | mean PSNR of each candidate (dB) |", "|---|---|---|---|"]
    for scene in folds(results):
        for path in sorted((results / f"choices-without-{scene}").glob("*.json")):
            c = io.read_json(path)
            means = ", ".join(f"{w}: {v:.2f}" for w, v in c["mean_psnr"].items())
            lines.append(f"| {scene} | {c['row']} | {c['chosen']['weight']:g} | {means} |")
    return "\n".join(lines)


def fold_choices(results: Path) -> str:
    return "\n\n".join(
        [
            "# Fold choices",
            "Each fold's choices, made by its own jobs from its training scenes:",
            summary_table(results),
            "The step each translator kept (validated on the fold's held-out training scene), of its budget, "
            "and why it stopped:",
            translator_table(results),
            "The joint rows' prior weight, each candidate fitted as the row on the held-out training scene:",
            joint_table(results),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    if not folds(args.results):
        raise SystemExit(f"{args.results}: no fold folders (*-without-SCENE): not a leave-one-out run's results/")
    out = args.out or args.results / "tables" / "fold_choices.md"
    io.write_text(out, fold_choices(args.results) + "\n")
    print(f"{out}: {len(folds(args.results))} folds")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

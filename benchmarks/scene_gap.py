"""How far one evaluation scene sits from the others, row by row: a scene-specific artefact shows up
as one scene far below (or above) the rest for every row that shares the cause.

    python benchmarks/scene_gap.py RESULTS [RESULTS_BEFORE] --scene observatory [--out FILE]

For every row (stage 2, and stage 1 before 3D under ``stage 1:``): its PSNR on ``--scene`` (mean
over seeds), the mean over the other scenes' runs, and the gap (scene − others). With a second
results folder (the same preset before a change), both gaps side by side and how much the gap
closed. ``--out``: also write the table as Markdown (for the docs' generated blocks).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d import io  # noqa: E402
from spc3d.evaluation.findings import Row, read_rows, read_stage1  # noqa: E402


def rows_of(results: Path) -> dict[str, Row]:
    rows = read_rows(sorted(results.glob("eval/*/*/metrics.json")))
    stage1 = read_stage1(sorted(results.glob("stage1/*/*.json")))
    return rows | {f"stage 1: {name}": row for name, row in stage1.items()}


def gaps(rows: dict[str, Row], scene: str) -> dict[str, tuple[float, float, float]]:
    """Row -> (PSNR on ``scene``, mean PSNR elsewhere, gap), both means over the rows' finite runs."""
    out = {}
    for name, row in rows.items():
        here = [v for (s, _), v in row.runs.items() if s == scene and np.isfinite(v)]
        rest = [v for (s, _), v in row.runs.items() if s != scene and np.isfinite(v)]
        if here and rest:
            out[name] = (float(np.mean(here)), float(np.mean(rest)), float(np.mean(here) - np.mean(rest)))
    return out


def table(after: dict, before: dict | None, scene: str) -> list[str]:
    head = ["row", f"{scene}", "other scenes", "gap (dB)"]
    if before is not None:
        head += ["gap before (dB)", "closed by (dB)"]
    lines = [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for name in sorted(after, key=lambda n: after[n][2]):
        here, rest, gap = after[name]
        cells = [name, f"{here:.2f}", f"{rest:.2f}", f"{gap:+.2f}"]
        if before is not None:
            old = before.get(name)
            cells += ["–", "–"] if old is None else [f"{old[2]:+.2f}", f"{abs(old[2]) - abs(gap):+.2f}"]
        lines.append(f"| {' | '.join(cells)} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="results/ of a run with several evaluation scenes")
    ap.add_argument("before", type=Path, nargs="?", help="results/ of the same preset before a change")
    ap.add_argument("--scene", required=True, help="the evaluation scene set against the others")
    ap.add_argument("--out", type=Path, help="write the table as Markdown here too")
    args = ap.parse_args()
    after = gaps(rows_of(args.results), args.scene)
    if not after:
        raise SystemExit(f"{args.results}: no row has runs on {args.scene!r} and on another scene")
    before = gaps(rows_of(args.before), args.scene) if args.before else None
    lines = table(after, before, args.scene)
    print("\n".join(lines))
    if args.out:
        io.write_text(
            args.out, f"# PSNR on {args.scene} against the other scenes, per row\n\n" + "\n".join(lines) + "\n"
        )


if __name__ == "__main__":
    main()

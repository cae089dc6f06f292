"""How far identical code moves a row between two machines, against how far a row moves between seeds:
the measurement behind the findings' smallest effect of interest (``findings.smallest_effect_db``).

    python benchmarks/machine_spread.py RUN_A/results RUN_B/results [--seeds FINDINGS/results]

RUN_A and RUN_B are two runs of the same commit and config (same seeds, so the same SPC frames)
on two machines, or on one machine with another instruction set (e.g. ``ATEN_CPU_CAPABILITY=avx2
NUMBA_CPU_NAME=haswell`` on an AVX-512 machine: torch's kernels and the rasterizer's LLVM code then
sum in another order, as on an older CPU). Printed: every row's PSNR in both (stage 2 and stage 1
before 3D), their difference, and the quantiles of |difference| over the rows. ``--seeds``: a
findings run (several seeds per scene), whose per-row standard deviation over seeds within a scene
is printed beside, for scale: the test's intervals already carry that spread; the machine spread is
what the same code, seed and data move, which no interval carries.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d.evaluation.findings import Row, read_rows, read_stage1  # noqa: E402

STAGE1 = "stage 1: "


def rows_of(results: Path) -> dict[str, Row]:
    """Every scored row of a results folder: stage 2, and stage 1 under the ``stage 1:`` prefix."""
    rows = read_rows(sorted(results.glob("eval/*/*/metrics.json")))
    stage1 = read_stage1(sorted(results.glob("stage1/*/*.json")))
    return rows | {STAGE1 + name: row for name, row in stage1.items()}


def differences(a: dict[str, Row], b: dict[str, Row]) -> list[tuple[str, tuple, float, float]]:
    """(row, run, PSNR in a, PSNR in b) of every run both scored."""
    out = []
    for name in sorted(a.keys() & b.keys()):
        for run in sorted(a[name].runs.keys() & b[name].runs.keys(), key=str):
            x, y = a[name].runs[run], b[name].runs[run]
            if np.isfinite(x) and np.isfinite(y):
                out.append((name, run, x, y))
    return out


def seed_spread(rows: dict[str, Row]) -> dict[str, float]:
    """Per row: the pooled standard deviation over seeds within a scene (dB)."""
    out = {}
    for name, row in rows.items():
        by_scene: dict[str, list[float]] = {}
        for (scene, _), v in row.runs.items():
            if np.isfinite(v):
                by_scene.setdefault(scene, []).append(v)
        groups = [np.asarray(v) for v in by_scene.values() if len(v) > 1]
        dof = sum(len(g) - 1 for g in groups)
        if dof:
            out[name] = float(np.sqrt(sum(((g - g.mean()) ** 2).sum() for g in groups) / dof))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=Path, help="results/ of the first run")
    ap.add_argument("b", type=Path, help="results/ of the same commit and config on the other machine")
    ap.add_argument("--seeds", type=Path, help="results/ of a findings run: per-row spread over seeds, for scale")
    args = ap.parse_args()
    pairs = differences(rows_of(args.a), rows_of(args.b))
    if not pairs:
        raise SystemExit(f"{args.a} and {args.b} share no scored run: are they two runs of one config?")
    spread = seed_spread(rows_of(args.seeds)) if args.seeds else {}
    print(f"{'row':<34} {'run':<22} {'A':>7} {'B':>7} {'B - A':>7} {'seed sd':>8}")
    for name, run, x, y in pairs:
        sd = f"{spread[name]:8.2f}" if name in spread else f"{'–':>8}"
        print(f"{name:<34} {str(run):<22} {x:7.2f} {y:7.2f} {y - x:+7.2f} {sd}")
    gaps = np.abs([y - x for *_, x, y in pairs])
    q = np.quantile(gaps, [0.5, 0.75, 0.9, 1.0])
    print(
        f"\n|B - A| over {len(gaps)} row-runs (dB): median {q[0]:.3f}, 75 % {q[1]:.3f}, 90 % {q[2]:.3f}, max {q[3]:.3f}"
    )
    print(f"rows moved by more than 0.25 dB: {int((gaps > 0.25).sum())} of {len(gaps)}")
    if spread:
        sds = np.array(list(spread.values()))
        print(f"seed sd within a scene over {len(sds)} rows (dB): median {np.median(sds):.3f}, max {sds.max():.3f}")


if __name__ == "__main__":
    main()

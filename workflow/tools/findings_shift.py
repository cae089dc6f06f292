"""How far the findings moved between two runs of the findings preset (see spc3d.evaluation.shift).

    python workflow/tools/findings_shift.py OLD_RESULTS NEW_RESULTS [--names OLD NEW] [--out FILE]

OLD_RESULTS and NEW_RESULTS are the ``results/`` folders of two finished runs of
``workflow/presets/findings.yaml`` (e.g. before and after a change meant to leave the science alone).
Prints the table and writes it to FILE (default: NEW_RESULTS/tables/findings_shift.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # workflow/, for spc3d from a checkout

from spc3d.evaluation.shift import write_shift  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("old", type=Path, help="results/ of the earlier findings run")
    parser.add_argument("new", type=Path, help="results/ of the later findings run")
    parser.add_argument("--names", nargs=2, metavar=("OLD", "NEW"), help="labels for the two runs (e.g. commits)")
    parser.add_argument("--out", type=Path, help="where to write the table (default: NEW/tables/findings_shift.md)")
    args = parser.parse_args(argv)
    try:
        print(write_shift(args.old, args.new, args.out, tuple(args.names) if args.names else None), end="")
    except FileNotFoundError as err:
        raise SystemExit(f"findings_shift: {err}") from None


if __name__ == "__main__":
    main()

"""Keep a run's tables in the repository, as the sources of the docs' generated blocks of that run.

    python workflow/tools/archive_run.py RESULTS_DIR NAME [--with findings.json ...]

Copies ``RESULTS_DIR/tables/*.md`` (and each ``--with`` file of ``RESULTS_DIR/tables``) into
``docs/measurements/NAME/tables/``, replacing what was there, then refreshes the blocks
``NAME:tables/...`` of the README and docs/ from it (``readme_results.refresh_run``), the other
blocks left as they are. ``tests/test_generated_blocks.py`` fails when a block of an archived run
differs from its file: results/ is not kept in git, and a figure in the docs needs a file behind
it that stays.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_results import refresh_run  # noqa: E402

from spc3d import io  # noqa: E402

ARCHIVE = Path(__file__).resolve().parents[2] / "docs" / "measurements"


def archive(results: Path, name: str, extra: list[str]) -> list[Path]:
    tables = results / "tables"
    files = sorted(tables.glob("*.md")) + [tables / e for e in extra]
    missing = [str(f) for f in files if not f.is_file()]
    if not files or missing:
        what = "missing " + ", ".join(missing) if missing else "no tables"
        raise SystemExit(f"{tables}: {what}: run the workflow first")
    out = ARCHIVE / name / "tables"
    with io.atomic_path(out, is_dir=True) as tmp:
        for f in files:
            shutil.copy2(f, tmp / f.name)
    return [out / f.name for f in files]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("name")
    ap.add_argument("--with", dest="extra", nargs="*", default=[], help="more files of RESULTS_DIR/tables to keep")
    args = ap.parse_args(argv)
    kept = archive(args.results, args.name, args.extra)
    print(f"{ARCHIVE / args.name}: {len(kept)} files")
    for doc, count in refresh_run(ARCHIVE.parents[1] / "README.md", args.name, ARCHIVE / args.name).items():
        if count:
            print(f"{doc}: {count} block(s) of run {args.name} refreshed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

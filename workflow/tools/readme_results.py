"""Copy generated result tables into the README, between markers, so its numbers are never typed.

    python workflow/tools/readme_results.py RESULTS_DIR [README.md] [--run NAME=DIR ...]

Every block of the README of the form

    <!-- generated: tables/two_stage.md -->
    ...anything (replaced)...
    <!-- /generated -->

is replaced by the file ``RESULTS_DIR/tables/two_stage.md`` (its first heading dropped) and a line
naming the file and its date; the README's own text says which run that was. A block naming
``NAME:tables/findings.md`` is read from the results of another run, given as ``--run NAME=DIR``
(e.g. the findings preset's). A missing file or run is an error naming it; the README is written
atomically.
"""

from __future__ import annotations

import datetime
import re
import sys
from pathlib import Path

BLOCK = re.compile(r"(<!-- generated: (?P<path>[^ ]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S)


def provenance(results: Path, path: Path, run: str = "") -> str:
    when = datetime.datetime.fromtimestamp(path.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
    where = f"the {run} run's " if run else ""
    rel = path.relative_to(results)
    return f"*Copied by `workflow/tools/readme_results.py` from {where}`results/{rel}` ({when}).*"


def body(runs: dict[str, Path], ref: str) -> str:
    run, _, rel = ref.rpartition(":")
    if run not in runs:
        raise SystemExit(f"the README block names run {run!r} ({ref}): give its results as --run {run}=DIR")
    results = runs[run]
    path = results / rel
    if not path.is_file():
        raise SystemExit(f"{path} does not exist: run the workflow first (the README block names {rel})")
    text = path.read_text()
    text = re.sub(r"\A# .*\n+", "", text)  # the file's own title: the README has its heading
    return text.rstrip() + "\n\n" + provenance(results, path, run) + "\n"


def parse_args(argv: list[str]) -> tuple[dict[str, Path], Path] | None:
    """({run name: results dir}, README) from the command line ("" is RESULTS_DIR); None if malformed."""
    plain, runs = [], {}
    args = iter(argv)
    for arg in args:
        if arg == "--run":
            name, eq, folder = next(args, "").partition("=")
            if not (name and eq and folder):
                return None
            runs[name] = Path(folder)
        else:
            plain.append(arg)
    if not plain or len(plain) > 2:
        return None
    runs[""] = Path(plain[0])
    return runs, Path(plain[1] if len(plain) > 1 else "README.md")


def main(argv: list[str]) -> int:
    parsed = parse_args(argv)
    if parsed is None:
        print(__doc__)
        return 2
    runs, readme = parsed
    text = readme.read_text()
    new, count = BLOCK.subn(lambda m: m.group(1) + body(runs, m.group("path")) + m.group(4), text)
    tmp = readme.with_name(f".{readme.name}.tmp")
    tmp.write_text(new)
    tmp.replace(readme)
    print(f"{readme}: {count} generated block(s) refreshed from {', '.join(map(str, runs.values()))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

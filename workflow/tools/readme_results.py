"""Copy generated result tables into the README, between markers, so its numbers are never typed.

    python workflow/tools/readme_results.py RESULTS_DIR [README.md]

Every block of the README of the form

    <!-- generated: tables/two_stage.md -->
    ...anything (replaced)...
    <!-- /generated -->

is replaced by the file ``RESULTS_DIR/tables/two_stage.md`` (its first heading dropped) and a line
naming the file and its date; the README's own text says which run that was. A missing file is an
error naming it; the README is written atomically.
"""

from __future__ import annotations

import datetime
import re
import sys
from pathlib import Path

BLOCK = re.compile(r"(<!-- generated: (?P<path>[^ ]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S)


def provenance(results: Path, path: Path) -> str:
    when = datetime.datetime.fromtimestamp(path.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
    return f"*Copied by `workflow/tools/readme_results.py` from `results/{path.relative_to(results)}` ({when}).*"


def body(results: Path, rel: str) -> str:
    path = results / rel
    if not path.is_file():
        raise SystemExit(f"{path} does not exist: run the workflow first (the README block names {rel})")
    text = path.read_text()
    text = re.sub(r"\A# .*\n+", "", text)  # the file's own title: the README has its heading
    return text.rstrip() + "\n\n" + provenance(results, path) + "\n"


def main(argv: list[str]) -> int:
    if not argv or len(argv) > 2:
        print(__doc__)
        return 2
    results, readme = Path(argv[0]), Path(argv[1] if len(argv) > 1 else "README.md")
    text = readme.read_text()
    new, count = BLOCK.subn(lambda m: m.group(1) + body(results, m.group("path")) + m.group(4), text)
    tmp = readme.with_name(f".{readme.name}.tmp")
    tmp.write_text(new)
    tmp.replace(readme)
    print(f"{readme}: {count} generated block(s) refreshed from {results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

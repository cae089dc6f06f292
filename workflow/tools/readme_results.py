"""Copy generated result tables into the README and docs/, between markers, so their numbers are never typed.

    python workflow/tools/readme_results.py RESULTS_DIR [README.md] [--run NAME=DIR ...] [--keep NAME ...]

Every block of the README, and of every ``docs/*.md`` beside it, of the form

    <!-- generated: tables/two_stage.md -->
    ...anything (replaced)...
    <!-- /generated -->

is replaced by the file ``RESULTS_DIR/tables/two_stage.md`` (its first heading dropped) and a line
naming the file and its date; the document's own text says which run that was. A block naming
``NAME:tables/findings.md`` is read from the results of another run, given as ``--run NAME=DIR``
(e.g. the findings preset's). The README defaults to ``./README.md``; its ``docs/`` folder is found
next to it. A missing file or run is an error naming it and the document that asks for it, and
then no document is written; otherwise each document is written atomically. ``--keep NAME``
leaves the blocks of run NAME as they are (a run not repeated this time; its blocks keep the
provenance line that names their date).
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
    shown = f"results/{path.relative_to(results)}"
    parts = path.resolve().parts
    archived = [i for i in range(len(parts) - 1) if parts[i : i + 2] == ("docs", "measurements")]
    if archived:  # a run kept in git (archive_run.py): name the file a reader can open
        shown = "/".join(parts[archived[-1] :])
    return f"*Copied by `workflow/tools/readme_results.py` from {where}`{shown}` ({when}).*"


def body(runs: dict[str, Path], ref: str, doc: Path = Path("README.md"), kept: str | None = None) -> str:
    """The text for a block of ``doc`` naming ``ref`` (``[RUN:]path`` in a run's results); ``kept``:
    the block's current text, returned as it is when its run is kept (``runs[run]`` is None)."""
    run, _, rel = ref.rpartition(":")
    if run in runs and runs[run] is None:
        return kept
    if run not in runs:
        raise SystemExit(f"{doc}: a block names run {run!r} ({ref}): give its results as --run {run}=DIR")
    results = runs[run]
    path = results / rel
    if not path.is_file():
        raise SystemExit(f"{path} does not exist: run the workflow first ({doc} has a block naming {ref})")
    text = path.read_text()
    text = re.sub(r"\A# .*\n+", "", text)  # the file's own title: the document has its heading
    return text.rstrip() + "\n\n" + provenance(results, path, run) + "\n"


def documents(readme: Path) -> list[Path]:
    """The README and every ``docs/*.md`` next to it, in a fixed order."""
    return [readme, *sorted((readme.parent / "docs").glob("*.md"))]


def refresh(runs: dict[str, Path], doc: Path) -> tuple[str, int]:
    """``doc``'s text with every generated block replaced, and how many there were."""
    return BLOCK.subn(
        lambda m: m.group(1) + body(runs, m.group("path"), doc, m.group("body")) + m.group(4), doc.read_text()
    )


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def refresh_run(readme: Path, name: str, results: Path) -> dict[Path, int]:
    """Refresh only the blocks of run ``name`` (``NAME:tables/...``, read from ``results``) in the
    README and docs/, every other block left as it is (a benchmark that writes its own tables, e.g.
    ``benchmarks/real_spad.py --docs``). Returns {document: blocks of that run}; all documents are
    rendered before any is written, as in :func:`main`."""
    docs = documents(readme)
    names = {m.group("path").rpartition(":")[0] for doc in docs for m in BLOCK.finditer(doc.read_text())}
    runs = {n: None for n in names} | {name: results}
    refreshed = [(doc, *refresh(runs, doc)) for doc in docs]
    counts = {}
    for doc, text, _ in refreshed:
        if text != doc.read_text():
            write_atomically(doc, text)
        counts[doc] = sum(m.group("path").rpartition(":")[0] == name for m in BLOCK.finditer(text))
    return counts


def parse_args(argv: list[str]) -> tuple[dict[str, Path | None], Path] | None:
    """({run name: results dir, or None for a kept run}, README) from the command line ("" is
    RESULTS_DIR); None if malformed."""
    plain, runs = [], {}
    args = iter(argv)
    for arg in args:
        if arg == "--run":
            name, eq, folder = next(args, "").partition("=")
            if not (name and eq and folder):
                return None
            runs[name] = Path(folder)
        elif arg == "--keep":
            name = next(args, "")
            if not name:
                return None
            runs[name] = None
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
    if not readme.is_file():
        raise SystemExit(f"{readme} does not exist: give the README's path")
    # Every document is rendered before any is written: a missing file or run changes nothing.
    refreshed = [(doc, *refresh(runs, doc)) for doc in documents(readme)]
    sources = ", ".join(str(d) for d in runs.values() if d is not None)
    for doc, text, count in refreshed:
        if text != doc.read_text():
            write_atomically(doc, text)
        if count or doc == readme:
            print(f"{doc}: {count} generated block(s) refreshed from {sources}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

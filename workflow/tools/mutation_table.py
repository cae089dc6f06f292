"""The mutation-testing table of docs/testing.md, from mutmut's own result caches.

    python workflow/tools/mutation_table.py OUT --run NAME=CACHE[#FILE]:RUNNER ... [--equivalent TSV]
        [--commit REV] [--survivors]

Each ``--run`` names a module's mutmut 2 run: its ``.mutmut-cache`` (an SQLite file: one row per
mutant with its status; ``#FILE``: only that source file's rows) and the test files its runner ran
(``RUNNER``, comma-separated). The
equivalent mutants (a change no behaviour can tell, e.g. a constant's value never read as such)
are judged by hand in a TSV (``file``, ``line``, ``index``, ``source``, ``why``: mutant ``index``
of source line ``line``, whose text must still read ``source``), kept beside the table, so the
judgement is a file a reader can check rather than a count. Writes ``OUT/tables/mutation.md``:
per module the mutants, the killed (a timed-out mutant counts as killed: its tests ran ten times
their baseline and failed to finish), the equivalent, the survivors, those not run yet (a run
stopped before its end: only with ``--partial``, else an error) and the share killed of the
non-equivalent mutants run; then each equivalent mutant with its reason. ``--survivors``
prints the surviving, non-equivalent mutants (``file:line index: source``), the list to examine.
``workflow/tools/archive_run.py OUT mutation`` then keeps the table for docs/testing.md's block.
"""

from __future__ import annotations

import argparse
import csv
import sqlite3
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from spc3d import io  # noqa: E402

KILLED = {"ok_killed", "ok_suspicious", "bad_timeout"}
SURVIVED = "bad_survived"


@dataclass(frozen=True)
class Mutant:
    file: str
    line: int
    index: int
    source: str
    status: str

    @property
    def key(self) -> tuple[str, int, int]:
        return self.file, self.line, self.index


def read_cache(path: Path, only: str | None = None) -> list[Mutant]:
    """Every mutant of a mutmut 2 cache (its SQLite tables SourceFile, Line, Mutant); ``only``: those
    of that source file (a cache reused across modules holds the other module's rows too)."""
    if not path.is_file():
        raise SystemExit(f"{path}: no mutmut cache there (mutmut run writes .mutmut-cache)")
    query = (
        "SELECT SourceFile.filename, Line.line_number, Mutant.`index`, Line.line, Mutant.status "
        "FROM Mutant JOIN Line ON Mutant.line = Line.id JOIN SourceFile ON Line.sourcefile = SourceFile.id"
    )
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
        rows = db.execute(query).fetchall()
    # mutmut numbers lines from 0 in its cache; editors and tracebacks from 1
    return [Mutant(f, n + 1, i, (src or "").strip(), s) for f, n, i, src, s in rows if only in (None, f)]


def read_equivalent(path: Path | None, mutants: list[Mutant]) -> dict[tuple[str, int, int], str]:
    """{mutant key: why it is equivalent}; a judgement whose line no longer reads as judged is an error."""
    if path is None:
        return {}
    by_key = {m.key: m for m in mutants}
    judged = {}
    with open(path, newline="") as f:
        for n, row in enumerate(csv.DictReader(f, delimiter="\t"), start=2):
            key = (row["file"], int(row["line"]), int(row["index"]))
            m = by_key.get(key)
            if m is not None and m.source != row["source"].strip():
                raise SystemExit(f"{path}:{n}: {key[0]}:{key[1]} now reads {m.source!r}, judged as {row['source']!r}")
            if m is not None:
                judged[key] = row["why"]
    return judged


def counts(mutants: list[Mutant], equivalent: dict) -> dict[str, int]:
    killed = sum(m.status in KILLED for m in mutants)
    equiv = sum(m.status == SURVIVED and m.key in equivalent for m in mutants)
    survived = sum(m.status == SURVIVED and m.key not in equivalent for m in mutants)
    untested = len(mutants) - killed - equiv - survived
    return {"mutants": len(mutants), "killed": killed, "equivalent": equiv, "survived": survived, "untested": untested}


def runner_files(runner: str) -> str:
    """The test files of a runner (comma-separated pytest arguments), and how many tests it deselects."""
    args = runner.split(",")
    files = ", ".join(f"`{Path(a).name}`" for a in args if a.startswith("tests/") and "::" not in a)
    left_out = args.count("--deselect")
    return files + (f" (less {left_out} deselected)" if left_out else "")


def table(runs: dict[str, tuple[list[Mutant], str]], equivalent: dict, commit: str, partial: bool = False) -> str:
    lines = [
        "# Mutation testing",
        "",
        f"mutmut 2.4.5 at commit `{commit}`, one run per module with the tests its runner names (`-x`).",
        "",
        "| module | tests run per mutant | mutants | killed | equivalent | survivors | not run yet | "
        "killed / non-equivalent run |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, (mutants, runner) in runs.items():
        c = counts(mutants, equivalent)
        if c["untested"] and not partial:
            raise SystemExit(f"{name}: {c['untested']} mutants untested: the run did not finish (--partial shows it)")
        live = c["killed"] + c["survived"]
        share = f"{100 * c['killed'] / live:.1f} %" if live else "–"
        files = runner_files(runner)
        lines.append(
            f"| `{name}` | {files} | {c['mutants']} | {c['killed']} | {c['equivalent']} | {c['survived']} | "
            f"{c['untested']} | {share} |"
        )
    judged = [(m, equivalent[m.key]) for mutants, _ in runs.values() for m in mutants if m.key in equivalent]
    if judged:
        lines += ["", "Equivalent mutants (judged by hand; mutant index of the line, as `mutmut show` numbers):", ""]
        lines += [f"- `{m.file}:{m.line}` #{m.index} `{m.source}`: {why}" for m, why in judged]
    return "\n".join(lines) + "\n"


def parse_run(spec: str) -> tuple[str, Path, str | None, str]:
    """(name, cache, its source file or None for all, runner) of ``NAME=CACHE[#FILE]:TESTS``."""
    name, eq, rest = spec.partition("=")
    cache, colon, runner = rest.partition(":")
    if not (name and eq and colon and runner):
        raise SystemExit(f"--run {spec!r}: give NAME=CACHE[#FILE]:TESTS (e.g. o=.mutmut-cache:tests/test_x.py)")
    cache, _, only = cache.partition("#")
    return name, Path(cache), only or None, runner


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="a results folder: the table goes to OUT/tables/mutation.md")
    ap.add_argument("--run", action="append", required=True, help="NAME=CACHE:TESTS (comma-separated)")
    ap.add_argument("--equivalent", type=Path, help="TSV of the mutants judged equivalent")
    ap.add_argument("--commit", default="unknown", help="the commit the runs tested")
    ap.add_argument("--survivors", action="store_true", help="print the surviving non-equivalent mutants")
    ap.add_argument("--partial", action="store_true", help="a run not finished: count its untested mutants")
    args = ap.parse_args(argv)
    runs: dict[str, tuple[list[Mutant], str]] = {}
    for name, cache, only, runner in map(parse_run, args.run):  # a module run in parts: its caches join
        runs.setdefault(name, ([], runner))[0].extend(read_cache(cache, only))
    everything = [m for mutants, _ in runs.values() for m in mutants]
    equivalent = read_equivalent(args.equivalent, everything)
    if args.survivors:
        for m in everything:
            if m.status == SURVIVED and m.key not in equivalent:
                print(f"{m.file}:{m.line} {m.index}: {m.source}")
        return 0
    io.write_text(args.out / "tables" / "mutation.md", table(runs, equivalent, args.commit, args.partial))
    print(f"{args.out / 'tables' / 'mutation.md'}: {len(runs)} modules, {len(everything)} mutants")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

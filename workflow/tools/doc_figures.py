"""Measured figures in the README and docs/ that no file backs: the typed numbers a reader cannot check.

    python workflow/tools/doc_figures.py [README.md]

A measured figure is a number or a range (``~25 s``, ``3–13 dB``) with a unit of measurement (dB,
it/s, ms, s, min, h, CPU seconds, GB, MB, degrees, a × speed-up) or a signed decimal (a Δ, +1.85).
It is backed when it stands in a generated block (``<!-- generated: ... -->``, copied from a run's
file by ``readme_results.py``), or when all its numbers appear in a generated block of the same
document or in an archived file (``docs/measurements/``): prose that quotes a table's figure then
names a figure the table holds.
Everything else is listed as ``document:line: figure``, and the exit status is 1 when any is.
Settings are not figures (``128×96``, ``every 10 %``, ``1,200 iterations``: no measured unit),
and neither are the numbers of a command line or of inline code (``--steps 3000``, a message).

A number typed from a terminal, or from a run whose files are gone, cannot be checked against
anything: quote a file instead (``benchmarks/record.py``, ``workflow/tools/archive_run.py``) or
state the finding without it. ``tests/test_doc_figures.py`` runs this on the repository.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_results import BLOCK, documents  # noqa: E402

NUMBER = r"[+\-−]?\d[\d,]*(?:\.\d+)?"
UNIT = (  # a word unit after a space; ×, x or ° right after the number
    r"(?:\s(?:dB|it/s|ms|s|min|h|GB|MB|GiB|MiB|CPU[- ](?:s|seconds|minutes|hours))|\s?[×x°])"
)
FIGURE = re.compile(
    rf"(?<![\w.@/`~=-])~?(?P<num>{NUMBER})(?:\s?[–-]\s?(?P<upto>{NUMBER}))?(?P<unit>{UNIT})"  # ~25 s, 3–13 dB
    rf"(?![\w/]|×\s?\d|\s?×\s?\d)"
    rf"|(?<![\w.@/`~=(\[-])(?P<delta>[+−]\d+\.\d+)(?![\w.])"  # +1.85, −0.62: a Δ
)
SIZE = re.compile(r"\d\s?[×x]\s?\d")  # 128×96, 4 x 4: a size, not a speed-up
CODE = re.compile(r"`(?:[^`\n]|\n(?!\n))*`")  # inline code (within a paragraph): an option, a path, a message
COMMAND = re.compile(r"^\s*(?:\$ )?(?:python|snakemake|pip|bash|git|sbatch|mutmut|nice|PYTHONPATH)\b")
ARCHIVE = "docs/measurements"


def normal(num: str) -> str:
    """A number as compared: no sign, no thousands separators, − as -, trailing zeros kept."""
    return num.replace("−", "-").replace(",", "").lstrip("+-")


def numbers(text: str) -> set[str]:
    """Every number of ``text``, normalised."""
    return {normal(m) for m in re.findall(NUMBER, text)}


def block_numbers(text: str) -> set[str]:
    """The numbers of a document's generated blocks."""
    return set().union(*(numbers(m.group("body")) for m in BLOCK.finditer(text)))


def archived_numbers(readme: Path) -> set[str]:
    """The numbers of every archived file (docs/measurements)."""
    found: set[str] = set()
    for path in (readme.parent / ARCHIVE).rglob("*"):
        if path.is_file() and path.suffix in {".md", ".json", ".txt", ".csv"}:
            found |= numbers(path.read_text())
    return found


def prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) outside generated blocks and command lines, inline code spans emptied."""
    spans = [(m.start(), m.end()) for m in BLOCK.finditer(text)]
    kept, offset = [], 0
    for line in text.splitlines(keepends=True):
        inside = any(a <= offset < b for a, b in spans)
        offset += len(line)
        kept.append("\n" if inside or COMMAND.match(line) else line)
    prose = CODE.sub(lambda m: "``" + "\n" * m.group(0).count("\n"), "".join(kept))
    return [(i, line) for i, line in enumerate(prose.split("\n"), start=1) if line.strip()]


def figures(line: str) -> list[str]:
    """The measured figures of one line of prose."""
    found = []
    for m in FIGURE.finditer(line):
        unit = (m.group("unit") or "").strip()
        if unit in {"×", "x"} and SIZE.search(line[max(0, m.start() - 2) : m.end() + 3]):
            continue
        found.append(m.group(0).strip())
    return found


def unbacked(readme: Path) -> list[str]:
    """``document:line: figure`` of every measured figure no file backs."""
    archived = archived_numbers(readme)
    rows = []
    for doc in documents(readme):
        text = doc.read_text()
        backed = archived | block_numbers(text)
        for n, line in prose_lines(text):
            for fig in figures(line):
                if not {normal(n) for n in re.findall(NUMBER, fig.lstrip("~"))} <= backed:
                    rows.append(f"{doc.relative_to(readme.parent)}:{n}: {fig}")
    return rows


def main(argv: list[str]) -> int:
    readme = Path(argv[0]) if argv else Path("README.md")
    if not readme.is_file():
        raise SystemExit(f"{readme} does not exist: give the README's path")
    rows = unbacked(readme)
    print("\n".join(rows) if rows else "every measured figure is backed by a file")
    return 1 if rows else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

"""README.md and docs/*.md: a short README that starts with its commands, links that resolve, closed blocks."""

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = sorted((REPO / "docs").glob("*.md"))
PAGES = [README, *DOCS]
FENCE = re.compile(r"^```(\w*)\n(.*?)^```\n", re.M | re.S)
LINK = re.compile(r"(?<!\!)\[[^\]\n]*\]\(([^)\s]+)\)")
OPEN, CLOSE = re.compile(r"<!-- generated: [^ ]+ -->"), "<!-- /generated -->"


def page_id(path):
    return str(path.relative_to(REPO))


def test_the_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines: move a section to docs/"


def test_the_readme_starts_with_the_title_and_the_two_commands():
    text = README.read_text()
    title, _, rest = text.partition("\n")
    assert title.startswith("# spc3d")
    fences = FENCE.findall(rest)
    assert rest.lstrip("\n").startswith("```bash\n") and len(fences) >= 2
    (lang1, run), (lang2, test) = fences[:2]
    assert lang1 == lang2 == "bash"
    # The first two blocks follow each other directly after the title: install + run, install + test.
    assert rest.lstrip("\n").startswith(f"```bash\n{run}```\n```bash\n{test}```\n")
    assert run.startswith("pip install torch==") and run.rstrip().endswith("snakemake --cores 2")
    assert test.startswith("pip install torch==") and "python -m pytest" in test
    # The torch pin the README asks for is the one CI installs.
    pin = re.match(r"pip install (torch==\S+)", run).group(1)
    assert test.startswith(f"pip install {pin} ") and f"pip install -q {pin}\n" in (REPO / ".ci" / "run").read_text()


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_relative_links_point_to_files(page):
    text = FENCE.sub("", page.read_text())  # code blocks hold no links
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue  # a URL or an anchor in the same page
        path = target.partition("#")[0]
        if not (page.parent / path).exists():
            broken.append(target)
    assert not broken, f"{page_id(page)} links to missing files: {broken}"


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_generated_blocks_are_closed(page):
    depth = 0
    for number, line in enumerate(page.read_text().splitlines(), 1):
        if OPEN.fullmatch(line):
            assert depth == 0, f"{page_id(page)}:{number}: a generated block opens inside another"
            depth = 1
        elif line == CLOSE:
            assert depth == 1, f"{page_id(page)}:{number}: {CLOSE} without its opening marker"
            depth = 0
        else:
            assert "<!-- generated" not in line and "<!-- /generated" not in line, (
                f"{page_id(page)}:{number}: a marker must be a line of its own: {line!r}"
            )
    assert depth == 0, f"{page_id(page)}: the last generated block is not closed"


def test_every_docs_page_has_a_title_and_is_linked_from_the_readme():
    assert DOCS, "docs/ holds the README's long sections"
    readme = README.read_text()
    for doc in DOCS:
        first = doc.read_text().splitlines()[0]
        assert first.startswith("# "), f"{page_id(doc)} starts with a one-line '# ' title"
        assert f"](docs/{doc.name})" in readme, f"README.md does not link {page_id(doc)}"

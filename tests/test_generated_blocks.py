"""Generated blocks of the README and docs/ equal the archived files they were copied from.

A block ``<!-- generated: NAME:tables/x.md -->`` of a run archived in ``docs/measurements/NAME``
(workflow/tools/archive_run.py) must read exactly as that file does (first heading dropped), so a
figure edited by hand in a document, or a file archived again without refreshing the documents,
fails here. A block of a run that is not archived (results/ of a past run, outside git) fails too:
archive the run, or remove the block.
"""

from __future__ import annotations

import re

import pytest

from conftest import REPO, load_script

TOOL = load_script(REPO / "workflow" / "tools" / "readme_results.py")
ARCHIVE = REPO / "docs" / "measurements"
PROVENANCE = re.compile(r"\n*\*Copied by `workflow/tools/readme_results\.py` from .*\*\n*\Z")


def blocks() -> list[tuple[str, str, str]]:
    """(document, NAME:path, body) of every generated block."""
    return [
        (doc.name, m.group("path"), m.group("body"))
        for doc in TOOL.documents(REPO / "README.md")
        for m in TOOL.BLOCK.finditer(doc.read_text())
    ]


ARCHIVED = [b for b in blocks() if (ARCHIVE / b[1].rpartition(":")[0]).is_dir() and ":" in b[1]]


def test_every_block_has_an_archived_source():
    unkept = [f"{doc}: {ref}" for doc, ref, _ in blocks() if (doc, ref) not in {(d, r) for d, r, _ in ARCHIVED}]
    assert ARCHIVED and not unkept, f"blocks of runs not archived in docs/measurements/NAME: {unkept}"


@pytest.mark.parametrize("doc,ref,body", ARCHIVED, ids=[f"{d}:{r}" for d, r, _ in ARCHIVED])
def test_an_archived_runs_block_reads_as_its_file(doc, ref, body):
    run, _, rel = ref.rpartition(":")
    source = ARCHIVE / run / rel
    assert source.is_file(), f"{doc}: block {ref} names {source}, which is not archived"
    expected = re.sub(r"\A# .*\n+", "", source.read_text()).rstrip()
    assert PROVENANCE.sub("", body).rstrip() == expected, f"{doc}: block {ref} differs from {source}: refresh it"

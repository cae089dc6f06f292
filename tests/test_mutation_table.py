"""workflow/tools/mutation_table.py reads mutmut's caches and the equivalence judgements into the
table of docs/testing.md: counts per module, timeouts as killed, judged survivors apart."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from conftest import REPO, load_script

TOOL = load_script(REPO / "workflow" / "tools" / "mutation_table.py")


def make_cache(path, rows):
    """A mutmut 2 cache with (0-based line number, line text, index, status) rows of one file."""
    db = sqlite3.connect(path)
    db.executescript(
        "CREATE TABLE SourceFile (id INTEGER PRIMARY KEY, filename TEXT, hash TEXT);"
        "CREATE TABLE Line (id INTEGER PRIMARY KEY, sourcefile INTEGER, line TEXT, line_number INTEGER);"
        'CREATE TABLE Mutant (id INTEGER PRIMARY KEY, line INTEGER, "index" INTEGER, tested_against_hash TEXT,'
        " status TEXT);"
    )
    db.execute("INSERT INTO SourceFile VALUES (1, 'm.py', '')")
    lines = {}
    for n, text, index, status in rows:
        if n not in lines:
            lines[n] = len(lines) + 1
            db.execute("INSERT INTO Line VALUES (?, 1, ?, ?)", (lines[n], text, n))
        db.execute(
            'INSERT INTO Mutant (line, "index", tested_against_hash, status) VALUES (?, ?, "", ?)',
            (lines[n], index, status),
        )
    db.commit()
    db.close()


ROWS = [
    (0, "LN2 = 0.69", 0, "bad_survived"),
    (0, "LN2 = 0.69", 1, "ok_killed"),
    (4, "x = a + b", 0, "bad_timeout"),
    (4, "x = a + b", 1, "bad_survived"),
    (7, "return x", 0, "ok_suspicious"),
]


def test_counts_judgements_and_survivors(tmp_path, capsys):
    make_cache(tmp_path / "c", ROWS)
    (tmp_path / "eq.tsv").write_text("file\tline\tindex\tsource\twhy\nm.py\t1\t0\tLN2 = 0.69\tboth branches agree\n")
    args = [
        str(tmp_path / "out"),
        "--run",
        f"m={tmp_path / 'c'}:tests/test_m.py",
        "--equivalent",
        str(tmp_path / "eq.tsv"),
    ]
    assert TOOL.main([*args, "--commit", "abc1234"]) == 0
    text = (tmp_path / "out" / "tables" / "mutation.md").read_text()
    # 5 mutants: 3 killed (one timed out, one suspicious), 1 equivalent, 1 survivor: 3 of 4 = 75 %
    assert "| `m` | `test_m.py` | 5 | 3 | 1 | 1 | 0 | 75.0 % |" in text
    assert "- `m.py:1` #0 `LN2 = 0.69`: both branches agree" in text and "abc1234" in text
    assert TOOL.main([*args, "--survivors"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "m.py:5 1: x = a + b"


def test_a_stale_judgement_or_an_unfinished_run_is_an_error(tmp_path):
    make_cache(tmp_path / "c", ROWS)
    (tmp_path / "eq.tsv").write_text("file\tline\tindex\tsource\twhy\nm.py\t1\t0\tLN2 = 0.7\tmoved\n")
    run = ["--run", f"m={tmp_path / 'c'}:t.py"]
    with pytest.raises(SystemExit, match="now reads"):
        TOOL.main([str(tmp_path / "o"), *run, "--equivalent", str(tmp_path / "eq.tsv")])
    make_cache(tmp_path / "d", [*ROWS[:2], (9, "y = 1", 0, "untested")])
    with pytest.raises(SystemExit, match="untested"):
        TOOL.main([str(tmp_path / "o"), "--run", f"m={tmp_path / 'd'}:tests/t.py"])
    assert not (tmp_path / "o" / "tables" / "mutation.md").exists()
    assert TOOL.main([str(tmp_path / "o"), "--run", f"m={tmp_path / 'd'}:tests/t.py", "--partial"]) == 0
    assert "| `m` | `t.py` | 3 | 1 | 0 | 1 | 1 | 50.0 % |" in (tmp_path / "o" / "tables" / "mutation.md").read_text()


def test_a_module_run_in_parts_joins_its_caches(tmp_path):
    make_cache(tmp_path / "a", ROWS[:2])
    make_cache(tmp_path / "b", ROWS[2:])
    parts = [f"m={tmp_path / 'a'}:tests/test_m.py", f"m={tmp_path / 'b'}:tests/test_m.py"]
    assert TOOL.main([str(tmp_path / "o"), "--run", parts[0], "--run", parts[1]]) == 0
    text = (tmp_path / "o" / "tables" / "mutation.md").read_text()
    assert "| `m` | `test_m.py` | 5 | 3 | 0 | 2 | 0 | 60.0 % |" in text


def test_a_runner_names_its_files_and_what_it_deselects():
    runner = ",".join(["tests/test_f.py", "--deselect", "tests/test_f.py::a", "--deselect", "tests/test_f.py::b"])
    runner += ",tests/test_g.py"
    assert TOOL.runner_files(runner) == "`test_f.py`, `test_g.py` (less 2 deselected)"


def test_a_cache_shared_by_two_modules_is_read_for_one_file(tmp_path):
    make_cache(tmp_path / "c", ROWS)
    assert len(TOOL.read_cache(tmp_path / "c", "m.py")) == 5 and TOOL.read_cache(tmp_path / "c", "other.py") == []
    assert TOOL.parse_run("m=c#w/m.py:tests/t.py") == ("m", Path("c"), "w/m.py", "tests/t.py")

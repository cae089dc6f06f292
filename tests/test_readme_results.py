"""workflow/tools/readme_results.py: README blocks refreshed from generated files of one or more runs."""

import runpy
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "workflow" / "tools" / "readme_results.py"


def run_tool(*args):
    argv, sys.argv = sys.argv, [str(TOOL), *map(str, args)]
    try:
        with pytest.raises(SystemExit) as stop:
            runpy.run_path(str(TOOL), run_name="__main__")
    finally:
        sys.argv = argv
    return stop.value.code


def test_blocks_come_from_the_named_runs(tmp_path):
    for run, text in (("default", "| a | 1 |"), ("findings", "| b | 2 |")):
        (tmp_path / run / "tables").mkdir(parents=True)
        (tmp_path / run / "tables" / "t.md").write_text(f"# Title\n\n{text}\n")
    readme = tmp_path / "README.md"
    readme.write_text(
        "intro\n<!-- generated: tables/t.md -->\nold\n<!-- /generated -->\n"
        "mid\n<!-- generated: findings:tables/t.md -->\nold\n<!-- /generated -->\nend\n"
    )
    assert run_tool(tmp_path / "default", readme, "--run", f"findings={tmp_path / 'findings'}") == 0
    text = readme.read_text()
    assert "| a | 1 |" in text and "| b | 2 |" in text and "old" not in text and "# Title" not in text
    assert "from the findings run's `results/tables/t.md`" in text and text.endswith("end\n")


def test_a_missing_run_or_file_is_named(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("<!-- generated: findings:tables/t.md -->\n<!-- /generated -->\n")
    with pytest.raises(SystemExit, match="--run findings=DIR"):
        runpy.run_path(str(TOOL), run_name="not_main")["main"]([str(tmp_path), str(readme)])
    readme.write_text("<!-- generated: tables/t.md -->\n<!-- /generated -->\n")
    with pytest.raises(SystemExit, match="t.md does not exist"):
        runpy.run_path(str(TOOL), run_name="not_main")["main"]([str(tmp_path), str(readme)])
    assert run_tool(tmp_path, readme, "--run", "broken") == 2  # malformed: the usage


def test_blocks_in_docs_files_are_replaced(tmp_path):
    (tmp_path / "res" / "tables").mkdir(parents=True)
    (tmp_path / "res" / "tables" / "t.md").write_text("# Title\n\n| a | 1 |\n")
    (tmp_path / "fnd" / "tables").mkdir(parents=True)
    (tmp_path / "fnd" / "tables" / "t.md").write_text("# Title\n\n| b | 2 |\n")
    readme = tmp_path / "README.md"
    readme.write_text("no blocks here\n")
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "results.md").write_text(
        "# Results\n\n<!-- generated: tables/t.md -->\nold\n<!-- /generated -->\n"
        "<!-- generated: findings:tables/t.md -->\nold\n<!-- /generated -->\n"
    )
    (docs / "plain.md").write_text("# Plain\n")
    assert run_tool(tmp_path / "res", readme, "--run", f"findings={tmp_path / 'fnd'}") == 0
    text = (docs / "results.md").read_text()
    assert "| a | 1 |" in text and "| b | 2 |" in text and "old" not in text and "# Title" not in text
    assert "from `results/tables/t.md`" in text and "from the findings run's `results/tables/t.md`" in text
    assert readme.read_text() == "no blocks here\n" and (docs / "plain.md").read_text() == "# Plain\n"
    assert not list(tmp_path.rglob(".*.tmp"))


def test_a_missing_run_in_a_docs_file_names_that_file(tmp_path):
    (tmp_path / "tables").mkdir()
    (tmp_path / "tables" / "t.md").write_text("| a | 1 |\n")
    readme = tmp_path / "README.md"
    readme.write_text("<!-- generated: tables/t.md -->\nold\n<!-- /generated -->\n")
    (tmp_path / "docs").mkdir()
    doc = tmp_path / "docs" / "results.md"
    doc.write_text("<!-- generated: findings:tables/t.md -->\n<!-- /generated -->\n")
    main = runpy.run_path(str(TOOL), run_name="not_main")["main"]
    with pytest.raises(SystemExit, match=r"docs/results\.md.*--run findings=DIR"):
        main([str(tmp_path), str(readme)])
    doc.write_text("<!-- generated: tables/gone.md -->\n<!-- /generated -->\n")
    with pytest.raises(SystemExit, match=r"gone\.md does not exist.*docs/results\.md"):
        main([str(tmp_path), str(readme)])
    assert "old" in readme.read_text()  # an error in one document leaves every document as it was


def test_a_kept_run_leaves_its_blocks_as_they_are(tmp_path):
    (tmp_path / "res" / "tables").mkdir(parents=True)
    (tmp_path / "res" / "tables" / "t.md").write_text("# Title\n\n| new | 1 |\n")
    readme = tmp_path / "README.md"
    kept = "<!-- generated: trade:tables/t.md -->\n| old | 0 |\n\n*Copied ... (2026-01-01).*\n<!-- /generated -->\n"
    readme.write_text("<!-- generated: tables/t.md -->\nold\n<!-- /generated -->\n" + kept)
    assert run_tool(tmp_path / "res", readme, "--keep", "trade") == 0
    text = readme.read_text()
    assert "| new | 1 |" in text and text.endswith(kept)  # the kept run's block is untouched
    assert run_tool(tmp_path / "res", readme, "--keep") == 2  # --keep without a name: the usage


def test_one_run_alone_refreshes_its_blocks_and_keeps_every_other(tmp_path):
    """refresh_run (a benchmark writing its own tables): only the named run's blocks change, in the
    README and docs/; the default run's and other runs' blocks stay as they are."""
    (tmp_path / "spad" / "tables").mkdir(parents=True)
    (tmp_path / "spad" / "tables" / "t.md").write_text("# Title\n\n| new | 1 |\n")
    (tmp_path / "docs").mkdir()
    others = "<!-- generated: tables/t.md -->\nold default\n<!-- /generated -->\n"
    others += "<!-- generated: real:tables/t.md -->\nold real\n<!-- /generated -->\n"
    readme, doc = tmp_path / "README.md", tmp_path / "docs" / "a.md"
    readme.write_text(others)
    doc.write_text("intro\n<!-- generated: spad:tables/t.md -->\nold\n<!-- /generated -->\n" + others)
    counts = runpy.run_path(str(TOOL), run_name="not_main")["refresh_run"](readme, "spad", tmp_path / "spad")
    assert counts == {readme: 0, doc: 1} and readme.read_text() == others
    text = doc.read_text()
    assert "| new | 1 |" in text and "\nold\n" not in text and text.endswith(others)

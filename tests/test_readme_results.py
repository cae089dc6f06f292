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

"""Measured figures in the README and docs/ come from files: workflow/tools/doc_figures.py finds the rest.

A figure typed from a terminal (a time, a PSNR, a Δ) cannot be checked; one in a generated block,
or quoting a number of its document's blocks or of an archived run (docs/measurements), can.
"""

from __future__ import annotations

from conftest import REPO, load_script

TOOL = load_script(REPO / "workflow" / "tools" / "doc_figures.py")


def write_docs(tmp_path, readme: str, doc: str = "") -> None:
    (tmp_path / "docs" / "measurements" / "run" / "tables").mkdir(parents=True)
    (tmp_path / "docs" / "measurements" / "run" / "tables" / "t.md").write_text("| row | 21.47 |\n")
    (tmp_path / "README.md").write_text(readme)
    (tmp_path / "docs" / "a.md").write_text(doc)


def test_typed_figures_are_found_and_settings_are_not(tmp_path):
    write_docs(
        tmp_path,
        "The fit took 12.5 s and gained +0.73 over the prior, 3.1× faster.\n"
        "Scenes at 128×96, 4 x 4 tiles, every 10 %, 1,200 iterations, `--steps 3000`, `took 9 s`.\n"
        "python benchmarks/x.py --min-seconds 2.5 s\n"
        "RTX 3090s and the rasterizer at 150.0 it/s.\n",
    )
    rows = TOOL.unbacked(tmp_path / "README.md")
    assert rows == ["README.md:1: 12.5 s", "README.md:1: +0.73", "README.md:1: 3.1×", "README.md:4: 150.0 it/s"]


def test_figures_in_blocks_or_quoting_a_file_are_backed(tmp_path):
    block = "<!-- generated: run:tables/t.md -->\n| a | 30.25 dB | +1.85 |\n<!-- /generated -->\n"
    write_docs(
        tmp_path,
        block + "So the row gains +1.85 and reaches 30.25 dB; the archive says 21.47 dB.\n",
        "A figure of the README's block is not this document's: 30.25 dB. The archive's is: 21.47 dB.\n",
    )
    assert TOOL.unbacked(tmp_path / "README.md") == ["docs/a.md:1: 30.25 dB"]


def test_approximate_figures_ranges_and_degrees_are_figures_but_sweep_paths_are_not(tmp_path):
    write_docs(
        tmp_path,
        "a fit takes ~25 s; rows lose 3–13 dB and 1.5-2.7°; 17 CPU-minutes; sweeps/iters~300 s; 21.47–22.5 dB\n",
    )
    rows = TOOL.unbacked(tmp_path / "README.md")
    assert rows == [
        "README.md:1: ~25 s",
        "README.md:1: 3–13 dB",
        "README.md:1: 1.5-2.7°",
        "README.md:1: 17 CPU-minutes",
        "README.md:1: 21.47–22.5 dB",  # a range is backed only when both ends are
    ]


def test_inline_code_across_lines_and_command_lines_are_not_prose(tmp_path):
    write_docs(tmp_path, "an error (`rule x: more memory\nthan any node has (24105 MB)`) and 2.0 dB\n")
    assert TOOL.unbacked(tmp_path / "README.md") == ["README.md:2: 2.0 dB"]


def test_the_repositorys_readme_and_docs_type_no_measured_figure():
    rows = TOOL.unbacked(REPO / "README.md")
    assert not rows, "measured figures no file backs (quote a generated block or an archived file):\n" + "\n".join(rows)

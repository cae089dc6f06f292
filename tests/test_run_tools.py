"""The tools that turn a finished run's files into the docs' tables: fold choices, the run record,
the archive (workflow/tools/fold_choices.py, run_record.py, archive_run.py), on hand-made files."""

from __future__ import annotations

import json
import subprocess

import pytest

from conftest import REPO, load_script

TOOLS = REPO / "workflow" / "tools"


def write_json(path, obj):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def fold(results, left_out, held, step, weight):
    write_json(
        results / f"choices-without-{left_out}" / "joint-prior+3dgs.json",
        {
            "row": "joint-prior+3dgs",
            "chosen": {"weight": weight},
            "scenes": [held],
            "mean_psnr": {"0.1": 20.0, "1.0": 21.5},
        },
    )
    train = {"model_step": step, "stopped": {"step": step + 100, "of": 1000, "reason": "patience"}}
    write_json(results / f"models-without-{left_out}" / "pix2pix" / "train.json", train)
    write_json(
        results / f"models-without-{left_out}" / "classical" / "train.json",
        {"selection": {"chosen": "tv(weight=0.75)"}},
    )
    write_json(results / f"calibration-without-{left_out}" / "display-k1.json", {"K": 1, "level": 0.5 + step / 1e4})


def test_fold_choices_lists_every_folds_choices(tmp_path):
    tool = load_script(TOOLS / "fold_choices.py")
    fold(tmp_path, "fern", "trex", 300, 1.0)
    fold(tmp_path, "trex", "ollie", 450, 0.3)
    text = tool.fold_choices(tmp_path)
    assert "| fern | trex | tv(weight=0.75) | 0.530 (1) |" in text
    assert "| trex | 450 of 1000 (patience) |" in text
    assert "| trex | joint-prior+3dgs | 0.3 | 0.1: 20.00, 1.0: 21.50 |" in text
    with pytest.raises(SystemExit, match="no fold folders"):
        tool.main([str(tmp_path / "prior")])


TIME_V = """3 of 3 steps (100%) done
\tCommand being timed: "snakemake --cores 2"
\tUser time (seconds): 6000.50
\tSystem time (seconds): 99.50
\tElapsed (wall clock) time (h:mm:ss or m:ss): 1:02:03
\tMaximum resident set size (kbytes): 2097152
\tExit status: 0
"""


def test_run_record_reads_the_logs_time_the_jobs_cpu_and_the_reference(tmp_path):
    tool = load_script(TOOLS / "run_record.py")
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "f").write_text("x")
    git = ["git", "-C", str(tmp_path), "-c", "user.email=a@b", "-c", "user.name=a"]
    subprocess.run([*git, "add", "f"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "x"], check=True)
    for rule, cpu in (("train_translator", "700\t20"), ("reconstruct", "250\t30")):
        tsv = tmp_path / "benchmarks" / rule / "a.tsv"
        tsv.parent.mkdir(parents=True)
        tsv.write_text(f"user_s\tsys_s\n{cpu}\n")
    (tmp_path / "log").write_text("Building DAG\n" + TIME_V)
    (tmp_path / "raster").write_text("     10000 128x96     187.9          81.3       7.37    25.5x\n")
    text = tool.record(tmp_path, tmp_path / "log", tmp_path / "raster", None, "snakemake --cores 2")
    assert "exit 0, 3 of 3 jobs done" in text
    assert "| 1 h 02 min 03 s | 6,100 s | 2,048 MiB | 1,000 s | 187.9 |" in text
    assert text.index("| train_translator | 1 | 720 |") < text.index("| reconstruct | 1 | 280 |")
    (tmp_path / "log").write_text("no report")
    with pytest.raises(SystemExit, match="no `time -v` report"):
        tool.record(tmp_path, tmp_path / "log", tmp_path / "raster", None, "x")


def test_archive_keeps_a_runs_tables_and_refuses_a_missing_one(tmp_path, monkeypatch):
    tool = load_script(TOOLS / "archive_run.py")
    monkeypatch.setattr(tool, "ARCHIVE", tmp_path / "measurements")
    tables = tmp_path / "results" / "tables"
    tables.mkdir(parents=True)
    (tables / "findings.md").write_text("# F\n| a |\n")
    (tables / "findings.json").write_text("{}")
    kept = tool.archive(tmp_path / "results", "real", ["findings.json"])
    assert sorted(p.name for p in kept) == ["findings.json", "findings.md"]
    assert (tmp_path / "measurements" / "real" / "tables" / "findings.md").read_text() == "# F\n| a |\n"
    with pytest.raises(SystemExit, match="missing"):
        tool.archive(tmp_path / "results", "real", ["absent.json"])
    assert (tmp_path / "measurements" / "real" / "tables" / "findings.json").is_file()  # nothing lost


def test_archiving_a_run_refreshes_its_blocks_and_leaves_the_others(tmp_path, monkeypatch):
    tool = load_script(TOOLS / "archive_run.py")
    monkeypatch.setattr(tool, "ARCHIVE", tmp_path / "docs" / "measurements")
    (tmp_path / "docs").mkdir()
    readme = tmp_path / "README.md"
    other = "<!-- generated: real:tables/x.md -->\nkept as it is\n<!-- /generated -->\n"
    readme.write_text("<!-- generated: default:tables/t.md -->\nold\n<!-- /generated -->\n" + other)
    (tmp_path / "results" / "tables").mkdir(parents=True)
    (tmp_path / "results" / "tables" / "t.md").write_text("# T\n\n| new |\n")
    assert tool.main([str(tmp_path / "results"), "default"]) == 0
    text = readme.read_text()
    assert "| new |" in text and "old" not in text and other in text
    assert "`docs/measurements/default/tables/t.md`" in text  # the provenance names the archived file

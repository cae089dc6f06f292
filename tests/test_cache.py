"""Trained once, reused: Snakemake's between-workflow cache for translators, and the code in its key."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from spc3d import provenance, specs
from spc3d.jobs import translator_checkpoint

from conftest import SMOKE, run_snakemake


def _package(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / "spc3d" / name).parent.mkdir(parents=True, exist_ok=True)
        (root / "spc3d" / name).write_text(text)
    return root / "spc3d"


@pytest.fixture
def fake_package(tmp_path, monkeypatch):
    """spc3d as a tiny package: a script imports ``a``, which imports ``sub.b`` inside a function
    (relatively) and nothing of ``c``."""
    pkg = _package(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "def f():\n    from .sub import b\n    return b\n",
            "sub/__init__.py": "",
            "sub/b.py": "X = 1\n",
            "c.py": "Y = 2\n",
        },
    )
    monkeypatch.setattr(provenance, "ROOT", pkg)
    script = tmp_path / "script.py"
    script.write_text("from spc3d import a\n")
    return pkg, script


def test_the_closure_follows_imports_inside_functions_and_skips_the_rest(fake_package):
    pkg, script = fake_package
    names = {provenance.module_name(p) or p.name for p in provenance.closure([script])}
    assert names == {"script.py", "spc3d", "spc3d.a", "spc3d.sub", "spc3d.sub.b"}


def test_the_digest_changes_with_the_code_the_job_reaches_and_only_that(fake_package):
    pkg, script = fake_package
    before = provenance.closure_digest([script])
    (pkg / "c.py").write_text("Y = 3\n")  # not imported: tables, figures
    assert provenance.closure_digest([script]) == before
    (pkg / "sub" / "b.py").write_text("X = 2\n")  # imported lazily by a: a loss, a layer
    assert provenance.closure_digest([script]) != before


def test_comments_docstrings_and_formatting_are_not_code(fake_package):
    pkg, script = fake_package
    (pkg / "sub" / "b.py").write_text('"""The loss."""\n\nclass L:\n    """A loss."""\n\n    w: float = 0.1\n')
    before = provenance.closure_digest([script])
    edited = '"""The loss, reworded."""\n# a comment\nclass L:\n    """Another docstring."""\n'
    edited += '    w : float=0.1  # why\n    """w\'s doc."""\n'
    (pkg / "sub" / "b.py").write_text(edited)
    assert provenance.closure_digest([script]) == before
    (pkg / "sub" / "b.py").write_text(edited.replace("0.1", "0.2"))  # a constant: what runs
    assert provenance.closure_digest([script]) != before


def test_a_files_analysis_is_kept_for_the_next_process_and_only_for_its_bytes(fake_package, tmp_path, monkeypatch):
    """A kept analysis is read back by the next process (here: the in-process cache cleared), for the
    same bytes only; an unreadable entry is made again, and ``off`` keeps nothing."""
    pkg, script = fake_package
    kept = tmp_path / "kept"
    monkeypatch.setenv("SPC3D_CODE_CACHE", str(kept))
    provenance._analysis.cache_clear()
    b = pkg / "sub" / "b.py"
    digest = provenance.source_digest(b)
    entries = sorted(kept.glob("*.json"))
    assert len(entries) == 1 and not list(kept.glob("*.tmp"))
    entry = entries[0]
    assert json.loads(entry.read_text()) == {"digest": digest, "names": []}
    entry.write_text(json.dumps({"digest": "planted", "names": ["spc3d.c"]}))  # what a next process reads
    provenance._analysis.cache_clear()
    assert provenance.source_digest(b) == "planted" and provenance.imported_names(b) == {"spc3d.c"}
    b.write_text("X = 2\n")  # other bytes: the planted entry is never read for them
    provenance._analysis.cache_clear()
    assert provenance.source_digest(b) not in ("planted", digest) and provenance.imported_names(b) == set()
    entry.write_text("{not json")
    b.write_text("X = 1\n")
    provenance._analysis.cache_clear()
    assert provenance.source_digest(b) == digest and json.loads(entry.read_text())["digest"] == digest
    monkeypatch.setenv("SPC3D_CODE_CACHE", "off")
    provenance._analysis.cache_clear()
    (pkg / "c.py").write_text("Y = 3\n")
    before = len(list(kept.glob("*.json")))
    assert provenance.source_digest(pkg / "c.py") and len(list(kept.glob("*.json"))) == before
    monkeypatch.setenv("SPC3D_CODE_CACHE", str(entry))  # a file, not a folder: nothing kept, no error
    provenance._analysis.cache_clear()
    assert provenance.source_digest(pkg / "c.py") == provenance.source_digest(pkg / "c.py")
    provenance._analysis.cache_clear()


def test_the_real_training_closure_has_the_training_code_and_not_the_tables():
    scripts = Path(__file__).resolve().parents[1] / "workflow" / "scripts"
    files = provenance.closure([scripts / "train_translator.py", provenance.entry_file("spc3d.translate.pix2pix")])
    names = {provenance.module_name(p) for p in files}
    assert {"spc3d.translate.train", "spc3d.translate.pix2pix", "spc3d.translate.networks"} <= names
    assert "spc3d.evaluation.tables" not in names and "spc3d.translate.restormer" not in names
    # its settings, from its own file: another model's defaults are not part of its key
    specs = {name for name in names if name and name.startswith("spc3d.specs.translators")}
    assert specs == {"spc3d.specs.translators", "spc3d.specs.translators.pix2pix"}


@pytest.mark.parametrize(
    ("model", "own", "other"),
    [("3dgs", {"spc3d.reconstruct.splatting", "spc3d.reconstruct.splat.native"}, "spc3d.reconstruct.nerf_trainer")]
    + [
        (m, {"spc3d.reconstruct.nerf_trainer", "spc3d.reconstruct.volume"}, "spc3d.reconstruct.splatting")
        for m in ("nerf-mlp", "nerf-grid")
    ],
)
def test_a_fits_closure_has_its_own_models_code_and_not_the_others(model, own, other):
    # the key of rule reconstruct: its script and its model's factory module (Grid.reconstruct_code)
    scripts = Path(__file__).resolve().parents[1] / "workflow" / "scripts"
    factory = specs.RECONSTRUCTORS[model].factory.rpartition(":")[0]
    names = {
        provenance.module_name(p)
        for p in provenance.closure([scripts / "reconstruct.py", provenance.entry_file(factory)])
    }
    assert {"spc3d.reconstruct.stage2", "spc3d.reconstruct.objectives", *own} <= names
    assert other not in names and "spc3d.evaluation.tables" not in names


def test_a_translator_checkpoints_beside_its_models_folder():
    path = translator_checkpoint("results/sweeps/p1/models-cfa-without-fern/pix2pix-1")
    assert path == Path("results/sweeps/p1/checkpoints/models-cfa-without-fern/pix2pix-1/checkpoint.pt")
    assert translator_checkpoint("results/models/prior") == Path("results/checkpoints/models/prior/checkpoint.pt")


@pytest.mark.slow
def test_the_default_cache_folder_is_made_when_the_workflow_is_read(tmp_path):
    # Snakemake's --cache refuses a folder that does not exist (a fresh machine's ~/.cache/spc3d/outputs).
    home = tmp_path / "home"
    args = ["-n", "--cores", "1", "--configfile", str(SMOKE), "--cache", "--", "results/models/pix2pix"]
    done = run_snakemake(tmp_path / "w", *args, env={"HOME": str(home)}, unset=("SNAKEMAKE_OUTPUT_CACHE",))
    assert done.returncode == 0, done.stderr[-3000:]
    assert (home / ".cache" / "spc3d" / "outputs").is_dir()


def test_a_second_workflow_directory_trains_nothing_and_a_changed_setting_retrains(tmp_path, lpips_cache):
    store = tmp_path / "store"
    store.mkdir()
    local = tmp_path / "local.yaml"
    local.write_text(yaml.safe_dump({"metrics": {"lpips_source": str(lpips_cache)}}))
    env = {"SNAKEMAKE_OUTPUT_CACHE": str(store)}

    def train(work, *extra):
        args = ["--cores", "2", "--configfile", str(SMOKE), str(local), *extra, "--cache", "--"]
        done = run_snakemake(tmp_path / work, *args, "results/models/pix2pix", env=env)
        assert done.returncode == 0, done.stderr[-3000:]
        return tmp_path / work / "results" / "models" / "pix2pix", done.stderr

    first, log = train("w1")  # trained, then moved into the cache and linked back
    assert "Moving output file results/models/pix2pix to cache" in log
    entries = sorted(store.iterdir())
    assert len(entries) == 1 and first.resolve() == entries[0].resolve()  # stored under its provenance hash

    second, log = train("w2")  # same settings, another directory: fetched, not trained
    assert "Symlinking output file results/models/pix2pix/model.pt from cache" in log and "to cache" not in log
    assert "pix2pix: " not in log  # no training's progress bar
    assert (second / "model.pt").resolve() == (entries[0] / "model.pt").resolve()
    assert not (tmp_path / "w2" / "results" / "checkpoints").exists()  # no training ran there

    third, log = train("w3", "--config", "seed=1")  # another seed: other weights, trained anew
    assert "Moving output file results/models/pix2pix to cache" in log
    assert len(list(store.iterdir())) == 2 and third.resolve() != entries[0].resolve()


def copy_workflow(dest: Path) -> Path:
    """The workflow's files (Snakefile, config.yaml, workflow/, envs/) in ``dest``, to edit there."""
    import shutil

    repo = Path(__file__).resolve().parents[1]
    dest.mkdir()
    for name in ("Snakefile", "config.yaml"):
        shutil.copy2(repo / name, dest / name)
    for name in ("workflow", "envs"):
        shutil.copytree(repo / name, dest / name, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


@pytest.mark.slow
def test_a_docstring_reruns_no_fit_and_a_loss_constant_reruns_the_fits(tmp_path, lpips_cache):
    """The stage-2 fits' code key (rule reconstruct's ``code`` param) on a real run: a fit done, its
    objectives' docstring edited (nothing to do), then a constant of the likelihood (the fit reruns)."""
    import subprocess
    import sys

    repo = copy_workflow(tmp_path / "repo")
    work, target = tmp_path / "work", "results/recon/courtyard/bernoulli+3dgs"
    local = tmp_path / "local.yaml"
    local.write_text(yaml.safe_dump({"metrics": {"lpips_source": str(lpips_cache)}}))

    def snakemake(*args):
        cmd = [sys.executable, "-m", "snakemake", "-s", str(repo / "Snakefile"), "--directory", str(work)]
        cmd += ["--cores", "2", "--configfile", str(SMOKE), str(local), *args, "--", target]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout + done.stderr

    snakemake()
    objectives = repo / "workflow" / "spc3d" / "reconstruct" / "objectives.py"
    text = objectives.read_text()
    objectives.write_text(text.replace('"""SPAD likelihood of the binary frames;', '"""The likelihood of the bits;'))
    assert objectives.read_text() != text
    assert "Nothing to be done" in snakemake("-n")
    objectives.write_text(text.replace("clamp_min(1e-12)", "clamp_min(1e-11)"))
    plan = snakemake("-n")
    assert re.search(r"^reconstruct\s+1$", plan, re.M) and "Params have changed" in plan, plan[-3000:]

"""Bad input, table-driven: each case is a config change, a damaged scene or a broken environment.

For every case the real command (`snakemake TARGET --cores 1 --configfile smoke.yaml case.yaml`)
must exit non-zero with a short message naming the key or file, the value and what would be
right; fail at the earliest stage that has the information (``parse``: before Snakemake builds
its DAG, so no job starts; else the named rule); leave nothing a rerun would trust (no result of
the failing stage, no temporary folder); and a corrected run in the same folder must succeed.
"""

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml

from spc3d import io
from spc3d.config import read_yaml, resolve_paths
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.names import ConfigError

from conftest import REPO, run_snakemake

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
MAX_LINES = 14  # a message, not a schema dump (Snakemake adds a few lines of traceback)


@dataclass
class Case:
    id: str
    match: str  # regex the message must contain (in the output, or the failing job's log)
    config: dict = field(default_factory=dict)  # merged over the smoke preset
    stage: str = "parse"  # "parse", or the rule that fails
    scene: object = None  # damages the tiny LLFF scene "mini" (a function of its folder), which is then evaluated
    files: dict = field(default_factory=dict)  # file name in the work folder -> bytes (the config may name it)
    forbid: str | None = None  # regex the message must not contain


def _poses(fn):
    def damage(folder):
        pb = np.load(folder / "poses_bounds.npy")
        fn(pb)
        np.save(folder / "poses_bounds.npy", pb)

    return damage


def _image(fn):
    def damage(folder):
        fn(sorted((folder / "images").glob("*.png"))[2])

    return damage


def _npz_as_npy(folder):
    pb = np.load(folder / "poses_bounds.npy")
    with open(folder / "poses_bounds.npy", "wb") as f:
        np.savez(f, poses=pb)


def _gray(path):
    io.write_image(path, io.read_rgb(path)[:, :, :1])


def _resize(path):
    io.write_image(path, np.zeros((20, 30, 3), np.float32))


def _truncate(path):
    path.write_bytes(path.read_bytes()[:200])


class Evil:
    def __reduce__(self):
        return (print, ("code from a weight file ran",))


CASES = [
    # --- config keys: schema -------------------------------------------------------------------
    Case("unknown-top-level-key", r"sedd: unknown key; did you mean 'seed'", {"sedd": 1}),
    Case("misspelled-nested-key", r"spc\.frame: unknown key; did you mean 'frames'", {"spc": {"frame": 4}}),
    Case("wrong-type", r"resolution\.width = 'big': expected integer", {"resolution": {"width": "big"}}),
    # --- ranges and order, one rule for every numeric setting (spc3d.specs.build.check_range) ---------
    Case("negative-learning-rate", r"\.lr = -0\.001: must be > 0", {"stage1": {"pix2pixhd": {"lr": -0.001}}}),
    Case(
        "empty-densification-window",
        r"densify_from = 30, densify_until = 20: densification would never run",
        {"stage2": {"3dgs": {"densify_from": 30, "densify_until": 20}}},
    ),
    Case(
        "gaussian-cap-below-the-initial-points",
        r"max_gaussians = 100 is below init_points = 500",
        {"stage2": {"3dgs": {"max_gaussians": 100}}},
    ),
    Case(
        "grid-schedule-out-of-order",
        r"res_schedule = \[\[0, 16\], \[30, 32\], \[20, 24\]\]: list the entries by increasing iteration",
        {"stage2": {"nerf-grid": {"res_schedule": [[0, 16], [30, 32], [20, 24]]}}},
    ),
    Case(
        "dark-counts-above-the-target-detection",
        r"spc\.target_detection = 0\.5: dark counts alone fire 0\.6321 of the bits.*lower spc\.dark_count_rate",
        {"spc": {"dark_count_rate": 1.0e4}},
    ),
    Case(
        "last-repeat-seed-above-2-to-the-32",
        r"the last run's seed 4294967296 is above 4294967295 .*lower seed to at most 4294967294",
        {"seed": 2**32 - 1, "seeds": 2},
    ),
    Case(
        "capture-override-with-a-bad-key",
        r"captures\.mycap\.qq: unknown key; did you mean 'q'\?",
        {"captures": {"mycap": {"path": "WORK/cap", "qq": 0.5}}},
    ),
    Case(
        "float-where-an-integer-belongs",
        r"stage1\.train\.iterations = 64\.0: expected integer \(write 64\)",
        {"stage1": {"train": {"iterations": 64.0}}},
    ),
    Case(
        "number-yaml-reads-as-text",
        r"spc\.q = '1\.0e-3': expected number \(YAML reads 1\.0e-3 as text: write 0\.001\)",
        {"spc": {"q": "1.0e-3"}},
    ),
    Case("out-of-range", r"spc\.q = 1\.5: must be <= 1", {"spc": {"q": 1.5}}),
    Case("not-an-option", r"spc\.mode = 'poisson': use one of \['bernoulli', 'paper'\]", {"spc": {"mode": "poisson"}}),
    Case("impossible-exposure", r"spc\.exposure_s = -0\.001: must be > 0", {"spc": {"exposure_s": -1e-3}}),
    Case("checkpoint-rhythm", r"checkpoints\.fraction = 2: must be <= 1", {"checkpoints": {"fraction": 2}}),
    Case("no-eval-scene", r"scenes\.eval = \[\]: needs at least 1 item", {"scenes": {"eval": []}}),
    Case(
        "bad-combination",
        r"stage2\.combinations\.0 = 'pix2pixhd': a row is 'source\+model' and has no '\+' here "
        r"\(e\.g\. 'pix2pixhd\+3dgs'",
        {"stage2": {"combinations": ["pix2pixhd"]}},
    ),
    Case(
        "3dgs-zero-iterations", r"stage2\.3dgs\.iterations = 0: must be >= 1", {"stage2": {"3dgs": {"iterations": 0}}}
    ),
    Case(
        "grid-zero-iterations",
        r"stage2\.nerf-grid\.n_iters = 0: must be >= 1",
        {"stage2": {"nerf-grid": {"n_iters": 0}}},
    ),
    Case(
        "iterations-not-a-number",
        r"stage2\.3dgs\.iterations = 'abc': expected integer",
        {"stage2": {"3dgs": {"iterations": "abc"}}},
    ),
    # --- config keys: values checked against each other and against the models ------------------
    Case("unknown-source", r"unknown source 'magic'", {"stage2": {"combinations": ["magic+3dgs"]}}),
    Case("unknown-scene", r"scenes\.eval: unknown scene 'mars'; use a built-in layout", {"scenes": {"eval": ["mars"]}}),
    Case(
        "train-eval-overlap",
        r"share \['courtyard'\]: evaluation scenes must be held out",
        {"scenes": {"train": ["courtyard"], "eval": ["courtyard"]}},
    ),
    Case(
        "missing-llff-folder",
        r"llff_scenes\.gone: the folder /nonexistent/gone does not exist",
        {"llff_scenes": {"gone": "/nonexistent/gone"}, "scenes": {"eval": ["gone"]}},
    ),
    Case(
        "3dgs-typo",
        r"stage2\.3dgs: unknown setting\(s\) \['iteratons'\]; did you mean 'iterations'",
        {"stage2": {"3dgs": {"iteratons": 5}}},
    ),
    Case(
        "3dgs-float-count",
        r"stage2\.3dgs\.init_points = 1\.5: expected int",
        {"stage2": {"3dgs": {"init_points": 1.5}}},
    ),
    Case(
        "translator-typo",
        r"stage1\.pix2pixhd: unknown setting\(s\) \['ngff'\]; did you mean 'ngf'",
        {"stage1": {"pix2pixhd": {"ngff": 8}}},
    ),
    Case(
        "untrained-translator",
        r"stage1\.train\.iterations = 0 for pix2pixhd: an untrained network is not a result",
        {"stage1": {"train": {"iterations": 0}}},
    ),
    Case("more-frames-than-simulated", r"stage1\.frames = 8: more than the spc\.frames = 4", {"stage1": {"frames": 8}}),
    Case(
        "no-training-pairs",
        r"augment\.count = 0: the translators .* need at least one augmented pair",
        {"augment": {"count": 0}, "stage1": {"data": "fixed"}},
    ),
    Case(
        "stage1-data-mode", r"stage1\.data = 'onlin': use one of \['fixed', 'online'\]", {"stage1": {"data": "onlin"}}
    ),
    Case(
        "validation-typo",
        r"stage1\.diffusion\.validation: unknown setting\(s\) \['evry'\]; did you mean 'every'",
        {"stage1": {"diffusion": {"validation": {"evry": 50}}}},
    ),
    Case("stage1-without-train-scenes", r"scenes\.train is empty", {"scenes": {"train": []}}),
    Case(
        "paper-mode-physics-rows",
        r"spc\.mode = 'paper': the rows \['bernoulli\+3dgs', 'mle\+3dgs'\] invert the "
        r"exact Bernoulli model",
        {"spc": {"mode": "paper"}, "stage2": {"combinations": ["gt+3dgs", "mle+3dgs", "bernoulli+3dgs"]}},
    ),
    # --- files the config names --------------------------------------------------------------------
    Case(
        "missing-pretrained-weights",
        r"stage1\.restormer\.checkpoint: .*/missing\.pth does not exist",
        {"stage1": {"restormer": {"checkpoint": "WORK/missing.pth"}}},
    ),
    Case(
        "pretrained-weights-with-prior",
        r"restormer: published weights \(.*weights\.pth\) predict a residual over the input image.*prior_sigma: 0",
        {"stage1": {"restormer": {"checkpoint": "WORK/weights.pth"}}},
        files={"weights.pth": b"\x00garbage" * 64},
    ),
    Case(
        "corrupt-pretrained-weights",
        r"weights\.pth is not a readable Restormer checkpoint",
        {"stage1": {"restormer": {"checkpoint": "WORK/weights.pth", "prior_sigma": 0.0}}},
        files={"weights.pth": b"\x00garbage" * 64},
        forbid=r"weights_only=False",
    ),
    Case(
        "pickled-code-in-weights",
        r"evil\.pth is not a readable Restormer checkpoint \(it holds pickled Python",
        {"stage1": {"restormer": {"checkpoint": "WORK/evil.pth", "prior_sigma": 0.0}}},
        files={"evil.pth": "EVIL"},
        forbid=r"weights_only=False|code from a weight file ran",
    ),
    Case(
        "missing-lpips-source",
        r"metrics\.lpips_source: .*/no-such-weights does not exist",
        {"metrics": {"lpips_source": "WORK/no-such-weights"}},
    ),
    Case(
        "ragged-sweep-table",
        r"ragged\.tsv: not a tab-separated table .*every row needs one value per column",
        {"tradeoff": {"table": "WORK/ragged.tsv"}},
        files={"ragged.tsv": b"iters\tres\n100\t32\n200\t32\t5\n"},
    ),
    # --- scene data: a real LLFF folder, damaged -----------------------------------------------
    Case(
        "nan-pose",
        r"poses_bounds\.npy: non-finite poses \(NaN or inf\) in view\(s\) 3",
        scene=_poses(lambda pb: pb.__setitem__((3, 7), np.nan)),
    ),
    Case(
        "negative-near-bound",
        r"view\(s\) 0, 1, 2, 3, 4 \(and 5 more\) have bounds near=-1.*need 0 < near < far",
        scene=_poses(lambda pb: pb.__setitem__((slice(None), 15), -1.0)),
    ),
    Case(
        "not-a-rotation",
        r"the 3x3 part of view\(s\) 5 is not a rotation",
        scene=_poses(lambda pb: pb.__setitem__((5, slice(0, 3)), 2.0 * pb[5, 0:3])),
    ),
    Case(
        "wrong-poses-shape",
        r"array of shape \(10, 15\).*N x 17",
        scene=lambda f: np.save(f / "poses_bounds.npy", np.load(f / "poses_bounds.npy")[:, :15]),
    ),
    Case(
        "pose-image-mismatch",
        r"holds 9 images but .*poses_bounds\.npy has 10 poses; they must match",
        scene=_image(Path.unlink),
    ),
    Case(
        "npz-archive-named-npy",
        r"poses_bounds\.npy is an \.npz archive \(members \['poses'\]\), not a \.npy array",
        scene=_npz_as_npy,
    ),
    Case(
        "hwf-height-and-width-swapped",
        r"the poses' hwf says 48 high x 36 wide but the images are 48x36 \(WxH\): height and width look swapped",
        scene=_poses(lambda pb: pb.__setitem__((slice(None), slice(4, 10, 5)), pb[:, [9, 4]])),
    ),
    Case(
        "every-view-at-one-position",
        r"all 10 cameras sit at one position .*no parallax",
        scene=_poses(lambda pb: pb.__setitem__((slice(None), slice(3, 15, 5)), pb[0, 3:15:5])),
    ),
    Case(
        "a-single-training-view",
        r"2 view\(s\) leave 1 training view\(s\) .*needs at least 2",
        scene=lambda f: (
            np.save(f / "poses_bounds.npy", np.load(f / "poses_bounds.npy")[:2]),
            [p.unlink() for p in sorted((f / "images").glob("*.png"))[2:]],
        ),
    ),
    Case("image-of-another-size", r"image002\.png is 30x20 pixels but image000\.png is 48x36", scene=_image(_resize)),
    Case("grayscale-image", r"image002\.png: 1 channel\(s\); the views of a scene must be RGB", scene=_image(_gray)),
    Case("corrupt-png", r"image002\.png", scene=_image(_truncate), stage="prepare_scene"),
    Case(
        "no-image-folder",
        r"images_8 does not exist; choose an LLFF factor whose folder is present",
        {"resolution": {"llff_factor": 8}},
        scene=lambda f: None,
    ),
    # --- environment ---------------------------------------------------------------------------
    Case(
        "lpips-folder-without-weights",
        r"lpips_v0\.1_alex\.npz",
        {"metrics": {"lpips_source": "WORK/empty"}},
        files={"empty/README": b"no weights here"},
        stage="lpips_weights",
    ),
]
TARGETS = {"prepare_scene": "results/scenes/mini", "lpips_weights": "results/cache/lpips/lpips_v0.1_alex.npz"}
# Cases run in groups, one work folder each (the groups run in parallel under xdist).
GROUPS = {
    "config-1": [c for c in CASES[:14] if c.scene is None and c.stage == "parse"],
    "config-2": [c for c in CASES[14:] if c.scene is None and c.stage == "parse"],
    "scene": [c for c in CASES if c.scene is not None and c.stage == "parse"],
    "jobs": [c for c in CASES if c.stage != "parse"],
}


def _resolve(value, work: Path):
    if isinstance(value, dict):
        return {k: _resolve(v, work) for k, v in value.items()}
    return value.replace("WORK", str(work)) if isinstance(value, str) else value


def _write_files(work: Path, files: dict) -> None:
    for name, data in files.items():
        path = work / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if data == "EVIL":
            import torch

            torch.save({"params": Evil()}, path)
        else:
            path.write_bytes(data)


class World:
    """A work folder and a tiny real-layout LLFF folder "mini" (rendered from a built-in layout)."""

    def __init__(self, root: Path):
        self.work, self.mini = root / "work", root / "mini"
        self.work.mkdir()
        write_builtin_scene("observatory", self.mini, height=36, width=48, views=10, supersample=1)
        self.pristine = {p: p.read_bytes() for p in self.mini.rglob("*") if p.is_file()}

    def config(self, case: Case | None = None) -> dict:
        """The case's config over the "mini" scene's (for scene cases) or alone; None: corrected."""
        scene = {
            "llff_scenes": {"mini": str(self.mini)},
            "scenes": {"eval": ["mini"]},
            "resolution": {"llff_factor": 1},
        }
        if case is None:
            return scene
        return (scene if case.scene is not None or case.stage == "prepare_scene" else {}) | _resolve(
            case.config, self.work
        )

    def restore(self) -> None:
        for p in [p for p in self.mini.rglob("*") if p.is_file()]:
            p.unlink()
        for p, data in self.pristine.items():
            p.write_bytes(data)

    def run(self, target: str, config: dict):
        cfg = self.work / "case.yaml"
        cfg.write_text(yaml.safe_dump(config))
        return run_snakemake(self.work, target, "--cores", "1", "--configfile", str(SMOKE), str(cfg), timeout=300)

    def snapshot(self) -> dict:
        results = self.work / "results"
        return (
            {str(p.relative_to(results)): p.stat().st_mtime_ns for p in results.rglob("*")} if results.exists() else {}
        )


def _leftovers(work: Path) -> list[str]:
    return [str(p.relative_to(work)) for p in (work / "results").rglob("*.tmp")] if (work / "results").exists() else []


def check_case(world: World, case: Case) -> None:
    """Run the case; assert exit code, message, stage, and that nothing was produced or lost."""
    _write_files(world.work, case.files)
    if case.scene is not None:
        case.scene(world.mini)
    target = TARGETS.get(case.stage, "results/scenes/mini")
    before = world.snapshot()
    proc = world.run(target, world.config(case))
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, (case.id, out[-3000:])
    if case.stage == "parse":
        assert "Building DAG" not in out, (case.id, out[-3000:])  # stopped before any job
        assert len(out.strip().splitlines()) <= MAX_LINES, (case.id, out)
        assert world.snapshot() == before, case.id  # nothing written, nothing already there touched
        message = out
    else:
        assert re.search(rf"Error in rule {case.stage}:", out), (case.id, out[-3000:])
        message = "\n".join(p.read_text() for p in (world.work / "logs" / case.stage).rglob("*.log"))
        assert not (world.work / target).exists(), case.id  # the failed job's output is gone, not half-written
    assert re.search(case.match, message), (case.id, message[-3000:])
    if case.forbid:
        assert not re.search(case.forbid, out + message), (case.id, out[-3000:])
    assert _leftovers(world.work) == [], case.id
    world.restore()


@pytest.mark.slow
@pytest.mark.parametrize("group", GROUPS)
def test_bad_input_is_stopped_early_and_clearly(tmp_path, group):
    """Parse-stage groups start from a finished corrected run, which every bad case must leave
    untouched; then (all groups) the corrected command in the same folder succeeds."""
    world = World(tmp_path)
    target = "results/scenes/mini"
    if group != "jobs":
        assert world.run(target, world.config()).returncode == 0
    for case in GROUPS[group]:
        check_case(world, case)
    again = world.run(target, world.config())
    assert again.returncode == 0, (again.stdout + again.stderr)[-3000:]
    assert (world.work / target).exists() and _leftovers(world.work) == []


def test_yaml_syntax_error_in_config_yaml_names_file_and_line(tmp_path):
    """The repository's config.yaml (read by the Snakefile itself) with a broken line."""
    repo = tmp_path / "repo"
    repo.mkdir()
    (repo / "Snakefile").write_text((REPO / "Snakefile").read_text())
    (repo / "workflow").symlink_to(REPO / "workflow")
    text = (REPO / "config.yaml").read_text().replace("seed: 0", "seed: [0", 1)
    (repo / "config.yaml").write_text(text)
    proc = run_snakemake(tmp_path, "-n", "-s", str(repo / "Snakefile"), timeout=120)
    out = proc.stdout + proc.stderr
    line = text.splitlines().index("seed: [0") + 1  # the parser notices further down; it names both lines
    assert proc.returncode != 0 and re.search(
        rf"config\.yaml:\d+:\d+: not valid YAML .*flow sequence at line {line}\)", out
    ), out[-2000:]


def test_read_yaml_and_the_config_checker_cli(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("spc:\n  frames: 4\n\tq: 0.5\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml:3:1: not valid YAML"):
        read_yaml(bad)
    twice = tmp_path / "twice.yaml"
    twice.write_text("spc:\n  q: 0.5\n  frames: 4\n  q: 0.4\n")
    with pytest.raises(ConfigError, match=r"twice\.yaml:4:3: key 'q' given twice \(first at line 2\); keep one"):
        read_yaml(twice)
    proc = run_snakemake(tmp_path / "work", "-n", "--configfile", str(twice))  # a --configfile too, before any job
    assert proc.returncode != 0 and "key 'q' given twice" in proc.stdout + proc.stderr
    assert "Building DAG" not in proc.stdout + proc.stderr
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must be a mapping"):
        read_yaml(listed)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("spc: {frame: 4}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "spc3d.config", str(wrong), str(SMOKE)], capture_output=True, text=True
    )
    assert proc.returncode == 1 and "spc.frame: unknown key; did you mean 'frames'" in proc.stdout + proc.stderr
    assert f"{SMOKE}: ok" in proc.stdout


def test_one_path_rule_every_relative_path_from_the_repository_root(tmp_path):
    config = {
        "llff_scenes": {"fern": "data/fern", "abs": "/data/abs"},
        "tradeoff": {"table": "workflow/t.tsv"},
        "metrics": {"lpips_source": None},
        "stage1": {"restormer": {"checkpoint": "w/restormer.pth"}, "pix2pix": {}, "train": {}},
    }
    resolve_paths(config, tmp_path)
    assert config["llff_scenes"] == {"fern": str(tmp_path / "data" / "fern"), "abs": "/data/abs"}
    assert config["tradeoff"]["table"] == str(tmp_path / "workflow" / "t.tsv")
    assert config["stage1"]["restormer"]["checkpoint"] == str(tmp_path / "w" / "restormer.pth")
    assert config["metrics"]["lpips_source"] is None and config["stage1"]["pix2pix"] == {}


def test_relative_paths_do_not_follow_the_working_directory(tmp_path):
    """With --directory elsewhere, a relative metrics.lpips_source still means the repository's."""
    cfg = tmp_path / "rel.yaml"
    cfg.write_text("metrics: {lpips_source: no-such-folder-xyz}\n")
    proc = run_snakemake(tmp_path, "-n", "--configfile", str(SMOKE), str(cfg), timeout=120)
    assert proc.returncode != 0 and f"{REPO / 'no-such-folder-xyz'} does not exist" in proc.stdout + proc.stderr


def test_case_table_is_large_and_covers_every_stage():
    assert len(CASES) >= 25 and len({c.id for c in CASES}) == len(CASES)
    assert {c.stage for c in CASES} == {"parse", "prepare_scene", "lpips_weights"}
    assert sum(map(len, GROUPS.values())) == len(CASES)


def test_translators_benchmark_names_an_unknown_memory_format_before_building():
    """benchmarks/translators.py --formats: a typo is named with the formats it accepts, before any model is built."""
    env = dict(os.environ, PYTHONPATH=str(REPO / "workflow"))
    cmd = [sys.executable, str(REPO / "benchmarks" / "translators.py"), "--formats", "contiguous,nhwc"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode != 0
    assert "unknown memory format(s) ['nhwc']; use contiguous, channels_last" in proc.stderr

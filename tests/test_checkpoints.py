"""Checkpoints belong to their settings: after a change, Snakemake reruns the job and the job
retrains from scratch (the old checkpoint discarded, the reason logged and recorded) instead of
"resuming" a model trained under the old settings. Also: edited LLFF images rerun their scene."""

import shutil

import numpy as np
import pytest
import torch
import yaml

from spc3d import io
from spc3d.checkpoints import Checkpoint, CheckpointPolicy, differences, digest_path, fingerprint
from spc3d.training import run

from conftest import REPO, InterruptAt, Interrupted, llff_scene, run_snakemake

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
GT3DGS = "results/eval/courtyard/gt+3dgs/metrics.json"


class Counter:
    """A minimal trainer: one number that counts the steps (exact resume is easy to see)."""

    def __init__(self):
        self.value = torch.zeros(())

    def step(self, it):
        self.value += it
        return {"loss": float(self.value)}

    def state(self):
        return {"value": self.value.clone()}

    def load(self, state):
        self.value = state["value"].clone()


def test_checkpoint_is_resumed_only_by_its_own_job(tmp_path):
    path = tmp_path / "ckpt.pt"
    fp = fingerprint("test", {"settings": {"iterations": 10, "width": 8}, "seed": 0}, {"data": "abc"})
    with pytest.raises(Interrupted):
        run(InterruptAt(Counter(), 8), 10, Checkpoint(path, fp), CheckpointPolicy(fraction=0.3, minutes=0))
    same = Checkpoint(path, fp)
    counter = Counter()
    assert run(counter, 10, same)["resumed_from"] == 6 and float(counter.value) == sum(range(1, 11))
    for change, why in [
        ({"settings": {"iterations": 10, "width": 12}, "seed": 0}, "settings.width: 8 -> 12"),
        ({"settings": {"iterations": 10, "width": 8}, "seed": 1}, "seed: 0 -> 1"),
    ]:
        other = Checkpoint(path, fingerprint("test", change, {"data": "abc"}))
        rec = run(Counter(), 10, other)
        assert rec["resumed_from"] == 0 and other.record["discarded"] == why
        run(Counter(), 10, Checkpoint(path, fp))  # back to the first job's checkpoint
    changed = Checkpoint(
        path, fingerprint("test", {"settings": {"iterations": 10, "width": 8}, "seed": 0}, {"data": "xyz"})
    )
    assert run(Counter(), 10, changed)["resumed_from"] == 0 and changed.record["discarded"] == "inputs.data changed"


def test_unreadable_or_foreign_checkpoints_are_discarded_not_loaded(tmp_path, caplog):
    path = tmp_path / "ckpt.pt"
    fp = fingerprint("test", {"seed": 0}, {})
    path.write_bytes(b"not a checkpoint")
    ckpt = Checkpoint(path, fp)
    assert run(Counter(), 3, ckpt)["resumed_from"] == 0 and ckpt.record["discarded"].startswith("unreadable")
    assert "discarding checkpoint" in caplog.text and str(path) in caplog.text

    class Evil:  # a pickled object: weights_only loading refuses it instead of running its code
        def __reduce__(self):
            return (print, ("pwned",))

    torch.save({"fingerprint": fp, "iteration": 3, "state": Evil()}, path)
    ckpt = Checkpoint(path, fp)
    assert run(Counter(), 3, ckpt)["resumed_from"] == 0 and "unreadable" in ckpt.record["discarded"]


def test_policy_and_iterations_are_checked():
    assert CheckpointPolicy(fraction=0.1).every(1200) == 120 and CheckpointPolicy(fraction=0.1).every(5) == 1
    assert CheckpointPolicy(fraction=0).every(100) is None
    with pytest.raises(ValueError, match="fraction"):
        CheckpointPolicy(fraction=1.5)
    with pytest.raises(ValueError, match="iterations must be >= 1"):
        run(Counter(), 0)


def test_digests_see_content_not_hidden_temporaries(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.txt").write_text("1")
    before = digest_path(tmp_path / "a")
    (tmp_path / "a" / ".x.txt.abc.tmp").mkdir()  # an interrupted writer's leftovers do not count
    assert digest_path(tmp_path / "a") == before
    (tmp_path / "a" / "x.txt").write_text("2")
    assert digest_path(tmp_path / "a") != before
    assert (
        differences({"a": {"b": 1}, "inputs": {"s": "1"}}, {"a": {"b": 2}, "inputs": {"s": "2"}})
        == "a.b: 1 -> 2; inputs.s changed"
    )


def _run(workdir, *configs, target=GT3DGS):
    proc = run_snakemake(workdir, target, "--cores", "2", "--configfile", str(SMOKE), *map(str, configs))
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _yaml(path, data):
    path.write_text(yaml.safe_dump(data))
    return path


def _record(workdir, folder):
    return io.read_json(workdir / folder / "train.json")


@pytest.mark.slow
def test_settings_changes_retrain_stage2(tmp_path, lpips_cache):
    """The issue's sequence (iterations 40 -> 20), then init_points and seed: each reruns and retrains."""
    lp = _yaml(tmp_path / "lpips.yaml", {"metrics": {"lpips_source": str(lpips_cache)}})
    _run(tmp_path, lp)
    first = _record(tmp_path, "results/recon/courtyard/gt+3dgs")
    assert first["checkpoint"]["resumed_from"] == 0 and first["checkpoint"]["saves"] >= 10
    steps = [
        ({"stage2": {"3dgs": {"iterations": 20}}}, "settings.iterations: 40 -> 20"),
        ({"stage2": {"3dgs": {"iterations": 20, "init_points": 300}}}, "settings.init_points: 500 -> 300"),
        ({"stage2": {"3dgs": {"iterations": 20, "init_points": 300}}, "seed": 1}, "seed: 0 -> 1"),
    ]
    for i, (change, why) in enumerate(steps):
        _run(tmp_path, lp, _yaml(tmp_path / f"change{i}.yaml", change))
        rec = _record(tmp_path, "results/recon/courtyard/gt+3dgs")
        assert rec["resumed_from"] == 0 and why in rec["checkpoint"]["discarded"], rec["checkpoint"]
        cfg = change["stage2"]["3dgs"]
        assert rec["settings"]["iterations"] == cfg["iterations"] == rec["iterations"]
        assert rec["settings"]["init_points"] == cfg.get("init_points", 500) and rec["seed"] == change.get("seed", 0)
        log = (tmp_path / "logs" / "reconstruct" / "courtyard" / "gt+3dgs.log").read_text()
        assert "discarding checkpoint results/checkpoints/courtyard/gt+3dgs/checkpoint.pt" in log and why in log


@pytest.mark.slow
def test_settings_changes_retrain_a_translator(tmp_path, lpips_cache):
    """New training pairs (spc.target_detection) and a wider network (ngf 8 -> 12) both retrain."""
    lp = _yaml(tmp_path / "lpips.yaml", {"metrics": {"lpips_source": str(lpips_cache)}})
    target = "results/models/pix2pix"
    _run(tmp_path, lp, target=target)
    model = (tmp_path / target / "model.pt").read_bytes()
    _run(tmp_path, lp, _yaml(tmp_path / "det.yaml", {"spc": {"target_detection": 0.3}}), target=target)
    rec = _record(tmp_path, target)
    assert rec["resumed_from"] == 0 and "inputs.pairs[0] changed" in rec["checkpoint"]["discarded"]
    assert (tmp_path / target / "model.pt").read_bytes() != model
    wider = {
        "spc": {"target_detection": 0.3},
        "stage1": {"pix2pix": {"ngf": 12, "ndf": 8, "num_downs": 3, "n_layers_D": 2}},
    }
    _run(tmp_path, lp, _yaml(tmp_path / "wide.yaml", wider), target=target)
    rec = _record(tmp_path, target)
    assert rec["resumed_from"] == 0 and "settings.ngf: 8 -> 12" in rec["checkpoint"]["discarded"]
    assert rec["settings"]["ngf"] == 12


@pytest.mark.slow
@pytest.mark.llff
def test_an_edited_llff_image_reruns_its_scene_and_retrains(tmp_path, lpips_cache):
    fern = llff_scene("fern")
    copy = tmp_path / "fern"
    copy.mkdir()
    shutil.copy(fern / "poses_bounds.npy", copy)
    shutil.copytree(fern / "images_8", copy / "images_8")
    cfg = _yaml(
        tmp_path / "fern.yaml",
        {
            "metrics": {"lpips_source": str(lpips_cache)},
            "llff_scenes": {"fern": str(copy)},
            "scenes": {"train": ["tabletop"], "eval": ["fern"]},
        },
    )
    target = "results/recon/fern/gt+3dgs"
    _run(tmp_path, cfg, target=target)
    dry = run_snakemake(tmp_path, target, "-n", "--configfile", str(SMOKE), str(cfg))
    assert "Nothing to be done" in dry.stdout + dry.stderr
    image = sorted((copy / "images_8").iterdir())[3]
    prepared = tmp_path / "results" / "scenes" / "fern" / "images" / f"{image.stem}.png"
    before = io.read_rgb(prepared)
    io.write_image(image.with_suffix(".png"), 1.0 - io.read_rgb(image))  # an edited capture
    if image.suffix.lower() != ".png":
        image.unlink()
    proc = _run(tmp_path, cfg, target=target)
    assert "prepare_scene" in proc.stdout + proc.stderr
    rec = _record(tmp_path, target)
    assert rec["resumed_from"] == 0 and "inputs.scene changed" in rec["checkpoint"]["discarded"]
    assert np.abs(io.read_rgb(prepared) - (1.0 - before)).mean() < 0.02  # the edited image, not the old one

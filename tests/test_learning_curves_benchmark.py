"""benchmarks/learning_curves.py: which model folder each variant trains, the config it trains under,
and the baseline a published network's gain is measured from, on hand-written training records."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from conftest import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "learning_curves.py"


@pytest.fixture(scope="module")
def bench():
    return load_script(SCRIPT)


def _args(methods):
    return argparse.Namespace(steps=3000, every=100, methods=methods)


def _write_training(work: Path, folder: str, curve: list[tuple[int, float]], cpu: float, prior=None) -> None:
    model = work / "results" / "models" / folder
    model.mkdir(parents=True)
    record = {
        "validation": {"curve": [{"iteration": i, "val_psnr": p, "val_ssim": 0.5} for i, p in curve]},
        "stopped": {"step": curve[-1][0], "reason": "budget"},
        "prior": prior,
    }
    (model / "train.json").write_text(json.dumps(record))
    bench_dir = work / "benchmarks" / "train_translator"
    bench_dir.mkdir(parents=True, exist_ok=True)
    (bench_dir / f"{folder}.tsv").write_text(f"s\tuser_s\tsys_s\n1.0\t{cpu - 1.0}\t1.0\n")


def test_published_variant_trains_the_pub_folders(bench):
    assert [bench.folder("published", m) for m in ("pix2pix", "diffusion")] == ["pix2pix-pub", "diffusion-pub"]
    assert bench.folder("paper", "pix2pix") == "pix2pix" and bench.folder("pixel", "cyclegan") == "cyclegan"
    # every method runs in it, with its own validation block matching the common one (never stopped early)
    stage1 = bench.overrides(_args(bench.METHODS), "published")["stage1"]
    assert stage1["validation"] == {"every": 100, "patience": 0}
    assert stage1["train"] == {"iterations": 3000, "decay_from": 1.0, "log_every": 100}
    for method in bench.METHODS:
        assert stage1[method] == {"validation": {"every": 100, "patience": 0}}


def test_variant_overrides_only_its_methods(bench):
    stage1 = bench.overrides(_args(["pix2pixhd", "restormer"]), "pixel")["stage1"]
    assert stage1["pix2pixhd"]["lambda_L1"] == 100.0
    assert "restormer" not in stage1 and "cyclegan" not in stage1  # not in the variant / not asked for


def test_gain_of_a_published_network_is_over_the_untrained_prior(bench, tmp_path):
    _write_training(tmp_path, "restormer-pub", [(0, 12.0), (100, 19.0), (200, 21.5)], cpu=40.0)
    _write_training(tmp_path, "prior", [(0, 21.0)], cpu=1.0, prior={"sigma": 2.0, "val_psnr": 21.0})
    frame, per_step, prior = bench.curve(tmp_path, "restormer-pub")
    assert prior == 21.0 and per_step == pytest.approx(40.0 / 200)
    row = bench.summary(frame, [100, 300], prior)
    assert row["Δ@0"] == -9.0 and row["Δ@100"] == -2.0 and row["Δ@300"] is None
    assert (row["best_Δ"], row["best_step"]) == (0.5, 200)


def test_residual_network_uses_its_own_prior(bench, tmp_path):
    prior = {"sigma": 2.0, "gain": [1.0, 1.0, 1.0], "val_psnr": 20.0}
    _write_training(tmp_path, "pix2pix", [(0, 20.0), (100, 21.0)], cpu=10.0, prior=prior)
    _, _, baseline = bench.curve(tmp_path, "pix2pix")
    assert baseline == 20.0  # no prior folder needed

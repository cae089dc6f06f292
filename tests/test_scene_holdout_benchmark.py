"""benchmarks/scene_holdout_curves.py: which trainings and validation scenes each fold's curve may
use (never its evaluation scene), and the config a subset trains under, on synthetic tables."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd
import pytest

from conftest import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "scene_holdout_curves.py"
SCENES = ["a", "b", "c", "d"]


@pytest.fixture(scope="module")
def bench():
    return load_script(SCRIPT)


def _table() -> pd.DataFrame:
    """Every pair of scenes trained, validated on the other two; gain = a code of (pair, scene)."""
    rows = []
    for i, first in enumerate(SCENES):
        for second in SCENES[i + 1 :]:
            for scene in sorted(set(SCENES) - {first, second}):
                code = 10 * SCENES.index(scene) + SCENES.index(first) + SCENES.index(second)
                for step in (0, 100):
                    rows.append(
                        {
                            "method": "m",
                            "trained_on": f"{first}+{second}",
                            "validated_on": scene,
                            "step": step,
                            "gain": code * step / 100,
                        }
                    )
    return pd.DataFrame(rows)


def test_a_fold_never_trains_nor_validates_on_its_evaluation_scene(bench):
    folds = bench.fold_curves(_table(), SCENES)
    last = folds[folds["step"] == 100].set_index("fold")
    # without d: pairs of a, b, c, each validated on the third: (b+c -> a), (a+c -> b), (a+b -> c)
    expected = {
        "d": [0 + 3, 10 + 2, 20 + 1],
        "a": [10 + 5, 20 + 4, 30 + 3],  # (c+d -> b), (b+d -> c), (b+c -> d)
    }
    for scene, codes in expected.items():
        assert last.loc[f"without-{scene}", "gain"] == pytest.approx(sum(codes) / 3)
        assert last.loc[f"without-{scene}", "pairs"] == 3
    assert (folds[folds["step"] == 0]["gain"] == 0).all()


def test_the_summary_reads_each_budget_and_the_best_step(bench):
    table = bench.summary(bench.fold_curves(_table(), SCENES), [50, 100, 200])
    row = table[table["fold"] == "without-d"].iloc[0]
    assert row["Δ@0"] == 0 and row["Δ@50"] == 0 and row["Δ@100"] == pytest.approx(12.0) and row["Δ@200"] is None
    assert row["best_step"] == 100 and table["fold"].iloc[-1] == "mean of folds"


def test_a_subset_trains_on_its_scenes_and_holds_out_the_rest(bench):
    args = argparse.Namespace(steps=300, every=50, methods=["pix2pix", "restormer"])
    config = bench.overrides(("c", "a"), SCENES, args)
    assert config["scenes"]["train"] == ["c", "a", "b", "d"] and config["scenes"]["leave_one_out"] is False
    for block in (config["stage1"], config["stage1"]["restormer"]):  # the method's own block too
        assert block["validation"] == {"every": 50, "patience": 0, "hold_out": 2}
        assert block["train"]["iterations"] == 300 and block["train"]["decay_from"] == 1.0

"""A run's metrics.json read and written through one record type (spc3d.evaluation.record): the
defaults of keys older records lack, the row name a capture's frame reads as, and a refusal of a
file that is not a run's record."""

from __future__ import annotations

import json
import math

import pytest

from spc3d.evaluation.record import RunRecord, read_runs, write_run

RECORD = {
    "scene": "fern",
    "combination": "mle+3dgs",
    "seed": 3,
    "frames": 1,
    "capture_factor": 1,
    "mean": {"psnr": 21.5, "ssim": 0.61},
    "init": {"used": "random", "asked": "colmap"},
    "stopped": {"step": 400, "of": 1200, "reason": "plateau"},
    "at_stop": {"psnr": 21.0, "train_s": 4.0},
    "train_s": 10.0,
    "capacity": {"gaussians": 5000},
    "per_view": [{"view": "a", "psnr": 21.5}],
}


def test_a_record_reads_its_keys_and_the_row_it_is():
    rec = RunRecord.from_dict(RECORD)
    assert (rec.scene, rec.seed, rec.budget, rec.reference) == ("fern", 3, (1, 1), True)
    assert rec.row == "mle-x1+3dgs"  # a K = 1 frame at S = 1 is the working-resolution row
    assert rec.init == "random" and rec.score("psnr") == 21.5 and math.isnan(rec.score("lpips_vgg"))
    assert rec.stopped["step"] == 400 and rec.at_stop["psnr"] == 21.0 and rec.train_s == 10.0
    assert rec.capacity == {"gaussians": 5000} and rec.get("per_view") == RECORD["per_view"]


def test_older_records_read_with_the_defaults_of_their_missing_keys():
    old = {"scene": "fern", "combination": "mle+3dgs", "frames": 1, "mean": None, "init": "colmap"}
    rec = RunRecord.from_dict(old)
    assert rec.capture_factor == 1 and rec.budget == (1, 1) and rec.reference and rec.seed is None
    assert rec.row == "mle+3dgs"  # a record without S keeps its name
    assert rec.init == "colmap" and rec.mean is None and math.isnan(rec.score("psnr"))
    assert rec.stopped is None and rec.scored_on == "RGB"
    unscored = RunRecord.from_dict(old | {"reference": False, "scored_on": "luminance", "capture_factor": 4})
    assert not unscored.reference and unscored.scored_on == "luminance" and unscored.budget == (1, 4)


def test_writing_refuses_what_is_not_a_runs_record_and_writes_nothing(tmp_path):
    path = tmp_path / "metrics.json"
    with pytest.raises(ValueError, match=r"metrics.json: not a run's metrics record, it lacks \['combination'\]"):
        write_run(path, {"scene": "fern", "mean": None})
    assert not path.exists()
    assert write_run(path, RECORD) == RECORD and json.loads(path.read_text()) == RECORD
    assert [r.fields for r in read_runs([path, path])] == [RECORD, RECORD]

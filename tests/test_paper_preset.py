"""The paper preset is merged over config.yaml (as ``snakemake --configfile`` does), so every key
config.yaml sizes for the CPU must be set again in it, or the CPU value silently carries over
(3DGS densifying until step 900 of 30,000, translators stopped by a 25-step validation rule)."""

from spc3d.config import workflow_config
from spc3d.names import translator_settings, translator_validation
from spc3d.specs.reconstructors import reconstructor_config

from conftest import REPO

PAPER = workflow_config(REPO / "workflow" / "presets" / "paper.yaml")


def test_3dgs_runs_the_reference_schedule():
    cfg = reconstructor_config("3dgs", PAPER["stage2"]["3dgs"])
    reference = {"iterations": 30000, "densify_from": 500, "densify_until": 15000, "densify_every": 100}
    reference |= {"opacity_reset_every": 3000, "sh_interval": 1000, "densify_grad": 2e-4, "plateau_patience": 0}
    assert {k: getattr(cfg, k) for k in reference} == reference


def test_every_translator_trains_the_whole_paper_budget():
    for method in ("pix2pixhd", "pix2pix", "cyclegan", "restormer", "diffusion"):
        _, training = translator_settings(PAPER["stage1"], method)
        assert training["iterations"] == 3_000_000, method
        validation = translator_validation(PAPER["stage1"], method)
        assert validation["patience"] == 0 and validation["every"] >= 15000, (method, validation)

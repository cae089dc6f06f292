"""Adapter: rule evaluate -> spc3d.evaluation.evaluate.evaluate."""

from pathlib import Path

from spc3d.evaluation.evaluate import evaluate
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    evaluate(
        snakemake.input.recon,
        snakemake.input.scene,
        snakemake.output[0],
        lpips_dir=Path(snakemake.input.lpips[0]).parent,
        spc_dir=snakemake.input.spc or None,
    )

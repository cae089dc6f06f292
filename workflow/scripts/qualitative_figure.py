"""Adapter: rule qualitative_figure -> spc3d.evaluation.figures.qualitative_figure."""

from pathlib import Path

from spc3d.evaluation.figures import qualitative_figure
from spc3d.jobs import logged
from spc3d.names import LABELS

with logged(snakemake.log[0]):
    recons = {Path(d).name: d for d in snakemake.input.recons}
    qualitative_figure(snakemake.input.scene, snakemake.input.spc, recons, snakemake.output[0], labels=LABELS)

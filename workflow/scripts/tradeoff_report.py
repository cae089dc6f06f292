"""Adapter: rule tradeoff_report -> spc3d.sweeps.report.tradeoff_report."""

from spc3d.jobs import logged
from spc3d.names import LABELS
from spc3d.sweeps.report import tradeoff_report

with logged(snakemake.log[0]):
    out = snakemake.output
    tradeoff_report(
        snakemake.params.points, snakemake.params.combos, out.csv, out.png, labels=LABELS, clock=snakemake.params.clock
    )

"""Adapter: rule tradeoff_report -> spc3d.sweeps.report.tradeoff_report."""

from spc3d.jobs import logged
from spc3d.names import LABELS
from spc3d.sweeps.report import tradeoff_report

with logged(snakemake.log[0]):
    out, job = snakemake.output, snakemake.params.job
    tradeoff_report(job.points, job.combos, out.csv, out.png, labels=LABELS, clock=job.clock)

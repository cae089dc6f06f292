"""Adapter: rule photon_level_report -> spc3d.sweeps.report.photon_level_report."""

from spc3d.jobs import logged
from spc3d.names import LABELS
from spc3d.sweeps.report import photon_level_report

with logged(snakemake.log[0]):
    out, job = snakemake.output, snakemake.params.job
    photon_level_report(job.points, job.combos, out.csv, out.png, labels=LABELS)

"""Adapter: rule write_summary -> spc3d.evaluation.summary.write_summary."""

from spc3d.evaluation.summary import write_summary
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    out = snakemake.output
    write_summary(
        snakemake.input.scenes,
        snakemake.input.spc,
        snakemake.input.colmap,
        snakemake.params.roles,
        out.csv,
        out.md,
        out.png,
    )

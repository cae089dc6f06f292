"""Adapter: rule write_display -> spc3d.inputs.exposure.write_display (params: frames K, capture)."""

from spc3d.inputs.exposure import write_display
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    write_display(
        snakemake.input.spc,
        snakemake.input.calibration,
        int(snakemake.params.job.frames),
        snakemake.output[0],
        capture=bool(snakemake.params.job.capture),
    )

"""Adapter: rule calibrate_display -> spc3d.inputs.exposure.calibrate_display (params: frames K, capture)."""

from spc3d.inputs.exposure import calibrate_display
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    calibrate_display(
        list(snakemake.input.scenes),
        list(snakemake.input.spc),
        int(snakemake.params.job.frames),
        snakemake.output[0],
        capture=bool(snakemake.params.job.capture),
    )

"""Adapter: rule translate_scene -> spc3d.translate.apply.translate_scene."""

from spc3d.jobs import logged
from spc3d.translate.apply import translate_scene

with logged(snakemake.log[0]):
    translate_scene(
        snakemake.input.model,
        snakemake.input.spc,
        snakemake.input.scene,
        snakemake.output[0],
        frames=snakemake.params.job.frames,
        threads=snakemake.threads,
        ensemble=snakemake.params.job.ensemble,
    )

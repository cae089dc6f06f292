"""Adapter: rule prepare_scene -> spc3d.inputs.prepare_scene."""

from spc3d.inputs import prepare_scene
from spc3d.workflow import logged

with logged(snakemake.log[0]):
    prepare_scene(snakemake.params.spec, snakemake.output[0])

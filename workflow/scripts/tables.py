"""Adapter: rule tables -> spc3d.tables."""
from pathlib import Path

from spc3d.tables import single_stage_table
from spc3d.workflow import logged

with logged(snakemake.log[0]):
    single_stage_table(list(snakemake.input), str(Path(snakemake.output.csv).with_suffix("")),
                       snakemake.params.nerf_variant)
